"""Record PettingZoo environments: one episode stream per agent, games of agent-episodes.

- :class:`RecordParallelEvidence` — a PettingZoo ``BaseParallelWrapper`` over a ``ParallelEnv``.
- :class:`RecordAECEvidence` — a PettingZoo ``BaseWrapper`` over an ``AECEnv``.

This is the only module that imports ``pettingzoo`` (``episode_audit`` imports it lazily, so
PettingZoo stays optional). Layout (``docs/format.md``, "PettingZoo files"): every agent of
``possible_agents`` is a stream; a joint ``reset()`` starts a *game*, one episode per agent
(file-global episode indices, ``agent`` set, ``game`` = the game index), so ``check``'s
per-episode rules apply to each agent unchanged.

Parallel API: row ``t`` of an agent is its action at parallel step ``t`` and what that step
returned for it (observation, reward, terminated, truncated, info). An agent that leaves
mid-game ends its episode with its flags; an agent that appears mid-game begins its episode
(reset row = the observation it first appears with) in the same game.

AEC API (:class:`AECTurns`): row ``k`` of agent X is X's ``k``-th action. Its reward is the sum of
``env.rewards[X]`` over every ``step()`` from that action until X's next turn (the next time X is
``agent_selection``, live or dead), so X's return is the sum of ``env.rewards[X]`` over all
steps — what PettingZoo reported, never ``last()``'s cumulative reward summed again (which
double counts). Observation, flags and info of the row are X's at its next turn. X's reset row
is its observation at its first turn. Dead steps (``step(None)`` for a terminated/truncated X) are
not actions: they close X's last row; replay performs them itself. Rewards X receives before its
first action are added to its first row (noted ``reward_before_first_turn``). A ``step()`` that
raises is no row (as for a Gymnasium env): the other agents' rows still open (actions that did
complete) are closed with their state when it raised, and every open agent-episode of the game
ends ``error``; agents that had no turn yet get no reset row. When no agent-episode is left open
by then (each had ended by its flags: a dead step that raises after the game was decided), their
outcomes stand and the last row that ``step()`` closed is noted ``env_raised`` (the error and
whose step raised), so the file still says the env raised.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pettingzoo
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper, BaseWrapper
from typing_extensions import Unpack

from ..errors import ConfigurationError, RecorderError
from ..format.columns import error_text
from ..format.records import to_jsonable
from ..format.spaces import codec_for, describe_space
from .file import EvidenceFile
from .notes import note
from .seeding import capture_rng_state
from .settings import RecorderOptions, RecorderSettings, run_info
from .stream import Stream

__all__ = [
    "AECTurns",
    "RecordAECEvidence",
    "RecordParallelEvidence",
    "env_id_of",
    "env_module_of",
    "is_pettingzoo_module",
    "is_registered",
    "make_registered",
]

KIND_PARALLEL = "pettingzoo_parallel"
KIND_AEC = "pettingzoo_aec"
_MODULE_PATTERN = re.compile(r"^pettingzoo\.[a-z_]+\.[a-z0-9_]+_v\d+$")

RowFn = Callable[[str, Any, tuple[Any, float, bool, bool, Any], list[str]], None]
ResetFn = Callable[[str, Any, Any], None]
# a row held back (see RecordAECEvidence.step): its stream, the action and result, its notes
_Row = tuple[Stream, Any, tuple[Any, float, bool, bool, Any], list[str]]


def agent_result(
    agent: Any,
    obs: Mapping[Any, Any],
    rewards: Mapping[Any, Any],
    terminated: Mapping[Any, Any],
    truncated: Mapping[Any, Any],
    infos: Mapping[Any, Any],
) -> tuple[Any, Any, Any, Any, Any]:
    """One agent's share of a Parallel ``step()`` result, as a Gymnasium 5-tuple."""
    return (
        obs.get(agent),
        rewards.get(agent, math.nan),
        terminated.get(agent, False),
        truncated.get(agent, False),
        infos.get(agent, {}),
    )


