"""What both PettingZoo recorders share: one stream per agent, games, the recording's lifecycle.

- :class:`AgentStreams` — the file, one stream per agent of ``possible_agents``, the games: a
  joint ``reset()`` starts one, one episode per agent (``docs/format.md``, "PettingZoo files").
- :class:`AgentRecorder` — the wrappers' setup, ``flush()``, ``close()`` and ``with``.
- :func:`agent_result` — one agent's share of a Parallel ``step()`` result.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from typing import Any

from typing_extensions import Unpack

from ...errors import ConfigurationError
from ...format.options import encode_typed, json_loss
from ...format.records import to_jsonable
from ...format.spaces import codec_for, describe_space
from ...format.unrecorded import UNRECORDED
from ..block import Episode
from ..file import EvidenceFile, FileRecorder
from ..notes import note
from ..seeding import capture_rng_state
from ..settings import RecorderOptions, RecorderSettings, check_options, run_info
from ..stream import Stream
from ..values import RecordedOptions, recordable_options
from .registry import checked_env_id, env_id_of, env_module_of, wrappers_of

__all__ = ["ARGS_DOC", "AgentRecorder", "AgentStreams", "agent_result"]

Begun = tuple[Episode, list[str]]


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


class AgentStreams:
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
        agents, obs_desc, act_desc = _shared_spaces(env)
        layout = _layout(env, kind, agents, env_id, env_module, env_kwargs)
        info = run_info(
            settings=settings,
            spec=None,
            observation_space=obs_desc,
            action_space=act_desc,
            layout=layout,
        )
        self.run_info = dataclasses.replace(info, env_id=layout["env_name"])
        self.file = EvidenceFile(path, self.run_info, settings, games=True, owner=owner)
        self.path = self.file.path
        first = env.possible_agents[0]
        obs_codec = codec_for(
            env.observation_space(first), digest_min_bytes=settings.digest_min_bytes
        )
        act_codec = codec_for(env.action_space(first))
        max_cycles = layout["max_cycles"] if isinstance(layout["max_cycles"], int) else None
        self.streams: dict[Any, Stream] = {
            agent: self.file.add_stream(
                obs_codec, act_codec, agent=str(agent), max_episode_steps=max_cycles
            )
            for agent in env.possible_agents
        }
        self.file.start()
        self.unwrapped = env.unwrapped
        self.game = -1
        self.seed: Any = None
        self.options: RecordedOptions | None = None
        self.rng: dict[str, Any] | None = None
        self.in_game: set[Any] = set()
        self.rendered = False  # render() was called
        self.render_note: str | None = None  # for the reset rows of the current game
        self._render_pending: str | None = None  # for those of the next game

    def new_game(self, seed: Any, options: Any) -> None:
        """End every open episode (``incomplete``) and note what the coming reset uses."""
        for stream in self.streams.values():
            stream.end_open()
        self.game += 1
        self.seed = seed
        self.options = recordable_options(options)  # (before the reset, which may change them)
        self.rng = capture_rng_state(self.unwrapped) if seed is None else None
        self.in_game = set()
        self.render_note, self._render_pending = self._render_pending, None

    def begin(self, agent: Any) -> Begun | None:
        """Begin ``agent``'s episode of the current game; return it (``None`` if not recorded)."""
        stream = self.streams.get(agent)
        if stream is None or agent in self.in_game:
            return None
        self.in_game.add(agent)
        notes: list[str] = [] if self.render_note is None else [self.render_note]
        return stream.begin(self.seed, self.options, self.rng, notes, game=self.game), notes

    def reset_row(self, agent: Any, begun: Begun | None, obs: Any, info: Any) -> None:
        """Record the reset row of the episode :meth:`begin` began for ``agent``, if any."""
        if begun is None:
            return
        episode, notes = begun
        self.streams[agent].record_reset(episode, obs, info, notes)

    def error(self, exc: Exception, during: str) -> None:
        """The env raised ``exc``: every open agent-episode ends ``error``."""
        self.file.end_with_error(self.streams.values(), exc, during)

    def note_render(self) -> None:
        """Note the recording's first ``render()`` (``rendered``) on the rows that follow it.

        On the next row of each of the game's agent-episodes, and on the reset rows of the next
        game (the call may have been the game's last). Replay does not render, and an env's
        steps may depend on it (pistonball's observations are the screen ``render()``
        redraws): a game that differs from then on is not a verdict on the env.
        """
        if self.rendered:
            return
        self.rendered = True
        when = f"in game {self.game}" if self.game >= 0 else "before the first reset()"
        text = note("rendered", f"render() called {when}; replay does not render")
        for agent in self.in_game:
            self.streams[agent].note_next_row([text])
        self._render_pending = text


def _shared_spaces(env: Any) -> tuple[list[str], dict[str, Any], dict[str, Any]]:
    """The agents, and the observation and action space every one of them must share."""
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
    return agents, obs_desc, act_desc


