"""The PettingZoo AEC recorder: :class:`RecordAECEvidence`, every agent turn.

Turns are accounted by :class:`~.turns.AECTurns` (shared with replay); the rows a ``step()``
closes are held until it returned or raised, so a step that raised after every agent-episode had
ended is noted ``env_raised`` on the last of them (``docs/format.md``, "PettingZoo files").
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.wrappers import BaseWrapper

from ...errors import RecorderError
from ...format.columns import error_text
from ..notes import note
from ..stream import Stream
from .agents import ARGS_DOC, AgentRecorder, Begun
from .registry import KIND_AEC
from .turns import AECTurns

__all__ = ["RecordAECEvidence"]

# a row held back (see RecordAECEvidence.step): its stream, the action and result, its notes
_Row = tuple[Stream, Any, tuple[Any, float, bool, bool, Any], list[str]]


def _ends_episode(result: tuple[Any, float, bool, bool, Any]) -> bool:
    """Whether a row with this result ends its episode.

    By its flags' truth values, taken as :meth:`Stream.step` takes them (flags without a truth
    value end nothing).
    """
    try:
        terminated, truncated = bool(result[2]), bool(result[3])
    except Exception:
        return False
    return terminated or truncated


def _write_row(
    stream: Stream, action: Any, result: tuple[Any, float, bool, bool, Any], notes: list[str]
) -> None:
    """Record one AEC row of ``stream``, with the notes of the accounting itself."""
    stream.note_next_row(notes)
    stream.step(action, result)


class RecordAECEvidence(AgentRecorder, BaseWrapper):  # type: ignore[misc]
    """Record every agent turn of a PettingZoo ``AECEnv`` to one MCAP evidence file.

    Rewards are taken from ``env.rewards`` after every step (see :class:`AECTurns`), never
    from ``last()``'s cumulative reward.

    Example:
        >>> import tempfile, pathlib, warnings
        >>> with warnings.catch_warnings():  # PettingZoo 1.27 deprecates env modules
        ...     warnings.simplefilter("ignore", DeprecationWarning)
        ...     from pettingzoo.classic import tictactoe_v3
        >>> from episode_audit import RecordAECEvidence, open_evidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "ttt.mcap"
        >>> with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        ...     env.reset(seed=0)
        ...     for move in [0, 3, 1, 4, 2]:  # player_1 completes the top row
        ...         env.step(move)
        ...     for agent in env.agent_iter():
        ...         env.step(None)  # dead steps
        >>> rows = open_evidence(path).episodes().to_pylist()
        >>> [(r["agent"], r["length"], r["return"]) for r in rows]
        [('player_1', 3, 1.0), ('player_2', 2, -1.0)]
    """

    __doc__ = (__doc__ or "") + ARGS_DOC
    _kind = KIND_AEC

    def _started(self, env: Any) -> None:
        self._begun: dict[Any, Begun | None] = {}
        self._turns = AECTurns(env, self._on_reset, self._on_row)
        self._held: list[_Row] | None = None  # rows closed by the step() under way

    def _on_reset(self, agent: str, obs: Any, info: Any) -> None:
        rec = self._rec
        begun = self._begun.pop(agent, None)
        if begun is None and agent not in rec.in_game:
            begun = rec.begin(agent)  # an agent that appeared mid-game
        rec.reset_row(agent, begun, obs, info)

    def _on_row(
        self, agent: str, action: Any, result: tuple[Any, float, bool, bool, Any], notes: list[str]
    ) -> None:
        stream = self._rec.streams.get(agent)
        if stream is None:
            return
        if self._held is not None:  # written once the step returned or raised (see step())
            self._held.append((stream, action, result, notes))
        else:
            _write_row(stream, action, result, notes)

    def _release(
        self, raised: Exception | None = None, agent: Any = None, dead: bool = False
    ) -> None:
        """Write the rows held since the ``step()`` under way began. Never raises.

        ``raised``: that step raised it, in ``agent``'s turn (a ``dead`` step or not). If that
        ends no agent-episode ``error`` (see :meth:`_raised_note`), the last row held says so.
        """
        held, self._held = self._held or [], None
        try:
            lost = None if raised is None else self._raised_note(held, raised, agent, dead)
            if lost is not None:
                if not held:
                    raise RecorderError(f"the env raised in a step that closed no row: {lost}")
                held[-1][3].append(lost)
            for row in held:
                _write_row(*row)
        except Exception as exc:
            self._rec.file.trouble(exc)

    def _raised_note(self, held: list[_Row], exc: Exception, agent: Any, dead: bool) -> str | None:
        """The note ``env_raised`` if the ``step()`` that raised ``exc`` ends no episode ``error``.

        That is when no agent-episode is left open once the ``held`` rows are written: every
        agent had ended by its flags (a dead step after the game was decided). ``None`` when one
        is left: it ends ``error``, which says it all.
        """
        ending = {stream for stream, _, result, _ in held if _ends_episode(result)}
        for stream in self._rec.streams.values():
            episode = stream.episode
            if episode is not None and not episode.ended and stream not in ending:
                return None
        turn = f"{agent}'s dead step" if dead else f"{agent}'s step"
        return note(
            "env_raised",
            f"{error_text(exc)} (during step: {turn}, after every agent-episode of game "
            f"{self._rec.game} had ended)",
        )

    def _cut(self) -> None:
        """Close the open rows of the current game with the env's state now."""
        try:
            self._turns.finish()
        except Exception as exc:
            self._rec.file.trouble(exc)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        """Reset the env (a new game); each agent's reset row is written at its first turn."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            self._enter()
            self._reset(seed, options)
        finally:
            self._busy = False

    def _reset(self, seed: int | None, options: dict[str, Any] | None) -> None:
        rec = self._rec
        if rec.game >= 0:
            self._cut()
        rec.new_game(seed, options)
        try:
            self.env.reset(seed=seed, options=options)
        except Exception as exc:
            for agent in self.env.possible_agents:
                rec.begin(agent)
            rec.error(exc, "reset")
            raise
        try:
            agents = list(self.env.agents)
            self._begun = {agent: rec.begin(agent) for agent in agents}
            self._turns.begin(agents)
            if rec.file.due():
                rec.file.auto_flush()
        except Exception as exc:  # never break the training loop over recording trouble
            rec.file.trouble(exc)

    def step(self, action: Any) -> None:
        """Step the env for ``agent_selection`` and account the turn (see :class:`AECTurns`).

        The rows the turn closes are held until the env's ``step()`` returned or raised: one
        that raised after every agent-episode had ended is noted on the last of them.
        """
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            if self._gated:
                self._enter()
            self._step(action)
        finally:
            self._busy = False

    def _step(self, action: Any) -> None:
        rec = self._rec
        self._held = []
        try:
            agent, dead = None, False
            try:
                agent = self.env.agent_selection
                dead = self._turns.turn(action)
            except Exception as exc:
                rec.file.trouble(exc)
            try:
                self.env.step(action)
            except Exception as exc:
                try:  # its action is no row; the other open rows close now, before the error
                    self._turns.failed()
                except Exception as trouble:
                    rec.file.trouble(trouble)
                self._release(exc, agent, dead)
                rec.error(exc, "step")
                raise
        finally:
            self._release()
        try:
            self._turns.stepped()
            if rec.file.due():
                rec.file.auto_flush()
        except Exception as exc:  # never break the training loop over recording trouble
            rec.file.trouble(exc)

    def _before_close(self) -> None:
        if self._rec.game >= 0:
            self._cut()