def is_pettingzoo_module(name: str) -> bool:
    """Whether ``name`` is one of PettingZoo's own versioned env modules (safe to import).

    It must look like ``pettingzoo.<family>.<name>_v<N>`` and resolve to a file inside the
    installed ``pettingzoo`` package.

    >>> is_pettingzoo_module("pettingzoo.classic.tictactoe_v3")
    True
    >>> is_pettingzoo_module("os.path"), is_pettingzoo_module("pettingzoo.classic.nope_v1")
    (False, False)
    """
    if not _MODULE_PATTERN.match(name):
        return False
    try:
        spec = importlib.util.find_spec(name)
        root = importlib.util.find_spec("pettingzoo")
    except (ImportError, ValueError):
        return False
    if spec is None or spec.origin is None or root is None or root.origin is None:
        return False
    package = Path(root.origin).resolve().parent
    return package in Path(spec.origin).resolve().parents


def env_module_of(env: Any) -> str | None:
    """The PettingZoo env module (``pettingzoo.classic.tictactoe_v3``) ``env`` was made by.

    Found from the unwrapped env's class module (the family) and ``metadata["name"]``
    (``tictactoe_v3``); ``None`` when that does not name one of PettingZoo's own modules.
    """
    base = getattr(env, "unwrapped", env)
    name = (getattr(base, "metadata", None) or {}).get("name")
    parts = type(base).__module__.split(".")
    if not isinstance(name, str) or len(parts) < 2 or parts[0] != "pettingzoo":
        return None
    module = f"pettingzoo.{parts[1]}.{name}"
    return module if is_pettingzoo_module(module) else None


def _registry(kind: str) -> Mapping[str, Any] | None:
    """PettingZoo's env registry for a layout ``kind`` (``None`` before PettingZoo 1.27)."""
    name = "parallel_registry" if kind == KIND_PARALLEL else "aec_registry"
    registry = getattr(pettingzoo, name, None)
    return registry if isinstance(registry, Mapping) else None


def _entry_module(spec: Any) -> str | None:
    entry = getattr(spec, "entry_point", None)
    if isinstance(entry, str):
        return entry.partition(":")[0]
    module = getattr(entry, "__module__", None)
    return module if isinstance(module, str) else None


def env_id_of(env: Any, kind: str) -> str | None:
    """The id under which PettingZoo's registry makes ``env`` (``classic/tictactoe-v3``).

    ``kind`` picks the registry (``pettingzoo_aec``: ``pettingzoo.aec_registry``, else
    ``parallel_registry``). The id is that of the one registered spec whose entry point lives in
    the module of the unwrapped env's class and whose name and version are the env's
    ``metadata["name"]`` (``tictactoe_v3``); ``None`` when there is no such spec, or more than
    one, or PettingZoo has no registry (before 1.27).

    >>> import pettingzoo
    >>> env = pettingzoo.make("aec", "classic/tictactoe-v3")
    >>> env_id_of(env, "pettingzoo_aec"), env_id_of(env, "pettingzoo_parallel")
    ('classic/tictactoe-v3', None)
    """
    registry = _registry(kind)
    base = getattr(env, "unwrapped", env)
    name = (getattr(base, "metadata", None) or {}).get("name")
    if registry is None or not isinstance(name, str):
        return None
    wanted = re.sub(r"_v(?=\d+$)", "-v", name)
    module = type(base).__module__
    found = [
        str(env_id)
        for env_id, spec in registry.items()
        if str(env_id).rpartition("/")[2] == wanted and _entry_module(spec) == module
    ]
    return found[0] if len(found) == 1 else None


def is_registered(kind: str, env_id: str) -> bool:
    """Whether ``env_id`` is registered, exactly, in this process's PettingZoo ``kind`` registry.

    A dictionary lookup: nothing is imported. ``False`` before PettingZoo 1.27 (no registry).

    >>> is_registered("pettingzoo_parallel", "classic/rps-v2")
    True
    >>> is_registered("pettingzoo_parallel", "classic/tictactoe-v3")  # an AEC-only env
    False
    """
    registry = _registry(kind)
    return registry is not None and env_id in registry