def _layout(
    env: Any,
    kind: str,
    agents: list[str],
    env_id: str | None,
    env_module: str | None,
    env_kwargs: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """The layout metadata of a PettingZoo file: how replay rebuilds the env."""
    module = env_module if env_module is not None else env_module_of(env)
    registry_id = env_id_of(env, kind) if env_id is None else checked_env_id(env_id, kind)
    base = env.unwrapped
    name = (getattr(base, "metadata", None) or {}).get("name")
    layout_notes: list[str] = []
    kwargs_json: Any = None
    kwargs_typed: str | None = None
    if env_kwargs is not None:
        kwargs_json, kwargs_typed = _recorded_kwargs(env_kwargs, layout_notes)
    else:
        layout_notes.append("env_kwargs not given: replay builds the env with its defaults")
    if module is None and registry_id is None:
        layout_notes.append(
            "the env id and module are unknown: replay needs --env-factory MODULE:CALLABLE"
        )
    return {
        "kind": kind,
        "num_envs": 1,
        "agents": agents,
        "env_id": registry_id,
        "env_module": module,
        "env_name": name if isinstance(name, str) else type(base).__name__,
        "env_kwargs": kwargs_json,
        **({} if kwargs_typed is None else {"env_kwargs_typed": kwargs_typed}),
        "max_cycles": getattr(base, "max_cycles", None),
        "wrappers": wrappers_of(env),
        "notes": layout_notes,
    }


def _recorded_kwargs(kwargs: Mapping[str, Any], notes: list[str]) -> tuple[Any, str | None]:
    """The env kwargs as JSON (``env_kwargs``), and their typed form when JSON changes them.

    Each kwarg JSON would change (a tuple, a numpy value, ``inf``, an int key) is a placeholder
    in the JSON, so a reader without ``env_kwargs_typed`` refuses to build the env from other
    kwargs than it had; the typed form (``format/options.py``) holds them all exactly, and
    kwargs it cannot hold are noted in ``notes`` (replay then needs an env factory). JSON that
    cannot hold them at all is misuse (``ConfigurationError``).
    """
    given = dict(kwargs)
    try:
        plain = to_jsonable(given)
        losses = {name: json_loss({name: value}) for name, value in given.items()}
    except (TypeError, ValueError, RecursionError) as exc:
        raise ConfigurationError(f"env_kwargs: not JSON-serializable ({exc})") from None
    changed = [name for name, loss in losses.items() if loss is not None]
    if not changed:
        return plain, None
    try:
        typed: str | None = encode_typed(given)
        held = "exact in env_kwargs_typed"
    except (TypeError, ValueError, RecursionError) as exc:
        typed, held = None, f"{exc}: replay needs an env factory"
        notes.append(f"env_kwargs {', '.join(changed)}: {losses[changed[0]]}; {held}")
    for name in changed:
        plain[str(name)] = {UNRECORDED: f"{type(given[name]).__qualname__} ({held})"}
    return plain, typed


ARGS_DOC = """
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
        env_kwargs: The keyword arguments the env was made with (JSON-serializable; tuples,
            numpy values, non-finite floats and int keys are held exactly too); replay passes
            them to ``pettingzoo.make`` or the module's ``env()`` / ``parallel_env()``.
            PettingZoo does not keep them, so without this replay uses the env's defaults.
        **options: The recorder options, as for :class:`~episode_audit.RecordEvidence` (see
            :class:`~episode_audit.record.settings.RecorderSettings`; reward terms and endings
            are read from each agent's own info).
"""
"""The arguments both wrappers' docstrings end with."""


class AgentRecorder(FileRecorder):
    """What both wrappers share: the recording's setup, ``flush()``, ``close()``, ``with``."""

    env: Any
    _rec: AgentStreams
    _warns_unclosed = False

    _kind: str  # the layout kind: KIND_PARALLEL or KIND_AEC

    def __init__(
        self,
        env: Any,
        path: str | os.PathLike[str],
        *,
        env_id: str | None = None,
        env_module: str | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
        **options: Unpack[RecorderOptions],
    ) -> None:
        check_options(options, f"{type(self).__name__}.__init__()")
        super().__init__(env)  # type: ignore[call-arg]  # the PettingZoo wrapper's, next in line
        self._rec = AgentStreams(
            env,
            path,
            self._kind,
            env_id=env_id,
            env_module=env_module,
            env_kwargs=env_kwargs,
            settings=RecorderSettings(**options),
            owner=self,
        )
        self._file = self._rec.file
        self.run_info = self._rec.run_info
        self.path = self._rec.path
        self._opened()
        self._started(env)

    def _started(self, env: Any) -> None:
        """Called at the end of ``__init__``, the file started (a wrapper's own state)."""

    def render(self) -> Any:
        """Render the env; the first call is noted ``rendered`` (replay does not render)."""
        self._rec.note_render()
        return self.env.render()

    def flush(self) -> None:
        """Write everything recorded so far to the file now (open AEC rows stay open)."""
        super().flush()

    def close(self) -> None:
        """Finish the evidence file (open episodes become ``incomplete``) and close the env.

        Safe to call more than once. The env is closed even if finishing fails.
        """
        self._close_file(lambda: self.env.close())

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
