"""The PettingZoo Parallel recorder: :class:`RecordParallelEvidence`.

Row ``t`` of an agent is its action in the ``t``-th ``step()`` it acted in, with what that step
returned for it; an agent that appears mid-game begins its episode in the same game, the
observation it appears with its reset row (``docs/format.md``, "PettingZoo files").
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pettingzoo.utils.wrappers import BaseParallelWrapper

from .agents import ARGS_DOC, AgentRecorder, agent_result
from .registry import KIND_PARALLEL

__all__ = ["RecordParallelEvidence"]


class RecordParallelEvidence(AgentRecorder, BaseParallelWrapper):  # type: ignore[misc]
    """Record every agent of a PettingZoo ``ParallelEnv`` to one MCAP evidence file.

    Example:
        >>> import tempfile, pathlib, warnings
        >>> with warnings.catch_warnings():  # PettingZoo 1.27 deprecates env modules
        ...     warnings.simplefilter("ignore", DeprecationWarning)
        ...     from pettingzoo.classic import rps_v2
        >>> from episode_audit import RecordParallelEvidence, open_evidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "rps.mcap"
        >>> with RecordParallelEvidence(rps_v2.parallel_env(max_cycles=3), path) as env:
        ...     _ = env.reset(seed=1)
        ...     while env.agents:
        ...         _ = env.step({agent: 1 for agent in env.agents})
        >>> rows = open_evidence(path).episodes().to_pylist()
        >>> [(r["agent"], r["game"], r["length"], r["outcome"]) for r in rows]
        [('player_0', 0, 3, 'truncated'), ('player_1', 0, 3, 'truncated')]
    """

    __doc__ = (__doc__ or "") + ARGS_DOC
    _kind = KIND_PARALLEL

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[Any, Any], dict[Any, dict[str, Any]]]:
        """Reset the env (a new game) and record every agent's reset row."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            self._enter()
            return self._reset(seed, options)
        finally:
            self._busy = False

    def _reset(
        self, seed: int | None, options: dict[str, Any] | None
    ) -> tuple[dict[Any, Any], dict[Any, dict[str, Any]]]:
        rec = self._rec
        rec.new_game(seed, options)
        try:
            obs, infos = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            for agent in self.env.possible_agents:
                rec.begin(agent)
            rec.error(exc, "reset")
            raise
        try:
            self._join(obs, infos)
            if rec.file.due():
                rec.file.auto_flush()
        except Exception as exc:  # never break the training loop over recording trouble
            rec.file.trouble(exc)
        return obs, infos

    def _join(self, obs: Mapping[Any, Any], infos: Mapping[Any, Any]) -> None:
        """Begin the episodes of the agents that are live now and have none in this game."""
        rec = self._rec
        for agent in self.env.agents:
            if agent not in rec.in_game:
                begun = rec.begin(agent)
                rec.reset_row(agent, begun, obs.get(agent), infos.get(agent, {}))

    def step(self, actions: dict[Any, Any]) -> tuple[Any, Any, Any, Any, Any]:
        """Step the env and record each acting agent's step; results are returned untouched."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            if self._gated:
                self._enter()
            return self._step(actions)
        finally:
            self._busy = False

    def _step(self, actions: dict[Any, Any]) -> tuple[Any, Any, Any, Any, Any]:
        rec = self._rec
        try:
            result = self.env.step(actions)
        except Exception as exc:
            rec.error(exc, "step")
            raise
        file = rec.file
        file.held = True  # a flush due amid the agents' rows waits for the last: the step whole
        try:
            obs, rewards, terminated, truncated, infos = result
            streams = rec.streams
            for agent, action in actions.items():
                stream = streams.get(agent)
                if stream is None or agent not in rec.in_game:
                    continue
                stream.step(action, agent_result(agent, obs, rewards, terminated, truncated, infos))
            self._join(obs, infos)
        except Exception as exc:  # never break the training loop over recording trouble
            file.trouble(exc)
        finally:
            file.held = False
        if file.flush_wanted is not None:
            file.auto_flush(background=file.flush_wanted)  # (never raises)
        return result  # type: ignore[no-any-return]