def make_registered(kind: str, env_id: str, kwargs: Mapping[str, Any]) -> Any:
    """``pettingzoo.make("parallel" | "aec", env_id, **kwargs)`` (PettingZoo 1.27+)."""
    return pettingzoo.make("parallel" if kind == KIND_PARALLEL else "aec", env_id, **kwargs)


def _checked_env_id(env_id: str, kind: str) -> str:
    """The registered id ``env_id`` names (``classic/tictactoe`` -> ``classic/tictactoe-v3``)."""
    find = getattr(pettingzoo, "spec", None)
    if _registry(kind) is None or find is None:
        raise ConfigurationError(
            f"env_id={env_id!r}: this PettingZoo ({getattr(pettingzoo, '__version__', '?')}) "
            "has no env registry (PettingZoo 1.27+); leave env_id out"
        )
    try:
        spec = find("parallel" if kind == KIND_PARALLEL else "aec", env_id)
    except Exception as exc:
        api = "parallel" if kind == KIND_PARALLEL else "AEC"
        raise ConfigurationError(
            f"env_id={env_id!r} is not registered in PettingZoo's {api} registry "
            f"({type(exc).__name__}); register it with pettingzoo.register() first, "
            "or leave env_id out"
        ) from None
    return str(spec.id)


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


def _float(value: Any, notes: list[str], agent: str) -> float:
    try:
        return float(value)
    except Exception:
        notes.append(note("reward_not_numeric", f"agent {agent!r}: reward {value!r}"))
        return math.nan


class AECTurns:
    """Per-agent turn accounting of an AEC env (see the module docstring).

    Call :meth:`begin` after ``reset()``, :meth:`turn` just before each ``step(action)``,
    :meth:`stepped` just after it (or :meth:`failed` if it raised) and :meth:`finish` when the
    game is cut (next reset, close). ``on_reset(agent, obs, info)`` is called at an agent's first
    turn; ``on_row(agent, action, (obs, reward, terminated, truncated, info), notes)`` when one of
    its rows closes. The recorder and the replay share this class, so they account turns
    identically.
    """

    def __init__(self, env: Any, on_reset: ResetFn, on_row: RowFn) -> None:
        self.env = env
        self.on_reset = on_reset
        self.on_row = on_row
        self.pending: dict[str, list[Any]] = {}  # agent -> [action, reward, notes]
        self.early: dict[str, float] = {}  # rewards received before the first action
        self.started: set[str] = set()
        self.expected: list[str] = []
        self.acting: str | None = None  # whose row the last turn() opened

    def begin(self, agents: Sequence[str]) -> None:
        """A new game began with ``agents``."""
        self.pending = {}
        self.early = {}
        self.started = set()
        self.expected = list(agents)
        self.acting = None

    def _start(self, agent: str) -> None:
        if agent in self.started:
            return
        self.started.add(agent)
        env = self.env
        live = agent in env.agents
        obs = env.observe(agent) if live else None
        self.on_reset(agent, obs, env.infos.get(agent, {}) if live else {})

    def _close(self, agent: str) -> None:
        row = self.pending.pop(agent, None)
        if row is None:
            return
        action, reward, notes = row
        env = self.env
        if agent in env.agents:
            obs = env.observe(agent)
            term = env.terminations.get(agent, False)
            trunc = env.truncations.get(agent, False)
            info = env.infos.get(agent, {})
        else:
            obs, term, trunc, info = None, False, False, {}
        self.on_row(agent, action, (obs, reward, term, trunc, info), notes)

    def arrive(self) -> str:
        """``agent_selection``'s turn has come: begin it (reset row), close its open row.

        What :meth:`turn` does before the action; the replay calls it alone where the recorded
        actions run out. Returns the agent.
        """
        agent: str = self.env.agent_selection
        self._start(agent)
        self._close(agent)
        return agent

    def turn(self, action: Any) -> bool:
        """Account for ``step(action)`` about to run; return whether it is a dead step."""
        self.acting = None
        env = self.env
        agent = self.arrive()
        dead = bool(env.terminations.get(agent, False) or env.truncations.get(agent, False))
        if not dead:
            notes: list[str] = []
            reward = self.early.pop(agent, 0.0)
            if reward:
                notes.append(
                    note(
                        "reward_before_first_turn",
                        f"{reward!r} received before agent {agent!r} first acted; "
                        "added to its first step",
                    )
                )
            self.pending[agent] = [action, reward, notes]
            self.acting = agent
        return dead

    def failed(self) -> None:
        """The ``step()`` accounted by the last :meth:`turn` raised: the game's turns are over.

        Its action is no row (as a Gymnasium step that raises). The other open rows — actions
        whose step did complete — are closed with the env's state now; agents that had no turn
        get no reset row, and a later :meth:`finish` does nothing.
        """
        if self.acting is not None:
            self.pending.pop(self.acting, None)
        self.acting = None
        self.expected = []
        try:
            for agent in list(self.pending):
                self._close(agent)
        finally:
            self.pending = {}  # a row the env's state could not close is dropped, not kept

    def stepped(self) -> None:
        """Add the rewards the step just produced (``env.rewards``) to each agent's open row."""
        for agent, value in self.env.rewards.items():
            row = self.pending.get(agent)
            if row is not None:
                row[1] += _float(value, row[2], agent)
            elif agent not in self.started and value:
                self.early[agent] = self.early.get(agent, 0.0) + _float(value, [], agent)

    def finish(self) -> None:
        """Close every open row and start every agent still without a reset row."""
        for agent in self.expected:
            self._start(agent)
        for agent in list(self.pending):
            self._close(agent)


