"""The recording core: one evidence file (:class:`EvidenceFile`), one or many episode streams.

A *stream* is a sequence of episodes of one actor: the single env of
:class:`~episode_audit.record.gym.RecordEvidence`, one sub-env of a vector env, or one agent of a
PettingZoo env. Every stream of a file has its own step and reset channels (channel metadata
``env_index`` and ``agent``); episode indices are file-global and unique, episode records of all
streams share one channel (see ``docs/format.md``, "Multi-stream files").

- :class:`EvidenceFile` owns the file: the writer, the run metadata, the episode channels, the
  clock, flush timing, counts, ``close()`` and the close-at-exit registry.
- :class:`Stream` owns one stream's episode state machine and column buffers: episodes begin with
  :meth:`Stream.begin` (+ :meth:`Stream.record_reset`), grow with :meth:`Stream.step`, and end by
  their flags, :meth:`Stream.end_open` (``incomplete``) or :meth:`Stream.end_error`.

The hot path (:meth:`Stream.step`) only appends to column buffers; rows become Arrow blocks when a
block is full, when ``flush_every_s`` has passed, on ``flush()`` and on ``close()``; episode
records are written at those flushes too. A bad value from the environment is recorded and noted,
never raised into the training loop.
"""

from __future__ import annotations

import atexit
import math
import operator
import os
import platform
import sys
import time
import weakref
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import datetime, timezone
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import pyarrow as pa
from gymnasium.wrappers import TimeLimit

from .._version import __version__
from ..errors import ConfigurationError, RecorderError
from ..format import names as fmt
from ..format.columns import (
    TERMS_TYPE,
    error_message,
    error_text,
    number,
    terms_column,
    text,
    text_array,
)
from ..format.records import EPISODE_SCHEMA, RunInfo, to_json, to_jsonable
from ..format.schemas import EPISODE_BLOCK_BASE, EPISODE_BLOCK_SCHEMA, reset_schema, step_schema
from ..format.spaces import ColumnBuffer, SpaceCodec
from .rules import (
    EndingRules,
    RewardTerms,
    TermsFn,
    named_terms,
    plain_names,
    time_limit_hit,
)
from .rules import note as note  # the recorders' note helpers (re-exported)
from .rules import short as short
from .writer import EvidenceWriter

__all__ = ["EvidenceFile", "RecorderSettings", "Stream", "library_versions"]

_INT64_MAX = 2**63 - 1
_TROUBLE_TEXT = 500  # characters of the first trouble kept in the run-end record


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


DEFAULT_BLOCK_STEPS = 32_768
"""Steps per columnar block unless told otherwise. Larger blocks cost the recorder a little
memory (flushes every ``flush_every_s`` bound what a crash can lose either way) and make every
read faster: ``check`` decodes a 1 M-step CartPole file ~25 % faster than with 8 192."""


class RecorderSettings:
    """The recorder options every wrapper takes, checked once (see :class:`RecordEvidence`)."""

    __slots__ = (
        "block_steps",
        "digest_min_bytes",
        "flush_every_s",
        "info_keys",
        "keep_all_info",
        "rules",
        "terms_rule",
        "track_info",
    )

    def __init__(
        self,
        *,
        reward_terms: RewardTerms | str | Sequence[str] | TermsFn | None = "auto",
        constant_terms: Mapping[str, float] | None = None,
        ending_rules: EndingRules | None = None,
        info_keys: Sequence[str] | str = (),
        digest_min_bytes: int | None = None,
        block_steps: int = DEFAULT_BLOCK_STEPS,
        flush_every_s: float = 1.0,
    ) -> None:
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
            self.terms_rule = reward_terms
        else:
            self.terms_rule = RewardTerms(reward_terms, dict(constant_terms or {}))
        self.rules = ending_rules or EndingRules()
        self.info_keys: tuple[str, ...] | None = None if info_keys == "all" else tuple(info_keys)
        self.keep_all_info = info_keys == "all"
        self.track_info = bool(self.keep_all_info or self.info_keys)
        self.digest_min_bytes = digest_min_bytes
        self.block_steps = int(block_steps)
        self.flush_every_s = flush_every_s

    def recorder_metadata(self, notes: Sequence[str] = ()) -> dict[str, Any]:
        """The ``recorder`` key of the run metadata."""
        return {
            "block_steps": self.block_steps,
            "flush_every_s": self.flush_every_s,
            "digest_min_bytes": self.digest_min_bytes,
            "info_keys": "all" if self.keep_all_info else list(self.info_keys or ()),
            "notes": list(notes),
        }


def run_info(
    *,
    settings: RecorderSettings,
    spec: Any,
    observation_space: dict[str, Any],
    action_space: dict[str, Any],
    tags: Mapping[str, str] | None,
    command_line: Sequence[str] | None,
    layout: dict[str, Any],
    notes: Sequence[str] = (),
) -> RunInfo:
    """The run metadata of a recording of an env with ``spec`` (an ``EnvSpec`` or ``None``)."""
    spec_json: dict[str, Any] | None = None
    notes = list(notes)
    if spec is not None:
        try:
            import json

            spec_json = json.loads(spec.to_json())
        except Exception as exc:
            notes.append(f"env spec is not JSON-serializable ({type(exc).__name__}: {exc})")
    return RunInfo(
        format_version=fmt.FORMAT_VERSION,
        writer=f"episode-audit {__version__}",
        env_id=spec.id if spec is not None else None,
        env_spec=spec_json,
        observation_space=observation_space,
        action_space=action_space,
        reward_terms=settings.terms_rule.describe(),
        ending_rules=settings.rules.describe(),
        versions=library_versions(),
        platform=platform.platform(),
        command_line=list(sys.argv if command_line is None else command_line),
        start_time=datetime.now(timezone.utc).isoformat(),
        tags={str(k): str(v) for k, v in (tags or {}).items()},
        recorder=settings.recorder_metadata(notes),
        layout=layout,
    )


