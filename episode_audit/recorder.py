"""Recording wrappers: every step of every episode into one evidence file.

- :class:`RecordEvidence` — a ``gymnasium.Wrapper`` that writes seeds, RNG states, actions,
  observations, rewards and their named terms, ``terminated`` / ``truncated`` and each episode's
  outcome to an MCAP evidence file (see ``docs/format.md``).

The hot path only appends to column buffers; rows are turned into Arrow blocks when a block is
full, when ``flush_every_s`` has passed (checked on each step and reset), on ``flush()`` and on
``close()``. Episode records are written at those flushes too.
A bad value from the environment (a non-numeric reward or term, an observation that does not fit
its space, an info value JSON cannot hold) is recorded and noted, never raised into the training
loop. The wrapper raises only for misuse, e.g. stepping after ``close()``.
"""

from __future__ import annotations

import atexit
import math
import os
import platform
import sys
import time
import weakref
from array import array
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import pyarrow as pa
from gymnasium.envs.registration import EnvSpec

from . import format as fmt
from ._version import __version__
from .columns import TERMS_TYPE, terms_column
from .errors import ConfigurationError, RecorderError
from .outcomes import EndingRules, RewardTerms, TermsFn, find_time_limit, time_limit_hit
from .records import EPISODE_ARROW_SCHEMA, EPISODE_SCHEMA, RunInfo, to_json, to_jsonable
from .seeding import capture_rng_state
from .spaces import ColumnBuffer, SpaceCodec, codec_for, describe_space
from .writer import EvidenceWriter

__all__ = ["RecordEvidence", "library_versions"]

_INT64_MAX = 2**63 - 1
_NOTE_LIMIT = 300


def library_versions() -> dict[str, str]:
    """Versions of Python and of the libraries a rollout depends on (those imported).

    >>> sorted(library_versions())[:3]
    ['episode_audit', 'gymnasium', 'mcap']
    """
    import mcap

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "gymnasium": gym.__version__,
        "pyarrow": pa.__version__,
        "mcap": getattr(mcap, "__version__", "unknown"),
        "episode_audit": __version__,
    }
    for name in ("mujoco", "pettingzoo", "torch", "jax"):
        module = sys.modules.get(name)
        if module is not None:
            versions[name] = str(getattr(module, "__version__", "unknown"))
    return versions


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _note(code: str, message: str) -> str:
    return f"{code}: {message}"[:_NOTE_LIMIT]


class _Episode:
    """Running state of the open episode."""

    __slots__ = (
        "end_ns",
        "ended",
        "index",
        "notes",
        "options",
        "options_json",
        "ret",
        "rng_json",
        "rng_state",
        "seed",
        "start_ns",
        "steps",
        "totals",
    )

    def __init__(
        self,
        index: int,
        seed: int | None,
        rng_state: dict[str, Any] | None,
        options: Any,
        start_ns: int,
    ) -> None:
        self.index = index
        self.seed = seed
        self.rng_state = rng_state
        self.rng_json: bytes | None = None if rng_state is None else to_json(rng_state)
        self.options = options
        self.options_json: str | None = None if options is None else to_json(options).decode()
        self.start_ns = start_ns
        self.end_ns = start_ns
        self.steps = 0
        self.ret = 0.0
        self.totals: dict[str, float] = {}
        self.notes = 0
        self.ended = False


class _Block:
    """Column buffers of the steps (and resets) not yet written.

    Per step only the observation and action buffers and the ``times`` / ``rewards`` C arrays
    grow (plus the flat ``term_*`` arrays when the step has reward terms); the episode and step
    index columns, episode lengths, returns and term totals are derived at flush time from
    ``segments``; flags, outcomes, info and notes are kept sparsely, by row.
    """

    __slots__ = (
        "act",
        "ends",
        "episodes",
        "flags",
        "info",
        "notes",
        "obs",
        "reset_info",
        "reset_notes",
        "reset_obs",
        "resets",
        "rewards",
        "segments",
        "term_counts",
        "term_keys",
        "term_rows",
        "term_vals",
        "times",
    )

    def __init__(
        self, obs_codec: SpaceCodec, act_codec: SpaceCodec, episode: _Episode | None
    ) -> None:
        self.obs: ColumnBuffer = obs_codec.new_buffer()
        self.act: ColumnBuffer = act_codec.new_buffer()
        self.times = array("q")  # monotonic ns of each step
        self.rewards = array("d")
        # (first row, episode index, step index of that row, counted): a new one at every
        # reset; rows of a segment that is not counted were stepped after their episode ended.
        self.segments: list[tuple[int, int, int, bool]] = []
        self.episodes: dict[int, _Episode] = {}
        if episode is not None:
            self.add_segment(0, episode, episode.steps, not episode.ended)
        self.flags: dict[int, tuple[bool, bool]] = {}  # rows with terminated or truncated set
        # reward terms, flat: for each row that has terms, its row, count, keys and values
        self.term_rows = array("q")
        self.term_counts = array("q")
        self.term_keys: list[Any] = []
        self.term_vals = array("d")
        self.ends: dict[int, tuple[str, str | None]] = {}
        self.info: dict[int, dict[str, Any]] = {}
        self.notes: dict[int, list[str]] = {}
        # resets: (episode, monotonic ns, seed, rng_state JSON, options JSON)
        self.reset_obs: ColumnBuffer = obs_codec.new_buffer()
        self.resets: list[tuple[int, int, int | None, str | None, str | None]] = []
        self.reset_info: dict[int, dict[str, Any]] = {}
        self.reset_notes: dict[int, list[str]] = {}

    def add_segment(self, row: int, episode: _Episode, first_step: int, counted: bool) -> None:
        self.segments.append((row, episode.index, first_step, counted))
        self.episodes[episode.index] = episode

    def next_step_index(self) -> int:
        """The step index the next row of the last segment's episode gets."""
        row, _, first, _ = self.segments[-1]
        return first + len(self.times) - row

    def add_terms(self, row: int, keys: Any, values: list[float]) -> None:
        self.term_rows.append(row)
        self.term_counts.append(len(values))
        self.term_keys.extend(keys)
        self.term_vals.extend(values)