def _write_row(
    stream: Stream, action: Any, result: tuple[Any, float, bool, bool, Any], notes: list[str]
) -> None:
    """Record one AEC row of ``stream``, with the notes of the accounting itself."""
    stream.note_next_row(notes)
    stream.step(action, result)


class _Agents:
    """The recording state shared by both wrappers: the file, one stream per agent, games."""

    def __init__(
        self,
        env: Any,
        path: str | os.PathLike[str],
        kind: str,
        *,
        env_id: str | None,
        env_module: str | None,
        env_kwargs: Mapping[str, Any] | None,
        settings: RecorderSettings,
        owner: Any,
    ) -> None:
        agents = [str(a) for a in env.possible_agents]
        if not agents:
            raise ConfigurationError("the env has no possible_agents; nothing to record")
        obs_desc = describe_space(env.observation_space(env.possible_agents[0]))
        act_desc = describe_space(env.action_space(env.possible_agents[0]))
        for agent in env.possible_agents[1:]:
            if (
                describe_space(env.observation_space(agent)) != obs_desc
                or describe_space(env.action_space(agent)) != act_desc
            ):
                raise ConfigurationError(
                    f"agent {agent!r} has other observation/action spaces than "
                    f"{env.possible_agents[0]!r}; agents with different spaces are not "
                    "supported yet (record them in separate files)"
                )
        module = env_module if env_module is not None else env_module_of(env)
        registry_id = env_id_of(env, kind) if env_id is None else _checked_env_id(env_id, kind)
        base = env.unwrapped
        name = (getattr(base, "metadata", None) or {}).get("name")
        layout_notes: list[str] = []
        kwargs_json: Any = None
        if env_kwargs is not None:
            try:
                kwargs_json = to_jsonable(dict(env_kwargs))
            except (TypeError, ValueError) as exc:
                raise ConfigurationError(f"env_kwargs: not JSON-serializable ({exc})") from None
        else:
            layout_notes.append("env_kwargs not given: replay builds the env with its defaults")
        if module is None and registry_id is None:
            layout_notes.append(
                "the env id and module are unknown: replay needs --env-factory MODULE:CALLABLE"
            )
        layout: dict[str, Any] = {
            "kind": kind,
            "num_envs": 1,
            "agents": agents,
            "env_id": registry_id,
            "env_module": module,
            "env_name": name if isinstance(name, str) else type(base).__name__,
            "env_kwargs": kwargs_json,
            "max_cycles": getattr(base, "max_cycles", None),
            "notes": layout_notes,
        }
        info = run_info(
            settings=settings,
            spec=None,
            observation_space=obs_desc,
            action_space=act_desc,
            layout=layout,
        )
        self.run_info = dataclasses.replace(info, env_id=layout["env_name"])
        self.file = EvidenceFile(
            path,
            self.run_info,
            settings,
            games=True,
            owner=owner,
        )
        self.path = self.file.path
        obs_codec = codec_for(
            env.observation_space(env.possible_agents[0]),
            digest_min_bytes=settings.digest_min_bytes,
        )
        act_codec = codec_for(env.action_space(env.possible_agents[0]))
        max_cycles = layout["max_cycles"] if isinstance(layout["max_cycles"], int) else None
        self.streams: dict[Any, Stream] = {
            agent: self.file.add_stream(
                obs_codec, act_codec, agent=str(agent), max_episode_steps=max_cycles
            )
            for agent in env.possible_agents
        }
        self.file.start()
        self.unwrapped = base
        self.game = -1
        self.seed: Any = None
        self.options: Any = None
        self.rng: dict[str, Any] | None = None
        self.in_game: set[Any] = set()

    def new_game(self, seed: Any, options: Any) -> None:
        """End every open episode (``incomplete``) and note what the coming reset uses."""
        for stream in self.streams.values():
            stream.end_open()
        self.game += 1
        self.seed = seed
        self.options = options
        self.rng = capture_rng_state(self.unwrapped) if seed is None else None
        self.in_game = set()

    def begin(self, agent: Any) -> Any:
        """Begin ``agent``'s episode of the current game; return it (``None`` if not recorded)."""
        stream = self.streams.get(agent)
        if stream is None or agent in self.in_game:
            return None
        self.in_game.add(agent)
        notes: list[str] = []
        return stream.begin(self.seed, self.options, self.rng, notes, game=self.game), notes

    def reset_row(self, agent: Any, begun: Any, obs: Any, info: Any) -> None:
        if begun is None:
            return
        episode, notes = begun
        self.streams[agent].record_reset(episode, obs, info, notes)

    def error(self, exc: Exception, during: str) -> None:
        self.file.end_with_error(self.streams.values(), exc, during)