class _Episode:
    """Running state of one open episode of a stream."""

    __slots__ = (
        "after_end",
        "agent",
        "end_ns",
        "ended",
        "env_index",
        "game",
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
        env_index: int = 0,
        agent: str | None = None,
        game: int | None = None,
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
        self.after_end = 0  # rows stepped after it ended, in blocks already written
        self.ret = 0.0
        self.totals: dict[str, float] = {}
        self.notes = 0
        self.ended = False
        self.env_index = env_index
        self.agent = agent
        self.game = game

    def next_step(self) -> int:
        """The step index of its next row in a new block (rows after its end number on)."""
        return self.steps + self.after_end


class _Block:
    """Column buffers of one stream's steps (and resets) not yet written.

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
        "pending",
        "raw_names",
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
            self.add_segment(0, episode, episode.next_step(), not episode.ended)
        self.flags: dict[int, tuple[bool, bool]] = {}  # rows with terminated or truncated set
        # reward terms, flat: for each row that has terms, its row, count, keys and values
        self.term_rows = array("q")
        self.term_counts = array("q")
        self.term_keys: list[Any] = []
        self.term_vals = array("d")
        # whether add_terms took keys as an extractor gave them (named at flush: _apply_block)
        self.raw_names = False
        self.ends: dict[int, tuple[str, str | None]] = {}
        self.info: dict[int, dict[str, Any]] = {}
        self.notes: dict[int, list[str]] = {}
        # resets: (episode, monotonic ns, seed, rng_state JSON, options JSON, game)
        self.reset_obs: ColumnBuffer = obs_codec.new_buffer()
        self.resets: list[tuple[int, int, int | None, str | None, str | None, int | None]] = []
        self.reset_info: dict[int, dict[str, Any]] = {}
        self.reset_notes: dict[int, list[str]] = {}
        # rows a batching recorder has taken but not yet handed over with Stream.extend
        self.pending = 0

    def rows(self) -> int:
        """Rows of the block, counting the ``pending`` ones not yet handed over."""
        return len(self.times) + self.pending

    def add_segment(self, row: int, episode: _Episode, first_step: int, counted: bool) -> None:
        self.segments.append((row, episode.index, first_step, counted))
        self.episodes[episode.index] = episode

    def next_step_index(self) -> int:
        """The step index the next row of the last segment's episode gets."""
        row, _, first, _ = self.segments[-1]
        return first + self.rows() - row

    def add_terms(self, row: int, keys: Any, values: list[float]) -> None:
        """Add a row's terms, its keys as they are (named by the one rule at flush)."""
        self.raw_names = True
        self.term_rows.append(row)
        self.term_counts.append(len(values))
        self.term_keys.extend(keys)
        self.term_vals.extend(values)


def _info_column(
    rows: int,
    info: dict[int, dict[str, Any]],
    notes: dict[int, list[str]],
    episode_of: Callable[[int], _Episode | None],
) -> pa.Array:
    """The ``info`` column of ``rows`` rows: each kept info as JSON (null where none).

    A value JSON cannot hold is written as its ``repr`` and noted ``info_unserializable`` in
    ``notes``, counted in the episode ``episode_of(row)`` (see :func:`_add_notes`).
    """
    if not info:
        return pa.nulls(rows, pa.string())
    values: list[str | None] = [None] * rows
    for row, data in info.items():
        try:
            values[row] = to_json(data).decode()
        except Exception:  # TypeError, ValueError, RecursionError (a cycle), a raising __str__
            safe: dict[str, Any] = {}
            for key, value in data.items():
                name = key if isinstance(key, str) else short(key)
                try:
                    to_json(value)
                    safe[name] = to_jsonable(value)
                except Exception:
                    safe[name] = f"<unserializable {type(value).__name__}: {short(value)}>"
                    what = f"info[{short(key)}] is a {type(value).__name__}"
                    _add_notes(episode_of(row), notes, row, [note("info_unserializable", what)])
            values[row] = to_json(safe).decode()
    return pa.array(values, pa.string())


def _notes_column(rows: int, notes: dict[int, list[str]]) -> pa.Array:
    if not notes:
        return pa.nulls(rows, pa.string())
    values: list[str | None] = [None] * rows
    for row, items in notes.items():
        values[row] = to_json(items).decode()
    return pa.array(values, pa.string())


class _Owner(Protocol):
    def close(self) -> None: ...


CHUNK_TARGET_BYTES = 32 << 20
"""Largest uncompressed chunk the recorder aims for: a flush comes after at most this many
bytes of step rows over every stream, whatever ``block_steps`` says (large observations), so
the rows a recorder holds stay small and files stay far inside the reader's 1 GiB record cap
(``reader.MAX_RECORD_BYTES``)."""

_OTHER_COLUMNS_BYTES = 64  # episode, step, time, reward, flags, offsets of a step row


def _type_bytes(kind: pa.DataType) -> int:
    """Bytes of one value of ``kind`` (a guess of 64 for variable-size types)."""
    if pa.types.is_fixed_size_list(kind):
        return int(kind.list_size) * _type_bytes(kind.value_type)
    if pa.types.is_struct(kind):
        return sum(_type_bytes(kind.field(i).type) for i in range(kind.num_fields))
    try:
        return max(1, int(kind.bit_width) // 8)
    except ValueError:
        return 64


class EvidenceFile:
    """One evidence file being recorded: run metadata, episode channels, flushes, close.

    Streams are added with :meth:`add_stream`; :meth:`flush` writes every stream's pending
    blocks and the records of the episodes ended since the previous flush, in one chunk.

    Args:
        path: The evidence file to create (never overwritten unless ``overwrite``).
        run: The run metadata (``layout`` says how many streams there are and of what kind).
        settings: The recorder settings (the same for every stream).
        fsync: ``fsync`` the file on every flush.
        overwrite: Allow replacing an existing file.
        games: Whether episode records and reset rows carry a ``game`` (PettingZoo files).
        owner: The wrapper to ``close()`` when the interpreter exits with the file still open.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        run: RunInfo,
        settings: RecorderSettings,
        *,
        fsync: bool = False,
        overwrite: bool = False,
        games: bool = False,
        owner: _Owner | None = None,
    ) -> None:
        self.run = run
        self.settings = settings
        self.games = games
        self.multi = run.layout.get("kind", "single") != "single"
        self.block_steps = settings.block_steps
        self.flush_ns = int(settings.flush_every_s * 1e9)
        # Clock: monotonic for ordering, anchored to the wall clock once.
        self.clock = time.monotonic_ns
        self.wall_offset = time.time_ns() - time.monotonic_ns()
        self._episode_schema = EPISODE_BLOCK_SCHEMA if games else EPISODE_BLOCK_BASE
        self.pending: list[tuple[_Episode, dict[str, Any]]] = []
        self.streams: list[Stream] = []
        # called first by every flush (a batching recorder hands over its rows)
        self.before_flush: list[Callable[[], None]] = []
        self.writer = EvidenceWriter(
            path, library=f"episode-audit {__version__}", fsync=fsync, overwrite=overwrite
        )
        self.path = self.writer.path
        try:
            self.writer.add_metadata(fmt.METADATA_RUN, run.to_metadata())
        except BaseException:
            self.writer.abandon()
            raise
        self._episodes_channel = self._episode_blocks_channel = -1
        self.started = False
        self.next_episode = 0
        self.last_flush = self.clock()
        self.flush_at = self.last_flush + self.flush_ns  # when flush_every_s will have passed
        self.closed = False
        self.counts = {"episodes": 0, "steps": 0, "blocks": 0, "success_reported": 0}
        self._warned = False
        self.troubles = 0  # the recorder's own failures, said in the run-end record
        self.first_trouble: str | None = None
        if owner is not None:
            _OPEN_RECORDERS.add(owner)
        self._owner = owner

    def start(self) -> None:
        """Register the episode channels (after every stream's) and flush the file's head.

        Call once, after the last :meth:`add_stream`; the channels of a single-stream file are
        then numbered as they always were (steps, resets, episode records, episode blocks).
        ``block_steps`` is lowered here when the streams' rows are so large that a chunk would
        outgrow :data:`CHUNK_TARGET_BYTES`.
        """
        if self.started:
            raise RecorderError(f"{self.path}: the evidence file is already started")
        writer = self.writer
        try:
            self._episodes_channel = writer.register_json_channel(
                fmt.TOPIC_EPISODE_END, fmt.SCHEMA_EPISODE_END, EPISODE_SCHEMA
            )
            self._episode_blocks_channel = writer.register_arrow_channel(
                fmt.TOPIC_EPISODES, fmt.SCHEMA_EPISODE_BLOCK, self._episode_schema, {"agent": ""}
            )
            writer.flush()
        except BaseException:
            writer.abandon()
            raise
        row_bytes = sum(stream.row_bytes for stream in self.streams)
        self.block_steps = max(1, min(self.block_steps, CHUNK_TARGET_BYTES // max(1, row_bytes)))
        for stream in self.streams:
            stream.cap_block_steps(self.block_steps)
        self.started = True

    def add_stream(
        self,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int = 0,
        agent: str | None = None,
        time_limit: TimeLimit[Any, Any] | None = None,
        max_episode_steps: int | None = None,
    ) -> Stream:
        """Register a stream's step and reset channels and return the stream.

        Truncations count as ``time_limit`` when ``time_limit`` (a Gymnasium ``TimeLimit``
        wrapper) says its limit was hit, or, without one, when the episode reached
        ``max_episode_steps``.
        """
        if self.started:
            raise RecorderError(f"{self.path}: streams are added before start()")
        stream = Stream(
            self,
            obs_codec,
            act_codec,
            env_index=env_index,
            agent=agent,
            time_limit=time_limit,
            max_episode_steps=max_episode_steps,
        )
        self.streams.append(stream)
        return stream

    def check_open(self) -> None:
        """Raise :class:`RecorderError` when the file is closed."""
        if self.closed:
            raise RecorderError(
                f"{self.path}: the recorder is closed; create a new recorder to record more"
            )

    def take_episode_index(self) -> int:
        """The next file-global episode index."""
        index = self.next_episode
        self.next_episode += 1
        return index

    def due(self) -> bool:
        """Whether ``flush_every_s`` has passed since the last flush."""
        return self.clock() >= self.flush_at

    def trouble(self, exc: Exception) -> None:
        """Something failed inside the recorder itself: warn once, keep the loop running.

        The run-end record counts them and keeps the first (``recorder_trouble``), so the file
        says the evidence may miss what was being recorded then.
        """
        self.troubles += 1
        if self.first_trouble is None:
            self.first_trouble = error_text(exc)[:_TROUBLE_TEXT]
        if not self._warned:
            self._warned = True
            import warnings

            warnings.warn(
                f"episode-audit: recording to {self.path} failed ({type(exc).__name__}: {exc}); "
                "the training loop continues",
                RuntimeWarning,
                stacklevel=4,
            )

    # ------------------------------------------------------------------ episode records

    def _episode_record(self, episode: _Episode, ending: dict[str, Any]) -> dict[str, Any]:
        end_ns = ending.pop("error_ns", episode.end_ns)
        record = {
            "episode": episode.index,
            "env_index": episode.env_index,
            "agent": episode.agent,
            "seed": episode.seed,
            "options": episode.options,
            **ending,
            "length": episode.steps,
            "return": episode.ret,
            "term_totals": episode.totals,
            "start_time_ns": episode.start_ns + self.wall_offset,
            "end_time_ns": end_ns + self.wall_offset,
            "notes": episode.notes,
        }
        if self.games:
            record["game"] = episode.game
        return record

    def _write_episodes(self) -> None:
        """Write the episodes ended since the last flush: JSON messages and one Arrow block."""
        ended = self.pending
        if not ended:
            return
        self.pending = []
        pending = [(self._episode_record(ep, ending), ep.rng_json) for ep, ending in ended]
        write_json = self.writer.write_json
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
            "game": [r.get("game") for r in records],
        }
        arrays = [
            terms_column(n, dict(enumerate(col("term_totals"))))
            if name == "term_totals"
            else pa.array(columns[name], self._episode_schema.field(name).type)
            for name in self._episode_schema.names
        ]
        batch = pa.RecordBatch.from_arrays(arrays, schema=self._episode_schema)
        self.writer.write_batch(self._episode_blocks_channel, batch, records[-1]["end_time_ns"])

    # ------------------------------------------------------------------ flushing, closing

    def flush(self) -> None:
        """Write every stream's pending rows and the ended episodes' records, in one chunk."""
        for hook in self.before_flush:
            hook()
        for stream in self.streams:
            stream.write_blocks()
        self._write_episodes()
        self.writer.flush()
        self.last_flush = self.clock()
        self.flush_at = self.last_flush + self.flush_ns

    def end_with_error(self, streams: Iterable[Stream], exc: BaseException, during: str) -> None:
        """The env raised ``exc``: end the streams' open episodes as ``error``, written now.

        A failure here is the recorder's trouble (warned once): the loop then sees the env's
        own error, never one of the recorder's.
        """
        try:
            for stream in streams:
                stream.end_error(exc, during)
            self.flush()
        except Exception as trouble:
            self.trouble(trouble)

    def auto_flush(self) -> None:
        """:meth:`flush` because a block filled or ``flush_every_s`` passed.

        This runs inside the training loop: a failure is the recorder's trouble (warned once),
        never the loop's.
        """
        try:
            self.flush()
        except Exception as exc:
            self.flush_at = self.clock() + self.flush_ns  # not again on every step
            self.trouble(exc)

    def close(self) -> None:
        """End every open episode as ``incomplete``, flush, and finish the file.

        Safe to call more than once.
        """
        if self.closed:
            return
        self.closed = True
        if self._owner is not None:
            _OPEN_RECORDERS.discard(self._owner)
        try:
            for stream in self.streams:
                stream.end_open()
            self.flush()
            run_end = {
                "status": "finished",
                "episodes": str(self.counts["episodes"]),
                "steps": str(self.counts["steps"]),
                "blocks": str(self.counts["blocks"]),
                "end_time": datetime.now(timezone.utc).isoformat(),
                fmt.RUN_END_SUCCESS_REPORTED: str(self.counts["success_reported"]),
            }
            if self.troubles:
                run_end[fmt.RUN_END_TROUBLE] = str(self.troubles)
                run_end[fmt.RUN_END_FIRST_TROUBLE] = text(self.first_trouble or "")
            self.writer.finish(run_end)
        except BaseException:
            self.writer.abandon()
            raise


class Stream:
    """One stream of episodes in an :class:`EvidenceFile` (make it with ``add_stream``).

    A recorder drives it: :meth:`begin` then the env's reset then :meth:`record_reset`; then
    :meth:`step` per step. Episodes end by their flags (classified by the file's ending rules),
    by :meth:`end_open` (``incomplete``) or by :meth:`end_error`.
    """

    def __init__(
        self,
        file: EvidenceFile,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int = 0,
        agent: str | None = None,
        time_limit: TimeLimit[Any, Any] | None = None,
        max_episode_steps: int | None = None,
    ) -> None:
        settings = file.settings
        self.file = file
        self._clock = file.clock
        self.env_index = env_index
        self.agent = agent
        self._obs_codec = obs_codec
        self._act_codec = act_codec
        self._rules = settings.rules
        self._terms_rule = settings.terms_rule
        self._extract_terms = settings.terms_rule.extractor
        # How the terms of infos with the last key tuple seen are read (see _plan_terms):
        # the names (None: ask _extract_terms step by step) and one itemgetter of them
        self._terms_keys: tuple[Any, ...] | None = None
        self._terms_names: tuple[str, ...] | None = ()
        self._terms_get: Callable[[Any], Any] = tuple  # set with the names
        self._terms_one = False
        # plans by key tuple: an env that adds a term key on some steps only flips between two
        self._terms_plans: dict[tuple[Any, ...], tuple[Any, ...]] = {}
        self._info_keys = settings.info_keys
        self._keep_all_info = settings.keep_all_info
        self._track_info = settings.track_info
        self._block_steps = settings.block_steps
        self.row_bytes = (
            _type_bytes(obs_codec.field("o").type)
            + _type_bytes(act_codec.field("a").type)
            + _OTHER_COLUMNS_BYTES
        )
        """Estimated bytes of one step row (for sizing blocks)."""
        self._time_limit = time_limit
        self._max_steps = max_episode_steps
        self._step_schema = step_schema(
            act_codec.field(fmt.COL_ACTION), obs_codec.field(fmt.COL_OBSERVATION)
        )
        # Multi-stream files: reset rows also say whose they are (and, with games, which game).
        self._reset_extra = file.multi
        self._reset_schema = reset_schema(
            obs_codec.field(fmt.COL_OBSERVATION), multi_stream=file.multi
        )
        channel_meta = {"agent": agent or "", "env_index": str(env_index)}
        writer = file.writer
        try:
            self._steps_channel = writer.register_arrow_channel(
                fmt.TOPIC_STEPS, fmt.SCHEMA_STEP_BLOCK, self._step_schema, channel_meta
            )
            self._resets_channel = writer.register_arrow_channel(
                fmt.TOPIC_RESETS, fmt.SCHEMA_RESET_BLOCK, self._reset_schema, channel_meta
            )
        except BaseException:
            writer.abandon()
            raise
        self.episode: _Episode | None = None
        self.block = _Block(obs_codec, act_codec, None)

    # ------------------------------------------------------------------ episodes

    def begin(
        self,
        seed: Any,
        options: Any,
        rng_state: dict[str, Any] | None,
        notes: list[str],
        *,
        game: int | None = None,
        start_ns: int | None = None,
    ) -> _Episode:
        """Start the stream's next episode (ending an open one as ``incomplete``).

        ``seed`` is what was passed to ``reset()``; ``rng_state`` the env's bit-generator state
        before an unseeded reset (``None`` if unknown: the episode is then noted as not
        replayable). Notes about the seed or options are appended to ``notes``.
        """
        episode = self.episode
        if episode is not None and not episode.ended:
            self.end_episode(episode, fmt.OUTCOME_INCOMPLETE)
        file = self.file
        recorded_seed = _recordable_seed(seed, notes)
        if seed is None and rng_state is None and not _has_note(notes, "rng_state_unavailable"):
            notes.append(
                note("rng_state_unavailable", "reset without a seed and the env has no np_random")
            )
        recorded_options: Any = None
        if options is not None:
            try:
                recorded_options = to_jsonable(options)
            except Exception:  # not JSON; cyclic or too deep (RecursionError); a key's str() raises
                notes.append(note("options_unserializable", short(options)))
                recorded_options = {"repr": short(options)}
        episode = _Episode(
            file.take_episode_index(),
            recorded_seed,
            rng_state,
            recorded_options,
            file.clock() if start_ns is None else start_ns,
            self.env_index,
            self.agent,
            game,
        )
        self.episode = episode
        self.block.add_segment(self.block.rows(), episode, 0, True)
        return episode

    def record_reset(self, episode: _Episode, obs: Any, info: Any, notes: list[str]) -> None:
        """Record the reset row of ``episode`` (just begun); never raises."""
        try:
            self._record_reset(episode, obs, info, notes)
        except Exception as exc:  # never break the training loop over recording trouble
            self.file.trouble(exc)

    def _record_reset(self, episode: _Episode, obs: Any, info: Any, notes: list[str]) -> None:
        block = self.block
        row = len(block.resets)
        rng_json = None if episode.rng_json is None else episode.rng_json.decode()
        _append_noted(block.reset_obs, obs, "observation", notes, "reset observation: ")
        if self._track_info or type(info) is not dict:
            kept = self._kept_info(info, notes)
            if kept:
                block.reset_info[row] = kept
        block.resets.append(
            (
                episode.index,
                episode.start_ns,
                episode.seed,
                rng_json,
                episode.options_json,
                episode.game,
            )
        )
        if notes:
            _add_notes(episode, block.reset_notes, row, notes)

    def _kept_info(self, info: Any, notes: list[str]) -> dict[str, Any] | None:
        if not isinstance(info, Mapping):
            notes.append(note("info_not_dict", f"info is a {type(info).__name__}"))
            return None
        if self._keep_all_info:
            return dict(info)
        keys = self._info_keys
        if not keys:
            return None
        return {k: info[k] for k in keys if k in info} or None

    def end_open(self, outcome: str = fmt.OUTCOME_INCOMPLETE) -> None:
        """End the open episode, if any, with ``outcome`` (``incomplete`` by default)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self.end_episode(episode, outcome)

    def end_error(self, exc: BaseException, during: str) -> None:
        """End the open episode as ``error`` (the env raised ``exc`` during reset or step)."""
        episode = self.episode
        if episode is None or episode.ended:
            return
        self.end_episode(episode, fmt.OUTCOME_ERROR, error=(exc, during))

    def end_episode(
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
        """Mark the episode ended; its record is written at the next flush."""
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
                "type": text(type(exc).__qualname__),
                "message": error_message(exc)[:2000],
                "during": during,
            }
            ending["error_ns"] = self.file.clock()
        file = self.file
        file.pending.append((episode, ending))
        file.counts["episodes"] += 1

    def cap_block_steps(self, rows: int) -> None:
        """Write a block after at most ``rows`` rows (the file sizes blocks of large rows)."""
        self._block_steps = min(self._block_steps, rows)

    # ------------------------------------------------------------------ steps

    def step(self, action: Any, result: Any) -> None:
        """Record one step: ``result`` is what ``env.step(action)`` returned. Never raises."""
        # The hot path: appends only; lengths, returns and term totals are derived at flush.
        # Anything unusual goes to _record_step_slow.
        try:
            obs, reward, terminated, truncated, info = result
            episode = self.episode
            if episode is None or episode.ended or self._track_info or not isinstance(info, dict):
                raise LookupError  # not the common case (or an info to note): the slow path
            # both flags' truth values, here: one without any (an array) takes the slow path
            running = (not terminated) & (not truncated)
            block = self.block
            names: tuple[str, ...] | None = ()
            terms = None
            if info:
                keys = tuple(info)
                if keys != self._terms_keys:
                    self._plan_terms(keys)
                names = self._terms_names
                if names:
                    # the values, straight into the block: array("d") takes numbers only (a
                    # str such as "1.5" raises: slow path, which drops what this added)
                    if self._terms_one:
                        block.term_vals.append(self._terms_get(info))
                    else:
                        block.term_vals.extend(self._terms_get(info))
                elif names is None:
                    terms = self._extract_terms(info)
                    if terms is not None:
                        # __float__, not float(): a str is not a number (slow path)
                        values = [v.__float__() for v in terms.values()]
            if block.obs.append(obs) is not None or block.act.append(action) is not None:
                raise LookupError  # a value was cast: note it on the slow path
            block.rewards.append(reward)  # may raise: slow path
        except Exception:
            self._record_step_slow(result, action)
            return
        row = len(block.times)
        if names:
            block.term_rows.append(row)
            block.term_counts.append(len(names))
            block.term_keys.extend(names)
        elif terms is not None:
            block.add_terms(row, terms, values)
        now = self._clock()
        block.times.append(now)  # commits the row
        if not running:
            self._end_by_flags(episode, block, row, terminated, truncated, info)
        if row + 1 >= self._block_steps or now >= self.file.flush_at:
            self.file.auto_flush()

    def note_next_row(self, notes: list[str]) -> None:
        """Put ``notes`` on the row the next :meth:`step` writes (a caller's own accounting)."""
        if notes and self.episode is not None:
            _add_notes(self.episode, self.block.notes, len(self.block.times), notes)

    def _plan_terms(self, keys: tuple[Any, ...]) -> None:
        """Say how the terms of infos with these keys are read, until the keys change."""
        plan = self._terms_plans.get(keys)
        if plan is None:
            names = self._terms_rule.names_for(keys)
            # names: one itemgetter reads them all; None: extract() step by step; (): none
            get = operator.itemgetter(*names) if names else tuple
            plan = (keys, names, get, names is not None and len(names) == 1)
            if len(self._terms_plans) < 64:  # bounded: an env with ever-new keys re-plans
                self._terms_plans[keys] = plan
        self._terms_keys, self._terms_names, self._terms_get, self._terms_one = plan

    def extend(self, obs: Any, actions: Any, rewards: Any, times: Any) -> None:
        """Hand over all rows taken in a batch since the last call (numpy arrays, a row each).

        A batching recorder (the vector recorder) counts the rows it takes in ``block.pending``
        so episode boundaries and endings (:meth:`begin`, :meth:`end_step`) land on the right
        rows, and hands them over before the block is written. Values are already checked to
        need no coercion; a buffer that cannot take them at once gets them row by row.
        """
        block = self.block
        for buffer, values in ((block.obs, obs), (block.act, actions)):
            if not buffer.extend(values):
                for value in values:
                    buffer.append(value)
        block.rewards.frombytes(np.ascontiguousarray(rewards, dtype=np.float64).tobytes())
        block.times.frombytes(np.ascontiguousarray(times, dtype=np.int64).tobytes())
        block.pending = 0

    def end_step(
        self, row: int, terminated: bool, truncated: bool, info: Mapping[str, Any]
    ) -> None:
        """End the open episode by the flags of its step at ``row`` (a batched row)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self._end_by_flags(episode, self.block, row, terminated, truncated, info)

    def _record_step_slow(self, result: Any, action: Any) -> None:
        """Record a step the fast path declined; never raises into the training loop."""
        try:
            self._record_step(result, action)
        except Exception as exc:
            self.file.trouble(exc)

    def _record_step(self, result: Any, action: Any) -> None:
        block = self.block
        # The fast path may have appended the observation and/or action before bailing out:
        # roll back to the committed row count so every column stays aligned.
        rows = len(block.times)
        block.obs.truncate(rows)
        block.act.truncate(rows)
        del block.rewards[rows:]
        del block.term_vals[len(block.term_keys) :]
        notes: list[str] = []
        try:
            obs, reward, terminated, truncated, info = result
        except Exception:
            notes.append(note("step_result_invalid", f"step() returned {short(result)}"))
            obs, reward, terminated, truncated, info = None, math.nan, False, False, {}
        episode = self.episode
        if episode is None:
            episode = self._implicit_episode(notes)
        raw_flags = terminated, truncated  # _end_by_flags notes a true one that is not a bool
        try:
            terminated, truncated = bool(terminated), bool(truncated)
        except Exception:
            notes.append(
                note(
                    "flags_not_bool",
                    f"terminated={short(terminated)}, truncated={short(truncated)}",
                )
            )
            raw_flags = terminated, truncated = False, False
        r, terms = self._slow_values(reward, info, notes)
        _append_noted(block.obs, obs, "observation", notes)
        _append_noted(block.act, action, "action", notes)
        if self._track_info:
            kept = self._kept_info(info, notes)
            if kept:
                block.info[rows] = kept
        if episode.ended:
            notes.append(note("step_after_end", f"episode {episode.index} had already ended"))
            last = block.segments[-1] if block.segments else None
            if last is None or last[1] != episode.index or last[3]:
                # rows after the end keep the episode's step numbering but are not counted
                first = (
                    block.next_step_index()
                    if last is not None and last[1] == episode.index
                    else episode.next_step()
                )
                block.add_segment(rows, episode, first, False)
        block.rewards.append(r)
        if terms is not None:
            block.add_terms(rows, terms, list(terms.values()))
        if terminated or truncated:
            block.flags[rows] = (terminated, truncated)
        file = self.file
        now = file.clock()
        block.times.append(now)  # commits the row
        if notes:  # beside those an AEC recorder's turn accounting put on the row, if any
            _add_notes(episode, block.notes, rows, notes)
        if (terminated or truncated) and not episode.ended:
            self._end_by_flags(
                episode, block, rows, *raw_flags, info if isinstance(info, Mapping) else {}
            )
        if len(block.times) >= self._block_steps or now >= file.flush_at:
            file.auto_flush()

    def _limit_hit(self, block: _Block) -> bool:
        if self._time_limit is not None:
            return time_limit_hit(self._time_limit)
        limit = self._max_steps
        # The step's row is committed: the next step index is the episode's length so far.
        return limit is not None and block.segments != [] and block.next_step_index() >= limit

    def _end_by_flags(
        self,
        episode: _Episode,
        block: _Block,
        row: int,
        terminated: bool,
        truncated: bool,
        info: Mapping[str, Any],
    ) -> None:
        read: list[str] = []  # notes on the flags and values read (a success that is no bool)
        if type(terminated) not in _BOOLS or type(truncated) not in _BOOLS:
            # e.g. the text "False", which is true: the episode ends, and the step says why
            odd = f"terminated={short(terminated)}, truncated={short(truncated)}"
            read.append(note("flags_not_bool", f"{odd} (taken by their truth value)"))
        ending, why = self._rules.classify_or_note(
            bool(terminated),
            bool(truncated),
            info,
            time_limit_hit=self._limit_hit(block),
            notes=read,
        )
        if why is not None:  # the ending by the flags alone; say why
            read.append(note("ending_unreadable", why))
        if self._rules.reports_success(info):
            self.file.counts["success_reported"] += 1
        if read:
            _add_notes(episode, block.notes, row, read)
        label = ending.failure_label if terminated else ending.truncation_reason
        block.ends[row] = (ending.outcome, label)
        block.flags[row] = (bool(terminated), bool(truncated))
        self.end_episode(
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
            r = number(reward)
        except Exception:
            r = math.nan
            notes.append(note("reward_not_numeric", f"reward {short(reward)}"))
        if not isinstance(info, Mapping):
            notes.append(note("info_not_dict", f"info is a {type(info).__name__}"))
            return r, None
        try:
            raw = self._terms_rule.extract(info)
        except Exception as exc:
            notes.append(note("terms_unreadable", error_text(exc)))
            return r, None
        if raw is None:
            return r, None
        values: list[float] = []
        for key, value in raw.items():
            try:
                values.append(number(value))
            except Exception:
                values.append(math.nan)
                notes.append(note("term_not_numeric", f"term {short(key)} is {short(value)}"))
        terms, shared = named_terms(list(raw), values)
        if shared is not None:
            notes.append(note("terms_name_collision", shared))
        return r, terms

    def _implicit_episode(self, notes: list[str]) -> _Episode:
        file = self.file
        episode = _Episode(
            file.take_episode_index(),
            None,
            None,
            None,
            file.clock(),
            self.env_index,
            self.agent,
        )
        self.episode = episode
        self.block.add_segment(len(self.block.times), episode, 0, True)
        notes.append(
            note("stepped_before_reset", "the env was stepped before reset(); not replayable")
        )
        return episode

    # ------------------------------------------------------------------ blocks

    def write_blocks(self) -> None:
        """Write the stream's pending step and reset rows (called by ``EvidenceFile.flush``)."""
        block = self.block
        file = self.file
        n = len(block.times)
        # Derive what the hot path did not keep: episode lengths, returns, end times, term
        # totals (before the next block starts counting from them).
        if n:
            episode, step = _index_columns(block.segments, n)
            terms = _apply_block(block, n, episode)
        self.block = _Block(self._obs_codec, self._act_codec, self.episode)
        offset = file.wall_offset
        writer = file.writer
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
            # notes found now count in the episodes' records, written after this (flush)
            episode_at = block.episodes.get
            info = _info_column(
                n, block.info, block.notes, lambda row: episode_at(int(episode[row]))
            )
            columns = {
                fmt.COL_EPISODE: pa.array(episode),
                fmt.COL_STEP: pa.array(step),
                fmt.COL_TIME: pa.array(times),
                fmt.COL_ACTION: block.act.finish(),
                fmt.COL_OBSERVATION: block.obs.finish(),
                fmt.COL_REWARD: pa.array(np.frombuffer(block.rewards, dtype=np.float64)),
                fmt.COL_TERMS: terms,
                fmt.COL_TERMINATED: pa.array(terminated),
                fmt.COL_TRUNCATED: pa.array(truncated),
                fmt.COL_OUTCOME: pa.array(outcome, pa.string()),
                fmt.COL_LABEL: pa.array(label, pa.string()),
                fmt.COL_INFO: info,
                fmt.COL_NOTES: _notes_column(n, block.notes),
            }
            batch = _batch(columns, self._step_schema)
            writer.write_batch(self._steps_channel, batch, int(times[-1]))
            file.counts["steps"] += n
            file.counts["blocks"] += 1
        if block.resets:
            n = len(block.resets)
            episode_r, mono_r, seeds, rng, options, games = zip(*block.resets, strict=True)
            times = np.fromiter(mono_r, dtype=np.int64, count=n) + offset
            columns = {
                fmt.COL_EPISODE: pa.array(np.fromiter(episode_r, dtype=np.int64, count=n)),
                fmt.COL_ENV_INDEX: pa.array(np.full(n, self.env_index, dtype=np.int64)),
                fmt.COL_TIME: pa.array(times),
                fmt.COL_SEED: pa.array(seeds, pa.int64()),
                fmt.COL_RNG_STATE: pa.array(rng, pa.string()),
                fmt.COL_OPTIONS: pa.array(options, pa.string()),
                fmt.COL_OBSERVATION: block.reset_obs.finish(),
                fmt.COL_INFO: _info_column(
                    n,
                    block.reset_info,
                    block.reset_notes,
                    lambda row: block.episodes.get(block.resets[row][0]),
                ),
                fmt.COL_NOTES: _notes_column(n, block.reset_notes),
            }
            if self._reset_extra:
                columns[fmt.COL_AGENT] = pa.array([self.agent] * n, pa.string())
                columns[fmt.COL_GAME] = pa.array(games, pa.int64())
            batch = _batch(columns, self._reset_schema)
            writer.write_batch(self._resets_channel, batch, int(times[-1]))


def _batch(columns: dict[str, pa.Array], schema: pa.Schema) -> pa.RecordBatch:
    """A record batch of ``schema`` from its columns by name."""
    return pa.RecordBatch.from_arrays([columns[name] for name in schema.names], schema=schema)


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
        elif end > start:  # stepped after the end: numbered on, not counted
            block.episodes[index].after_end += end - start
    if not block.term_rows:
        return pa.nulls(n, TERMS_TYPE)
    rows = np.frombuffer(block.term_rows, dtype=np.int64)
    counts = np.frombuffer(block.term_counts, dtype=np.int64)
    values = np.frombuffer(block.term_vals, dtype=np.float64)
    keys = block.term_keys
    if block.raw_names and not plain_names(set(keys)):
        counts, keys, values = _named_block_terms(block, episode_col)
    key_array = text_array(keys)  # every name plain (or named): as it is
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


def _named_block_terms(
    block: _Block, episode_col: np.ndarray[Any, np.dtype[np.int64]]
) -> tuple[np.ndarray[Any, np.dtype[np.int64]], list[str], np.ndarray[Any, np.dtype[np.float64]]]:
    """The block's term counts, names and values, each row's named by :func:`named_terms`.

    For a block whose keys are not all plain names (``b"a"``, ``1``, ``"1"``): as the slow
    path names a step's terms, with its ``terms_name_collision`` note.
    """
    keys = block.term_keys
    values = block.term_vals
    counts = array("q")
    names: list[str] = []
    named_values = array("d")
    start = 0
    for row, count in zip(block.term_rows, block.term_counts, strict=True):
        end = start + count
        terms, shared = named_terms(keys[start:end], values[start:end])
        start = end
        if shared is not None:
            episode = block.episodes.get(int(episode_col[row]))
            _add_notes(episode, block.notes, row, [note("terms_name_collision", shared)])
        counts.append(len(terms))
        names.extend(terms)
        named_values.extend(terms.values())
    return (
        np.frombuffer(counts, dtype=np.int64),
        names,
        np.frombuffer(named_values, dtype=np.float64),
    )


_BOOLS = frozenset({bool, np.bool_})


def _has_note(notes: list[str], code: str) -> bool:
    """Whether ``notes`` already has a note ``code`` (a caller may know the better reason)."""
    prefix = f"{code}:"
    return any(item.startswith(prefix) for item in notes)


def _add_notes(
    episode: _Episode | None, by_row: dict[int, list[str]], row: int, texts: list[str]
) -> None:
    """Add notes to ``row`` of ``by_row`` (a block's step or reset notes).

    A row with notes counts once in its episode's ``notes`` (``None``: a row of no episode),
    however many notes it gets and whenever: while stepping, or when its block is written
    (before the records of the episodes that ended, in the same flush).
    """
    row_notes = by_row.get(row)
    if row_notes is None:
        by_row[row] = texts
        if episode is not None:
            episode.notes += 1
    else:
        row_notes.extend(texts)


def _append_noted(
    buffer: ColumnBuffer, value: Any, what: str, notes: list[str], context: str = ""
) -> None:
    """Append ``value``; a cast or a value that does not fit (stored as null) gets a note."""
    try:
        cast = buffer.append(value)
    except (ValueError, TypeError) as exc:
        buffer.append_null()
        notes.append(note(f"{what}_invalid", f"{context}{exc}"))
        return
    if cast is not None:
        notes.append(note(f"{what}_cast", cast))


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
    notes.append(note("seed_out_of_range", f"seed {short(seed)} is not an int64; not replayable"))
    return None


_OPEN_RECORDERS: weakref.WeakSet[Any] = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:
    """Finish files whose recorder was never closed when the interpreter exits normally."""
    for recorder in list(_OPEN_RECORDERS):
        try:
            recorder.close()
        except Exception:
            pass