def _info_column(
    rows: int, info: dict[int, dict[str, Any]], notes: dict[int, list[str]]
) -> pa.Array:
    if not info:
        return pa.nulls(rows, pa.string())
    values: list[str | None] = [None] * rows
    for row, data in info.items():
        try:
            values[row] = to_json(data).decode()
        except (TypeError, ValueError):
            safe = {}
            for key, value in data.items():
                try:
                    to_json(value)
                    safe[key] = to_jsonable(value)
                except (TypeError, ValueError):
                    safe[key] = f"<unserializable {type(value).__name__}: {_short(value)}>"
                    notes.setdefault(row, []).append(
                        _note("info_unserializable", f"info[{key!r}] is a {type(value).__name__}")
                    )
            values[row] = to_json(safe).decode()
    return pa.array(values, pa.string())


def _notes_column(rows: int, notes: dict[int, list[str]]) -> pa.Array:
    if not notes:
        return pa.nulls(rows, pa.string())
    values: list[str | None] = [None] * rows
    for row, items in notes.items():
        values[row] = to_json(items).decode()
    return pa.array(values, pa.string())


class RecordEvidence(
    gym.Wrapper[gym.core.ObsType, gym.core.ActType, gym.core.ObsType, gym.core.ActType],
):
    """Record every step of every episode of an environment to an MCAP evidence file.

    Wrap the environment once; use it as usual; ``close()`` (or leaving a ``with`` block)
    finishes the file. Each episode stores the reset seed — or, for a reset without a seed, the
    env's RNG state captured just before it — so every episode can be replayed on its own.

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from episode_audit import RecordEvidence, open_evidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "cartpole.mcap"
        >>> with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), path) as env:
        ...     _ = env.reset(seed=5)
        ...     _ = env.action_space.seed(5)
        ...     for _ in range(3):
        ...         _ = env.step(env.action_space.sample())
        >>> ev = open_evidence(path)
        >>> ep = ev.episodes().to_pylist()[0]
        >>> ep["outcome"], ep["truncation_reason"], ep["seed"], ep["length"]
        ('truncated', 'time_limit', 5, 3)

    Args:
        env: The environment to record.
        path: The evidence file to create. An existing file is never overwritten unless
            ``overwrite=True``.
        tags: Free-form run tags (policy name, checkpoint, git commit, ...).
        reward_terms: Where a step's named reward terms come from: ``"auto"`` (``info
            ["reward_terms"]`` or ``info["reward_*"]``), a list of info keys, a callable
            ``info -> dict``, a :class:`RewardTerms`, or ``None``.
        constant_terms: Terms the env adds outside its info, declared once (``check`` adds
            them to every step's sum).
        ending_rules: How success, failure labels and truncation reasons are read.
        info_keys: Info keys to keep per step as JSON: a list of keys, or ``"all"``.
        digest_min_bytes: Store observation arrays of at least this many bytes as a 16-byte
            BLAKE2b digest instead of losslessly (for large images); ``None`` keeps all.
        block_steps: Steps per columnar block.
        flush_every_s: Flush at least this often (checked on every step and reset).
        fsync: ``fsync`` the file on every flush.
        overwrite: Allow replacing an existing file.
        command_line: The command line to store (defaults to ``sys.argv``).
    """

    def __init__(
        self,
        env: gym.Env[gym.core.ObsType, gym.core.ActType],
        path: str | os.PathLike[str],
        *,
        tags: Mapping[str, str] | None = None,
        reward_terms: RewardTerms | str | Sequence[str] | TermsFn | None = "auto",
        constant_terms: Mapping[str, float] | None = None,
        ending_rules: EndingRules | None = None,
        info_keys: Sequence[str] | str = (),
        digest_min_bytes: int | None = None,
        block_steps: int = 8192,
        flush_every_s: float = 1.0,
        fsync: bool = False,
        overwrite: bool = False,
        command_line: Sequence[str] | None = None,
    ) -> None:
        gym.Wrapper.__init__(self, env)
        if block_steps < 1:
            raise ConfigurationError(
                f"block_steps: expected an integer >= 1, actually: {block_steps!r}"
            )
        if not (flush_every_s > 0 and math.isfinite(flush_every_s)):
            raise ConfigurationError(
                f"flush_every_s: expected a positive number of seconds, actually: {flush_every_s!r}"
            )
        if isinstance(info_keys, str) and info_keys != "all":
            raise ConfigurationError(
                f"info_keys: expected a list of keys or 'all', actually: {info_keys!r}"
            )
        if isinstance(reward_terms, RewardTerms):
            if constant_terms:
                reward_terms = RewardTerms(
                    reward_terms.source, {**reward_terms.constants, **constant_terms}
                )
            self._terms_rule = reward_terms
        else:
            self._terms_rule = RewardTerms(reward_terms, dict(constant_terms or {}))
        self._rules = ending_rules or EndingRules()
        self._info_keys: tuple[str, ...] | None = None if info_keys == "all" else tuple(info_keys)
        self._keep_all_info = info_keys == "all"
        self._track_info = bool(self._keep_all_info or self._info_keys)
        self._extract_terms = self._terms_rule.extract
        self._block_steps = int(block_steps)
        self._flush_ns = int(flush_every_s * 1e9)

        self._obs_codec = codec_for(env.observation_space, digest_min_bytes=digest_min_bytes)
        self._act_codec = codec_for(env.action_space)
        self._time_limit = find_time_limit(env)
        self._unwrapped = env.unwrapped

        step_schema = pa.schema(
            [
                pa.field(fmt.COL_EPISODE, pa.int64(), nullable=False),
                pa.field(fmt.COL_STEP, pa.int64(), nullable=False),
                pa.field(fmt.COL_TIME, pa.int64(), nullable=False),
                self._act_codec.field(fmt.COL_ACTION),
                self._obs_codec.field(fmt.COL_OBSERVATION),
                pa.field(fmt.COL_REWARD, pa.float64(), nullable=False),
                pa.field(fmt.COL_TERMS, TERMS_TYPE),
                pa.field(fmt.COL_TERMINATED, pa.bool_(), nullable=False),
                pa.field(fmt.COL_TRUNCATED, pa.bool_(), nullable=False),
                pa.field(fmt.COL_OUTCOME, pa.string()),
                pa.field(fmt.COL_LABEL, pa.string()),
                pa.field(fmt.COL_INFO, pa.string()),
                pa.field(fmt.COL_NOTES, pa.string()),
            ]
        )
        reset_schema = pa.schema(
            [
                pa.field(fmt.COL_EPISODE, pa.int64(), nullable=False),
                pa.field("env_index", pa.int64(), nullable=False),
                pa.field(fmt.COL_TIME, pa.int64(), nullable=False),
                pa.field("seed", pa.int64()),
                pa.field("rng_state", pa.string()),
                pa.field("options", pa.string()),
                self._obs_codec.field(fmt.COL_OBSERVATION),
                pa.field(fmt.COL_INFO, pa.string()),
                pa.field(fmt.COL_NOTES, pa.string()),
            ]
        )
        self._step_schema = step_schema
        self._reset_schema = reset_schema
        self._episode_schema = pa.schema([f for f in EPISODE_ARROW_SCHEMA if f.name != "ended"])
        self._pending_episodes: list[tuple[_Episode, dict[str, Any]]] = []

        spec_json: dict[str, Any] | None = None
        spec_note: str | None = None
        if env.spec is not None:
            try:
                import json

                spec_json = json.loads(env.spec.to_json())
            except Exception as exc:
                spec_note = f"env spec is not JSON-serializable ({type(exc).__name__}: {exc})"
        run = RunInfo(
            format_version=fmt.FORMAT_VERSION,
            writer=f"episode-audit {__version__}",
            env_id=env.spec.id if env.spec is not None else None,
            env_spec=spec_json,
            observation_space=describe_space(env.observation_space),
            action_space=describe_space(env.action_space),
            reward_terms=self._terms_rule.describe(),
            ending_rules=self._rules.describe(),
            versions=library_versions(),
            platform=platform.platform(),
            command_line=list(sys.argv if command_line is None else command_line),
            start_time=datetime.now(timezone.utc).isoformat(),
            tags={str(k): str(v) for k, v in (tags or {}).items()},
            recorder={
                "block_steps": self._block_steps,
                "flush_every_s": flush_every_s,
                "digest_min_bytes": digest_min_bytes,
                "info_keys": "all" if self._keep_all_info else list(self._info_keys or ()),
                "notes": [spec_note] if spec_note else [],
            },
            layout={"kind": "single", "num_envs": 1, "agents": []},
        )
        self.run_info = run

        # Clock: monotonic for ordering, anchored to the wall clock once.
        self._clock = time.monotonic_ns
        self._wall_offset = time.time_ns() - time.monotonic_ns()

        self._writer = EvidenceWriter(
            path, library=f"episode-audit {__version__}", fsync=fsync, overwrite=overwrite
        )
        self.path = self._writer.path
        try:
            self._writer.add_metadata(fmt.METADATA_RUN, run.to_metadata())
            self._steps_channel = self._writer.register_arrow_channel(
                fmt.TOPIC_STEPS, fmt.SCHEMA_STEP_BLOCK, step_schema, {"agent": "", "env_index": "0"}
            )
            self._resets_channel = self._writer.register_arrow_channel(
                fmt.TOPIC_RESETS, fmt.SCHEMA_RESET_BLOCK, reset_schema, {"agent": ""}
            )
            self._episodes_channel = self._writer.register_json_channel(
                fmt.TOPIC_EPISODE_END, fmt.SCHEMA_EPISODE_END, EPISODE_SCHEMA
            )
            self._episode_blocks_channel = self._writer.register_arrow_channel(
                fmt.TOPIC_EPISODES, fmt.SCHEMA_EPISODE_BLOCK, self._episode_schema, {"agent": ""}
            )
            self._writer.flush()
        except BaseException:
            self._writer.abandon()
            raise

        self._episode: _Episode | None = None
        self._block = _Block(self._obs_codec, self._act_codec, None)
        self._next_episode = 0
        self._last_flush = self._clock()
        self._closed = False
        self._counts = {"episodes": 0, "steps": 0, "blocks": 0}
        _OPEN_RECORDERS.add(self)

    @property
    def spec(self) -> EnvSpec | None:  # type: ignore[override]
        """The wrapped env's spec: recording observes the env, it is not part of it.

        So ``gym.make(recorder.spec)`` builds the same env without a second recorder writing
        to the same file.
        """
        return self.env.spec

    # ------------------------------------------------------------------ helpers

    def _check_open(self) -> None:
        if self._closed:
            raise RecorderError(
                f"{self.path}: the recorder is closed; create a new RecordEvidence to record more"
            )

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[gym.core.ObsType, dict[str, Any]]:
        """Reset the env, recording the seed (or the RNG state), options and observation."""
        self._check_open()
        episode = self._episode
        if episode is not None and not episode.ended:
            self._end_episode(episode, fmt.OUTCOME_INCOMPLETE)
        rng_state = capture_rng_state(self._unwrapped) if seed is None else None
        index = self._next_episode
        self._next_episode += 1
        notes: list[str] = []
        recorded_seed = _recordable_seed(seed, notes)
        if seed is None and rng_state is None:
            notes.append(
                _note("rng_state_unavailable", "reset without a seed and the env has no np_random")
            )
        recorded_options: Any = None
        if options is not None:
            try:
                recorded_options = to_jsonable(options)
            except (TypeError, ValueError):
                notes.append(_note("options_unserializable", _short(options)))
                recorded_options = {"repr": _short(options)}
        episode = _Episode(index, recorded_seed, rng_state, recorded_options, self._clock())
        self._episode = episode
        self._block.add_segment(len(self._block.times), episode, 0, True)
        try:
            obs, info = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            self._end_episode(episode, fmt.OUTCOME_ERROR, error=(exc, "reset"))
            self._flush()
            raise
        try:
            self._record_reset(episode, obs, info, notes)
        except Exception as exc:  # never break the training loop over recording trouble
            self._recorder_trouble(exc)
        if self._clock() - self._last_flush >= self._flush_ns:
            self._flush()
        return obs, info

    def _record_reset(self, episode: _Episode, obs: Any, info: Any, notes: list[str]) -> None:
        block = self._block
        row = len(block.resets)
        rng_json = None if episode.rng_json is None else episode.rng_json.decode()
        _append_noted(block.reset_obs, obs, "observation", notes, "reset observation: ")
        if self._track_info or type(info) is not dict:
            kept = self._kept_info(info, notes)
            if kept:
                block.reset_info[row] = kept
        block.resets.append(
            (episode.index, episode.start_ns, episode.seed, rng_json, episode.options_json)
        )
        if notes:
            block.reset_notes[row] = notes
            episode.notes += 1

    def _kept_info(self, info: Any, notes: list[str]) -> dict[str, Any] | None:
        if not isinstance(info, Mapping):
            notes.append(_note("info_not_dict", f"info is a {type(info).__name__}"))
            return None
        if self._keep_all_info:
            return dict(info)
        keys = self._info_keys
        if not keys:
            return None
        return {k: info[k] for k in keys if k in info} or None

    def step(
        self, action: gym.core.ActType
    ) -> tuple[gym.core.ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env and record the step; the 5-tuple is returned untouched."""
        if self._closed:
            self._check_open()
        try:
            result = self.env.step(action)
        except Exception as exc:
            self._on_step_error(exc)
            raise
        # The hot path: appends only; lengths, returns and term totals are derived at flush.
        # Anything unusual goes to _record_step_slow.
        try:
            obs, reward, terminated, truncated, info = result
            episode = self._episode
            if episode is None or episode.ended or self._track_info:
                raise LookupError  # not the common case: take the slow path
            if not isinstance(info, dict):
                raise LookupError  # noted (info_not_dict) on the slow path
            # both flags' truth values, here: one without any (an array) takes the slow path
            running = (not terminated) & (not truncated)
            block = self._block
            terms = self._extract_terms(info) if info else None
            if terms is not None:
                # __float__, not float(): a str such as "1.5" is not a number (slow path)
                values = [v.__float__() for v in terms.values()]
            if block.obs.append(obs) is not None or block.act.append(action) is not None:
                raise LookupError  # a value was cast: note it on the slow path
            block.rewards.append(reward)  # type: ignore[arg-type]  # may raise: slow path
        except Exception:
            self._record_step_slow(result, action)
            return result
        row = len(block.times)
        if terms is not None:
            block.add_terms(row, terms, values)
        now = self._clock()
        block.times.append(now)  # commits the row
        if not running:
            self._end_by_flags(episode, block, row, terminated, truncated, info)
        if row + 1 >= self._block_steps or now - self._last_flush >= self._flush_ns:
            self._flush()
        return result

    def _record_step_slow(self, result: Any, action: Any) -> None:
        """Record a step the fast path declined; never raises into the training loop."""
        try:
            self._record_step(result, action)
        except Exception as exc:
            self._recorder_trouble(exc)

    def _record_step(self, result: Any, action: Any) -> None:
        block = self._block
        # The fast path may have appended the observation and/or action before bailing out:
        # roll back to the committed row count so every column stays aligned.
        rows = len(block.times)
        block.obs.truncate(rows)
        block.act.truncate(rows)
        del block.rewards[rows:]
        notes: list[str] = []
        try:
            obs, reward, terminated, truncated, info = result
        except Exception:
            notes.append(_note("step_result_invalid", f"step() returned {_short(result)}"))
            obs, reward, terminated, truncated, info = None, math.nan, False, False, {}
        episode = self._episode
        if episode is None:
            episode = self._implicit_episode(notes)
        try:
            terminated = bool(terminated)
            truncated = bool(truncated)
        except Exception:
            notes.append(
                _note(
                    "flags_not_bool",
                    f"terminated={_short(terminated)}, truncated={_short(truncated)}",
                )
            )
            terminated = truncated = False
        r, terms = self._slow_values(reward, info, notes)
        _append_noted(block.obs, obs, "observation", notes)
        _append_noted(block.act, action, "action", notes)
        if self._track_info:
            kept = self._kept_info(info, notes)
            if kept:
                block.info[rows] = kept
        if episode.ended:
            notes.append(_note("step_after_end", f"episode {episode.index} had already ended"))
            last = block.segments[-1] if block.segments else None
            if last is None or last[1] != episode.index or last[3]:
                # rows after the end keep the episode's step numbering but are not counted
                first = (
                    block.next_step_index()
                    if last is not None and last[1] == episode.index
                    else episode.steps
                )
                block.add_segment(rows, episode, first, False)
        block.rewards.append(r)
        if terms is not None:
            block.add_terms(rows, terms, list(terms.values()))
        if terminated or truncated:
            block.flags[rows] = (terminated, truncated)
        now = self._clock()
        block.times.append(now)  # commits the row
        if notes:
            block.notes[rows] = notes
            episode.notes += 1
        if (terminated or truncated) and not episode.ended:
            self._end_by_flags(
                episode,
                block,
                rows,
                terminated,
                truncated,
                info if isinstance(info, Mapping) else {},
            )
        if len(block.times) >= self._block_steps or now - self._last_flush >= self._flush_ns:
            self._flush()

    def _end_by_flags(
        self,
        episode: _Episode,
        block: _Block,
        row: int,
        terminated: bool,
        truncated: bool,
        info: Mapping[str, Any],
    ) -> None:
        ending = self._rules.classify(
            bool(terminated), bool(truncated), info, time_limit_hit=time_limit_hit(self._time_limit)
        )
        label = ending.failure_label if terminated else ending.truncation_reason
        block.ends[row] = (ending.outcome, label)
        block.flags[row] = (bool(terminated), bool(truncated))
        self._end_episode(
            episode,
            ending.outcome,
            failure_label=ending.failure_label,
            truncation_reason=ending.truncation_reason,
            terminated=bool(terminated),
            truncated=bool(truncated),
        )

    def _slow_values(
        self, reward: Any, info: Any, notes: list[str]
    ) -> tuple[float, dict[str, float] | None]:
        """Per-value handling of a reward and terms the fast path could not take."""
        try:
            r = _number(reward)
        except Exception:
            r = math.nan
            notes.append(_note("reward_not_numeric", f"reward {_short(reward)}"))
        if not isinstance(info, Mapping):
            notes.append(_note("info_not_dict", f"info is a {type(info).__name__}"))
            return r, None
        try:
            raw = self._terms_rule.extract(info)
        except Exception as exc:
            notes.append(_note("terms_unreadable", f"{type(exc).__name__}: {exc}"))
            return r, None
        if raw is None:
            return r, None
        terms: dict[str, float] = {}
        for key, value in raw.items():
            try:
                number = _number(value)
            except Exception:
                number = math.nan
                notes.append(_note("term_not_numeric", f"term {key!r} is {_short(value)}"))
            terms[key if isinstance(key, str) else str(key)] = number
        return r, terms

    def _implicit_episode(self, notes: list[str]) -> _Episode:
        index = self._next_episode
        self._next_episode += 1
        episode = _Episode(index, None, None, None, self._clock())
        self._episode = episode
        self._block.add_segment(len(self._block.times), episode, 0, True)
        notes.append(
            _note("stepped_before_reset", "the env was stepped before reset(); not replayable")
        )
        return episode

    def _on_step_error(self, exc: Exception) -> None:
        episode = self._episode
        if episode is None or episode.ended:
            return
        try:
            self._end_episode(episode, fmt.OUTCOME_ERROR, error=(exc, "step"))
            self._flush()
        except Exception as trouble:
            self._recorder_trouble(trouble)

    def _recorder_trouble(self, exc: Exception) -> None:
        """Something failed inside the recorder itself: warn once, keep the loop running."""
        if not getattr(self, "_warned", False):
            self._warned = True
            import warnings

            warnings.warn(
                f"episode-audit: recording to {self.path} failed ({type(exc).__name__}: {exc}); "
                "the training loop continues",
                RuntimeWarning,
                stacklevel=3,
            )

    def _end_episode(
        self,
        episode: _Episode,
        outcome: str,
        *,
        failure_label: str | None = None,
        truncation_reason: str | None = None,
        terminated: bool = False,
        truncated: bool = False,
        error: tuple[BaseException, str] | None = None,
    ) -> None:
        """Mark the episode ended; its record is written at the next flush (see _flush)."""
        episode.ended = True
        ending: dict[str, Any] = {
            "outcome": outcome,
            "failure_label": failure_label,
            "truncation_reason": truncation_reason,
            "terminated": terminated,
            "truncated": truncated,
            "error": None,
        }
        if error is not None:
            exc, during = error
            ending["error"] = {
                "type": type(exc).__qualname__,
                "message": str(exc)[:2000],
                "during": during,
            }
            ending["error_ns"] = self._clock()
        self._pending_episodes.append((episode, ending))
        self._counts["episodes"] += 1

    def _episode_record(self, episode: _Episode, ending: dict[str, Any]) -> dict[str, Any]:
        end_ns = ending.pop("error_ns", episode.end_ns)
        return {
            "episode": episode.index,
            "env_index": 0,
            "agent": None,
            "seed": episode.seed,
            "options": episode.options,
            **ending,
            "length": episode.steps,
            "return": episode.ret,
            "term_totals": episode.totals,
            "start_time_ns": episode.start_ns + self._wall_offset,
            "end_time_ns": end_ns + self._wall_offset,
            "notes": episode.notes,
        }

    def _write_episodes(self) -> None:
        """Write the episodes ended since the last flush: JSON messages and one Arrow block."""
        ended = self._pending_episodes
        if not ended:
            return
        self._pending_episodes = []
        pending = [(self._episode_record(ep, ending), ep.rng_json) for ep, ending in ended]
        write_json = self._writer.write_json
        channel = self._episodes_channel
        for record, rng_json in pending:
            # Optional fields that are null are left out (the JSON Schema marks them optional).
            # rng_state is already JSON (made once at reset): spliced in, not re-encoded.
            data = to_json({k: v for k, v in record.items() if v is not None})
            if rng_json is not None:
                data = data[:-1] + b',"rng_state":' + rng_json + b"}"
            write_json(channel, data, record["end_time_ns"])
        records = [r for r, _ in pending]

        def col(name: str) -> list[Any]:
            return [r[name] for r in records]

        errors = [r["error"] or {} for r in records]
        n = len(records)
        columns = {
            "episode": col("episode"),
            "env_index": col("env_index"),
            "agent": col("agent"),
            "seed": col("seed"),
            "rng_state": [None if j is None else j.decode() for _, j in pending],
            "options": [ep.options_json for ep, _ in ended],
            "outcome": col("outcome"),
            "failure_label": col("failure_label"),
            "truncation_reason": col("truncation_reason"),
            "terminated": col("terminated"),
            "truncated": col("truncated"),
            "length": col("length"),
            "return": col("return"),
            "start_time_ns": col("start_time_ns"),
            "end_time_ns": col("end_time_ns"),
            "error_type": [e.get("type") for e in errors],
            "error_message": [e.get("message") for e in errors],
            "error_during": [e.get("during") for e in errors],
            "notes": col("notes"),
        }
        arrays = [
            terms_column(n, dict(enumerate(col("term_totals"))))
            if name == "term_totals"
            else pa.array(columns[name], self._episode_schema.field(name).type)
            for name in self._episode_schema.names
        ]
        batch = pa.RecordBatch.from_arrays(arrays, schema=self._episode_schema)
        self._writer.write_batch(self._episode_blocks_channel, batch, records[-1]["end_time_ns"])

    # ------------------------------------------------------------------ flushing

    def _flush(self) -> None:
        block = self._block
        n = len(block.times)
        # Derive what the hot path did not keep: episode lengths, returns, end times, term
        # totals (before the next block starts counting from them).
        if n:
            episode, step = _index_columns(block.segments, n)
            terms = _apply_block(block, n, episode)
        self._block = _Block(self._obs_codec, self._act_codec, self._episode)
        offset = self._wall_offset
        if n:
            times = np.frombuffer(block.times, dtype=np.int64) + offset
            terminated = np.zeros(n, dtype=np.bool_)
            truncated = np.zeros(n, dtype=np.bool_)
            for row, (term, trunc) in block.flags.items():
                terminated[row] = term
                truncated[row] = trunc
            outcome: list[str | None] = [None] * n
            label: list[str | None] = [None] * n
            for row, (out, lab) in block.ends.items():
                outcome[row] = out
                label[row] = lab
            info = _info_column(n, block.info, block.notes)
            columns = [
                pa.array(episode),
                pa.array(step),
                pa.array(times),
                block.act.finish(),
                block.obs.finish(),
                pa.array(np.frombuffer(block.rewards, dtype=np.float64)),
                terms,
                pa.array(terminated),
                pa.array(truncated),
                pa.array(outcome, pa.string()),
                pa.array(label, pa.string()),
                info,
                _notes_column(n, block.notes),
            ]
            batch = pa.RecordBatch.from_arrays(columns, schema=self._step_schema)
            self._writer.write_batch(self._steps_channel, batch, int(times[-1]))
            self._counts["steps"] += n
            self._counts["blocks"] += 1
        if block.resets:
            n = len(block.resets)
            episode_r, mono_r, seeds, rng, options = zip(*block.resets, strict=True)
            times = np.fromiter(mono_r, dtype=np.int64, count=n) + offset
            columns = [
                pa.array(np.fromiter(episode_r, dtype=np.int64, count=n)),
                pa.array(np.zeros(n, dtype=np.int64)),
                pa.array(times),
                pa.array(seeds, pa.int64()),
                pa.array(rng, pa.string()),
                pa.array(options, pa.string()),
                block.reset_obs.finish(),
                _info_column(n, block.reset_info, block.reset_notes),
                _notes_column(n, block.reset_notes),
            ]
            batch = pa.RecordBatch.from_arrays(columns, schema=self._reset_schema)
            self._writer.write_batch(self._resets_channel, batch, int(times[-1]))
        self._write_episodes()
        self._writer.flush()
        self._last_flush = self._clock()

    def flush(self) -> None:
        """Write everything recorded so far to the file now."""
        self._check_open()
        self._flush()

    def close(self) -> None:
        """Finish the evidence file (an open episode is recorded as ``incomplete``) and close.

        Safe to call more than once. The environment is closed even if finishing fails.
        """
        if getattr(self, "_closed", True):
            return
        self._closed = True
        _OPEN_RECORDERS.discard(self)
        try:
            episode = self._episode
            if episode is not None and not episode.ended:
                self._end_episode(episode, fmt.OUTCOME_INCOMPLETE)
            self._flush()
            self._writer.finish(
                {
                    "status": "finished",
                    "episodes": str(self._counts["episodes"]),
                    "steps": str(self._counts["steps"]),
                    "blocks": str(self._counts["blocks"]),
                    "end_time": datetime.now(timezone.utc).isoformat(),
                }
            )
        except BaseException:
            self._writer.abandon()
            raise
        finally:
            super().close()

    @property
    def closed(self) -> bool:
        """Whether the evidence file has been finished."""
        return self._closed

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            import warnings

            warnings.warn(
                f"episode-audit: RecordEvidence for {getattr(self, 'path', '?')} was not closed; "
                "call close() or use it as a context manager",
                ResourceWarning,
                stacklevel=2,
            )


def _index_columns(
    segments: Sequence[tuple[int, int, int, bool]], n: int
) -> tuple[np.ndarray[Any, np.dtype[np.int64]], np.ndarray[Any, np.dtype[np.int64]]]:
    """Episode and step index per row, from the block's segments."""
    if not segments or segments[0][0] != 0:
        segments = [(0, -1, 0, False), *segments]  # rows before any reset: no episode
    starts = np.array([s[0] for s in segments], dtype=np.int64)
    lengths = np.diff(np.append(starts, n))
    episode = np.repeat(np.array([s[1] for s in segments], dtype=np.int64), lengths)
    first = np.repeat(np.array([s[2] for s in segments], dtype=np.int64) - starts, lengths)
    return episode, np.arange(n, dtype=np.int64) + first


def _apply_block(
    block: _Block, n: int, episode_col: np.ndarray[Any, np.dtype[np.int64]]
) -> pa.Array:
    """Add a block's rows to its episodes (length, return, end time, term totals).

    Returns the block's ``terms`` column. Rows stepped after an episode ended are not counted.
    """
    rewards = np.frombuffer(block.rewards, dtype=np.float64)
    segments = block.segments
    counted = np.zeros(n, dtype=np.bool_)
    for i, (start, index, _, live) in enumerate(segments):
        end = segments[i + 1][0] if i + 1 < len(segments) else n
        if end > start and live:
            ep = block.episodes[index]
            ep.steps += end - start
            ep.ret += float(np.add.reduce(rewards[start:end]))
            ep.end_ns = block.times[end - 1]
            counted[start:end] = True
    if not block.term_rows:
        return pa.nulls(n, TERMS_TYPE)
    rows = np.frombuffer(block.term_rows, dtype=np.int64)
    counts = np.frombuffer(block.term_counts, dtype=np.int64)
    values = np.frombuffer(block.term_vals, dtype=np.float64)
    keys = block.term_keys
    try:
        key_array = pa.array(keys, pa.string())
    except (pa.ArrowException, TypeError, ValueError):
        keys = [k if isinstance(k, str) else str(k) for k in keys]
        key_array = pa.array(keys, pa.string())
    per_value = np.repeat(rows, counts)
    keep = counted[per_value]
    totals = (
        pa.table({"e": pa.array(episode_col[per_value]), "k": key_array, "v": pa.array(values)})
        .filter(pa.array(keep))
        .group_by(["e", "k"], use_threads=False)
        .aggregate([("v", "sum")])
    )
    for e, k, v in zip(
        totals.column("e").to_pylist(),
        totals.column("k").to_pylist(),
        totals.column("v_sum").to_pylist(),
        strict=True,
    ):
        ep_totals = block.episodes[e].totals
        ep_totals[k] = ep_totals.get(k, 0.0) + v
    row_counts = np.zeros(n, dtype=np.int64)
    row_counts[rows] = counts
    offsets = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(row_counts, out=offsets[1:])
    valid = np.zeros(n, dtype=np.bool_)
    valid[rows] = True
    return pa.MapArray.from_arrays(
        pa.array(offsets), key_array, pa.array(values), mask=pa.array(~valid)
    )


def _number(value: Any) -> float:
    """``float(value)`` for numbers only: text such as ``"1.5"`` raises ``TypeError``."""
    if isinstance(value, (str, bytes, bytearray)):
        raise TypeError(f"{type(value).__name__} is not a number")
    return float(value)


def _append_noted(
    buffer: ColumnBuffer, value: Any, what: str, notes: list[str], context: str = ""
) -> None:
    """Append ``value``; a cast or a value that does not fit (stored as null) gets a note."""
    try:
        cast = buffer.append(value)
    except (ValueError, TypeError) as exc:
        buffer.append_null()
        notes.append(_note(f"{what}_invalid", f"{context}{exc}"))
        return
    if cast is not None:
        notes.append(_note(f"{what}_cast", cast))


def _recordable_seed(seed: Any, notes: list[str]) -> int | None:
    """The seed as an int64 for the file, or ``None`` (with a note) when it does not fit."""
    if seed is None:
        return None
    if type(seed) is int and 0 <= seed <= _INT64_MAX:
        return seed
    try:
        value = int(seed)
    except (TypeError, ValueError):
        value = -1
    if 0 <= value <= _INT64_MAX:
        return value
    notes.append(_note("seed_out_of_range", f"seed {_short(seed)} is not an int64; not replayable"))
    return None


_OPEN_RECORDERS: weakref.WeakSet[RecordEvidence[Any, Any]] = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:
    """Finish files whose recorder was never closed when the interpreter exits normally."""
    for recorder in list(_OPEN_RECORDERS):
        try:
            recorder.close()
        except Exception:
            pass