_ARGS_DOC = """
    Args:
        env: The PettingZoo env to record (every agent must share one observation space and
            one action space).
        path: The evidence file to create (never overwritten unless ``overwrite=True``).
        env_id: The id replay makes the env with, ``pettingzoo.make(api, env_id, **env_kwargs)``
            (PettingZoo 1.27+; must be registered, an unversioned id is recorded as the version
            it resolves to). Default: found in PettingZoo's registry (see
            :func:`env_id_of`), else none.
        env_module: The module replay builds the env from (default: found from the env, e.g.
            ``pettingzoo.classic.tictactoe_v3``; replay uses it when the file's ``env_id`` is not
            registered, importing it only if it is one of PettingZoo's own modules).
        env_kwargs: The keyword arguments the env was made with (JSON-serializable); replay
            passes them to ``pettingzoo.make`` or the module's ``env()`` / ``parallel_env()``.
            PettingZoo does not keep them, so without this replay uses the env's defaults.
        tags, reward_terms, constant_terms, ending_rules, info_keys, digest_min_bytes,
        block_steps, flush_every_s, fsync, overwrite, command_line: as for
            :class:`~episode_audit.RecordEvidence` (reward terms and endings are read from
            each agent's own info).
"""


class _Recording:
    """What both wrappers share: the recording's setup, ``flush()``, ``close()``, ``with``."""

    env: Any
    _rec: _Agents
    _closed: bool

    def _record_to(
        self,
        env: Any,
        path: str | os.PathLike[str],
        kind: str,
        settings: RecorderSettings,
        *,
        env_id: str | None,
        env_module: str | None,
        env_kwargs: Mapping[str, Any] | None,
    ) -> None:
        self._rec = _Agents(
            env,
            path,
            kind,
            env_id=env_id,
            env_module=env_module,
            env_kwargs=env_kwargs,
            settings=settings,
            owner=self,
        )
        self.run_info = self._rec.run_info
        self.path = self._rec.path
        self._closed = False

    def _before_close(self) -> None:
        """Called by :meth:`close` before the file is finished."""

    def flush(self) -> None:
        """Write everything recorded so far to the file now (open AEC rows stay open)."""
        self._rec.file.check_open()
        self._rec.file.flush()

    def close(self) -> None:
        """Finish the evidence file (open episodes become ``incomplete``) and close the env.

        Safe to call more than once. The env is closed even if finishing fails.
        """
        if getattr(self, "_closed", True):
            return
        self._closed = True
        try:
            self._before_close()
            self._rec.file.close()
        finally:
            self.env.close()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RecordParallelEvidence(_Recording, BaseParallelWrapper):  # type: ignore[misc]
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

    __doc__ = (__doc__ or "") + _ARGS_DOC

    def __init__(
        self,
        env: ParallelEnv,
        path: str | os.PathLike[str],
        *,
        env_id: str | None = None,
        env_module: str | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
        **options: Unpack[RecorderOptions],
    ) -> None:
        super().__init__(env)
        self._record_to(
            env,
            path,
            KIND_PARALLEL,
            RecorderSettings.of(options, "RecordParallelEvidence.__init__()"),
            env_id=env_id,
            env_module=env_module,
            env_kwargs=env_kwargs,
        )

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[Any, Any], dict[Any, dict[str, Any]]]:
        """Reset the env (a new game) and record every agent's reset row."""
        rec = self._rec
        rec.file.check_open()
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
                rec.file.flush()
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
        rec = self._rec
        if self._closed:
            rec.file.check_open()
        try:
            result = self.env.step(actions)
        except Exception as exc:
            rec.error(exc, "step")
            raise
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
            rec.file.trouble(exc)
        return result  # type: ignore[no-any-return]


class RecordAECEvidence(_Recording, BaseWrapper):  # type: ignore[misc]
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

    __doc__ = (__doc__ or "") + _ARGS_DOC

    def __init__(
        self,
        env: AECEnv,
        path: str | os.PathLike[str],
        *,
        env_id: str | None = None,
        env_module: str | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
        **options: Unpack[RecorderOptions],
    ) -> None:
        super().__init__(env)
        self._record_to(
            env,
            path,
            KIND_AEC,
            RecorderSettings.of(options, "RecordAECEvidence.__init__()"),
            env_id=env_id,
            env_module=env_module,
            env_kwargs=env_kwargs,
        )
        self._begun: dict[Any, Any] = {}
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
        rec = self._rec
        rec.file.check_open()
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
                rec.file.flush()
        except Exception as exc:  # never break the training loop over recording trouble
            rec.file.trouble(exc)

    def step(self, action: Any) -> None:
        """Step the env for ``agent_selection`` and account the turn (see :class:`AECTurns`).

        The rows the turn closes are held until the env's ``step()`` returned or raised: one
        that raised after every agent-episode had ended is noted on the last of them.
        """
        rec = self._rec
        if self._closed:
            rec.file.check_open()
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
                rec.file.flush()
        except Exception as exc:  # never break the training loop over recording trouble
            rec.file.trouble(exc)

    def _before_close(self) -> None:
        if self._rec.game >= 0:
            self._cut()
