r"""Read evidence files: the only module that touches ``mcap``'s readers.

:func:`open_evidence` returns an :class:`Evidence`: the run metadata, an episodes table and a
steps table as ``pyarrow.Table``\\ s (with column and episode selection), block-by-block
streaming, and episode-by-episode iteration.

A finished file is read through its summary (chunk index). A file whose writer was killed has no
summary: it is scanned linearly, every complete chunk is kept, and :attr:`Evidence.finished` is
``False`` with :attr:`Evidence.torn` saying what was dropped. Nothing here loads a whole file into
memory: chunks are read one at a time, and a single episode is read from the chunks its time range
covers.

Chunks are read by this module's own chunk reader, not record by record through ``mcap``: the
chunk record's declared sizes are checked against :data:`MAX_RECORD_BYTES` before anything is
decompressed, the decompressed records are checked against the chunk's CRC, and they are split
with :mod:`struct`, building objects only for the messages asked for. While the caller works on
one chunk, a worker thread reads and decompresses the next few (zstd, lz4 and CRC release the
GIL); at most :data:`READ_AHEAD` chunks are in flight.

One pass over a file is enough for everything: :meth:`Evidence.scan` yields what each chunk
holds (step blocks, reset blocks, episode records), and any complete pass over the steps
(``scan``, :meth:`Evidence.iter_step_batches`, :meth:`Evidence.steps`) also keeps the reset
blocks and the episode records (up to :data:`KEEP_LIMIT` bytes), so a following
:meth:`Evidence.resets` or :meth:`Evidence.episodes` reads nothing again. Both tables are
cached. The episodes of a finished file come from their end records alone, without decoding a
step block; only episodes without an end record (cut off in a torn file) are counted from their
steps. A finished file's episodes are those with an end record or a reset row.

Every error raised on purpose is an :class:`~episode_audit.errors.EvidenceError` naming the file.
"""

from __future__ import annotations

import bisect
import importlib
import json
import os
import stat
import struct
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from io import BytesIO
from itertools import pairwise
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from ..errors import (
    CorruptEvidenceError,
    EvidenceError,
    NotEvidenceError,
    UnsupportedVersionError,
)
from ..format import names as fmt
from ..format.records import EpisodeRanges, RunInfo
from ..format.schemas import EPISODE_BLOCK_BASE, EPISODE_BLOCK_SCHEMA, key_columns, required_columns
from ..format.schemas import EPISODE_TABLE_SCHEMA as EPISODE_SCHEMA
from ..format.spaces import SpaceCodec, codec_for, space_from_description

try:  # zlib-ng's CRC-32 (the same checksum) runs ~4x faster than the system zlib's
    from zlib_ng.zlib_ng import crc32 as _crc32
except ImportError:  # pragma: no cover - a platform without zlib-ng wheels
    from zlib import crc32 as _crc32

_ARROW_ZSTD = pa.Codec.is_available("zstd")
"""Whether this pyarrow decompresses zstd (PyPI's wheels do); else ``zstandard`` does."""

__all__ = [
    "EPISODE_COLUMNS",
    "ChunkContents",
    "ChunkRecords",
    "DamagedRegion",
    "EpisodeEvidence",
    "Evidence",
    "FileEnd",
    "iter_records",
    "open_evidence",
    "summary_definitions",
]

MAX_RECORD_BYTES = 1 << 30
"""Largest MCAP record (and decompressed chunk) the reader accepts: 1 GiB."""
MAX_JSON_BYTES = 1 << 20
"""Largest JSON episode record or metadata value the reader accepts: 1 MiB."""
READ_AHEAD = 4
"""Most chunks read and decompressed ahead of the one being worked on."""
READ_AHEAD_BYTES = 256 << 20
"""Most decompressed bytes read ahead (one chunk is always allowed, however large)."""
KEEP_LIMIT = 256 << 20
"""Most bytes of reset blocks and episode records a pass over the steps keeps for later."""

_MAGIC = b"\x89MCAP0\r\n"

# MCAP record layout (https://mcap.dev/spec): opcode u8, record length u64, then the body.
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_MESSAGE_INDEX = 0x07
_INDEX_HEAD = struct.Struct("<HI")
_RECORD_HEAD = struct.Struct("<BQ")
# Chunk body: message start time, message end time, uncompressed size, uncompressed CRC, and the
# compression string's length; then the string, the records' length (u64) and the records.
_CHUNK_HEAD = struct.Struct("<QQQII")
_U64 = struct.Struct("<Q")
# Message body: channel id u16, sequence u32, log time u64, publish time u64, then the data.
_MESSAGE_HEAD = struct.Struct("<H4xQ8x")
_THREADED_MIN_CHUNKS = 3
# Blocks are read in place from the decompressed chunk, at any offset: buffers that are not
# aligned for their type are copied (compute kernels and numpy want them aligned).
_IPC_OPTIONS = pa.ipc.IpcReadOptions(ensure_alignment=pa.ipc.Alignment.DataTypeSpecific)
_NOTHING = (False, False, False)

# What a message is to the reader, by its channel's topic.
_STEPS, _RESETS, _ENDS, _OTHER = 0, 1, 2, -1
_SLOTS = {fmt.TOPIC_STEPS: _STEPS, fmt.TOPIC_RESETS: _RESETS, fmt.TOPIC_EPISODE_END: _ENDS}
# Files with Arrow episode blocks: read those, skip the JSON copies of the same records.
_ARROW_SLOTS = {fmt.TOPIC_STEPS: _STEPS, fmt.TOPIC_RESETS: _RESETS, fmt.TOPIC_EPISODES: _ENDS}

EPISODE_COLUMNS: tuple[str, ...] = tuple(EPISODE_SCHEMA.names)
"""Columns of :meth:`Evidence.episodes`; ``ended`` is False for episodes a torn file cut off."""

_RESET_START_COLUMNS = [
    fmt.COL_EPISODE,
    fmt.COL_ENV_INDEX,
    fmt.COL_AGENT,
    fmt.COL_GAME,
    fmt.COL_TIME,
    fmt.COL_SEED,
    fmt.COL_RNG_STATE,
    fmt.COL_OPTIONS,
]
# Columns every episode block has (those of format 1.0's first files); ``game`` is optional.
_BLOCK_SCHEMA = EPISODE_BLOCK_SCHEMA
_BLOCK_BASE = EPISODE_BLOCK_BASE


@dataclass(frozen=True)
class _ChunkRef:
    offset: int
    start_time: int
    end_time: int
    compressed_size: int
    uncompressed_size: int
    # finished files: file offsets of the chunk's MessageIndex records, by channel id
    index_offsets: tuple[tuple[int, int], ...] = ()
    index_length: int = 0


@dataclass(frozen=True)
class _RawChunk:
    """A chunk record's fields, checked, with its still compressed records."""

    compression: str
    uncompressed_size: int
    uncompressed_crc: int
    data: bytes | memoryview


@dataclass
class _Chunk:
    """The wanted messages of one chunk: step blocks parsed, the rest as raw bytes."""

    ref: _ChunkRef
    steps: list[tuple[int, pa.RecordBatch]]
    resets: list[tuple[int, bytes]]
    records: list[bytes]
    step_channels: list[int] = field(default_factory=list)  # channel id of each step block


@dataclass(frozen=True)
class ChunkContents:
    """What one chunk of an evidence file holds, as :meth:`Evidence.scan` yields it.

    Attributes:
        offset: The chunk's byte offset in the file.
        steps: Its step blocks, in recording order (empty when not asked for).
        resets: Its reset blocks (empty when not asked for).
        episode_records: Its episode records, raw: Arrow IPC episode blocks for files that have
            them (topic ``episode_audit/episodes``), else JSON end records (empty when not
            asked for).
    """

    offset: int
    steps: list[pa.RecordBatch]
    resets: list[pa.RecordBatch]
    episode_records: list[bytes]


@dataclass
class _StepStats:
    """Per episode: step rows, summed reward and the last block's latest time."""

    lengths: dict[int, int] = field(default_factory=dict)
    returns: dict[int, float] = field(default_factory=dict)
    last_time: dict[int, int] = field(default_factory=dict)

    def add(self, batch: pa.RecordBatch) -> None:
        grouped = (
            pa.table(
                {
                    "e": batch.column(fmt.COL_EPISODE),
                    "r": batch.column(fmt.COL_REWARD),
                    "t": batch.column(fmt.COL_TIME),
                }
            )
            .group_by("e")
            .aggregate([("r", "count"), ("r", "sum"), ("t", "max")])
        )
        lengths, returns, last_time = self.lengths, self.returns, self.last_time
        for e, n, s, t in zip(  # noqa: B905 - equal-length columns of one table
            grouped.column("e").to_pylist(),
            grouped.column("r_count").to_pylist(),
            grouped.column("r_sum").to_pylist(),
            grouped.column("t_max").to_pylist(),
        ):
            lengths[e] = lengths.get(e, 0) + n
            returns[e] = returns.get(e, 0.0) + (s or 0.0)
            last_time[e] = t


@dataclass
class _Gathered:
    """What a complete pass keeps for :meth:`Evidence.resets` and :meth:`Evidence.episodes`.

    With a ``limit``, a pass that was not asked for them stops keeping anything once they
    exceed it (a later call then reads the file again); their own pass keeps everything.

    With a ``path``, reset blocks and episode Arrow blocks are decoded as they come (while
    the read-ahead thread decompresses the next chunks) rather than all at the end. A block
    that fails to decode is kept as bytes, and so is every block after it: decoding them
    later raises the error where it did before, when :meth:`Evidence.resets` or
    :meth:`Evidence.episodes` is called.
    """

    stats: _StepStats | None = None
    limit: int | None = None
    path: Path | None = None
    arrow_records: bool = False
    resets: list[pa.RecordBatch | bytes] = field(default_factory=list)
    records: list[pa.RecordBatch | bytes] = field(default_factory=list)
    size: int = 0
    dropped: bool = False

    def add(self, chunk: _Chunk) -> None:
        if self.dropped:
            return
        for _, data in chunk.resets:
            self.resets.append(self._early(data, self.resets, _reset_block))
            self.size += len(data)
        for data in chunk.records:
            decode = _episode_part if self.arrow_records else None
            self.records.append(self._early(data, self.records, decode))
            self.size += len(data)
        if self.limit is not None and self.size > self.limit:
            self.dropped = True
            self.resets, self.records, self.stats = [], [], None
            return
        if self.stats is not None:
            try:
                for _, batch in chunk.steps:
                    self.stats.add(batch)
            except Exception:
                self.stats = None  # counted again, with its error, if episodes() needs it

    def _early(
        self,
        data: bytes,
        kept: list[pa.RecordBatch | bytes],
        decode: Callable[[bytes, Path], pa.RecordBatch] | None,
    ) -> pa.RecordBatch | bytes:
        if decode is None or self.path is None or (kept and isinstance(kept[-1], bytes)):
            return data
        try:
            return decode(data, self.path)
        except EvidenceError:
            return data


@dataclass
class EpisodeEvidence:
    """One episode: its record (a row of :meth:`Evidence.episodes`), its steps and reset row."""

    record: dict[str, Any]
    steps: pa.Table
    reset: dict[str, Any] | None

    @property
    def index(self) -> int:
        """The episode index in its file."""
        return int(self.record["episode"])


@dataclass
class Evidence:
    """An open evidence file. Use :func:`open_evidence` to make one.

    Attributes:
        path: The file.
        run: The run metadata.
        finished: Whether the writer finished the file (summary, footer, run-end record).
        run_end: The run-end record (``status`` is ``finished`` or ``recovered``), if any.
        torn: For an unfinished file, what the reader had to drop at the torn end.
        summary_damage: For a finished file whose end is damaged — its summary section
            (MCAP's index of it) does not match the footer's CRC, or the footer or closing
            magic is garbled — what is wrong; the file was then read by scanning its data
            section, which holds all the evidence.
        run_end_damage: For a finished file whose run-end record (which its sound summary
            locates) is garbled, what is wrong. The writer finished the file and every chunk
            is there; the record's status and counts are lost, and :attr:`run_end` is
            ``None``.
    """

    path: Path
    run: RunInfo
    finished: bool
    run_end: dict[str, str] | None
    torn: str | None
    _chunks: list[_ChunkRef] = field(repr=False)
    _channels: dict[int, Channel] = field(repr=False)
    summary_damage: str | None = None
    run_end_damage: str | None = None
    _episodes_cache: pa.Table | None = field(default=None, repr=False)
    _resets_cache: pa.Table | None = field(default=None, repr=False)
    _gathered: _Gathered | None = field(default=None, repr=False)
    _stats: _StepStats | None = field(default=None, repr=False)

    @property
    def damaged_episodes(self) -> EpisodeRanges:
        """Episodes that lost part or all of their evidence in damaged chunks.

        Only a file rewritten by ``episode-audit recover`` from a damaged one says so (its
        run-end record lists them); for any other file this is empty.
        """
        return EpisodeRanges.from_json((self.run_end or {}).get("damaged_episodes"))

    @property
    def reports_success(self) -> bool | None:
        """Whether the task said anything about success in an episode's final info.

        ``False`` for a task without a success signal (CartPole, Hopper: its endings are
        failures or cut-offs, never successes); ``None`` when the file does not say (a torn
        file, or one written by a recorder that did not count it yet).
        """
        raw = (self.run_end or {}).get(fmt.RUN_END_SUCCESS_REPORTED)
        try:
            return None if raw is None else int(raw) > 0
        except ValueError:
            return None

    @property
    def damaged_stretches(self) -> int:
        """How many damaged stretches of the original file a recovery skipped (0 if none)."""
        raw = (self.run_end or {}).get("damaged")
        try:
            value = json.loads(raw) if raw else []
        except ValueError:
            return 0
        return len(value) if isinstance(value, list) else 0

    # --------------------------------------------------------------- raw access

    def _open(self) -> IO[bytes]:
        try:
            return open(self.path, "rb")
        except OSError as exc:
            raise EvidenceError(self.path, f"cannot open: {exc.strerror}") from None

    def _decoded(
        self, refs: Sequence[_ChunkRef], *, ahead: bool, want: frozenset[int] | None = None
    ) -> Iterator[tuple[_ChunkRef, tuple[memoryview, list[int] | None]]]:
        """Yield each chunk's decompressed records and its wanted messages' offsets.

        With ``ahead``, a worker thread reads and decompresses ahead.
        """
        path = self.path
        with self._open() as f:
            if not ahead or len(refs) < _THREADED_MIN_CHUNKS:
                for ref in refs:
                    yield ref, _read_and_decompress(f, ref, path, want)
                return
            # One worker: it alone touches ``f``, one chunk after the other. (Two workers were
            # measured slower on 2 cores: they compete with the thread that parses.)
            pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="episode-audit-read")
            pending: deque[tuple[_ChunkRef, Future[tuple[memoryview, list[int] | None]]]] = deque()
            in_flight = 0  # decompressed bytes pending
            try:
                for ref in refs:
                    while pending and (
                        len(pending) >= READ_AHEAD
                        or in_flight + ref.uncompressed_size > READ_AHEAD_BYTES
                    ):
                        done, future = pending.popleft()
                        in_flight -= done.uncompressed_size
                        yield done, future.result()
                    pending.append((ref, pool.submit(_read_and_decompress, f, ref, path, want)))
                    in_flight += ref.uncompressed_size
                while pending:
                    done, future = pending.popleft()
                    yield done, future.result()
            finally:
                for _, future in pending:
                    future.cancel()
                pool.shutdown(wait=True)

    @property
    def _slots(self) -> dict[str, int]:
        """Topic -> slot; episode records come from Arrow blocks when the file has them."""
        if any(ch.topic == fmt.TOPIC_EPISODES for ch in self._channels.values()):
            return _ARROW_SLOTS
        return _SLOTS

    def _read(
        self,
        *,
        steps: bool,
        resets: bool,
        records: bool,
        start_time: int | None = None,
        ahead: bool = True,
    ) -> Iterator[_Chunk]:
        """Yield the wanted messages of every chunk (from ``start_time`` on), in file order.

        With ``ahead`` (for whole-file passes) a worker thread reads and decompresses the next
        chunks while the caller works on this one.
        """
        refs = [r for r in self._chunks if start_time is None or r.end_time >= start_time]
        slots = self._slots
        route = {cid: slots.get(ch.topic, _OTHER) for cid, ch in self._channels.items()}
        wanted = (steps, resets, records)
        want = frozenset(c for c, slot in route.items() if slot != _OTHER and wanted[slot])
        path = self.path
        # Every step block has the schema the file declares for them (or, if it declares
        # none, the first block's): a reader streaming blocks can rely on one schema.
        expected = self._declared_schema(fmt.TOPIC_STEPS)
        for ref, (data, positions) in self._decoded(refs, ahead=ahead, want=want):
            channels: list[Channel] = []
            messages = _split(
                data, path, ref.offset, route, wanted, channels, None, slots, positions
            )
            for channel in channels:
                self._channels.setdefault(channel.id, channel)
            chunk = _Chunk(ref, [], [], [])
            for slot, log_time, view, channel_id in messages:
                if slot == _STEPS:
                    batch = _arrow_batch(view, path, fmt.TOPIC_STEPS)
                    if expected is None:
                        expected = batch.schema
                    elif not batch.schema.equals(expected):
                        raise CorruptEvidenceError(
                            path,
                            f"a step block in the chunk at byte {ref.offset} does not have the "
                            "schema of the others (or the one the file declares)",
                        )
                    chunk.steps.append((log_time, batch))
                    chunk.step_channels.append(channel_id)
                elif slot == _RESETS:
                    chunk.resets.append((log_time, view.tobytes()))
                else:
                    chunk.records.append(view.tobytes())
            yield chunk

    def _pass(
        self,
        *,
        steps: bool,
        resets: bool = False,
        records: bool = False,
        keep_all: bool = False,
    ) -> Iterator[_Chunk]:
        """Read every chunk once; a complete pass also keeps resets and episode records.

        They are kept by the first complete pass only, and (unless ``keep_all``) only up to
        :data:`KEEP_LIMIT` bytes.
        """
        gather = None
        if self._gathered is None:
            stats = _StepStats() if steps and not self.finished else None
            gather = _Gathered(
                stats,
                None if keep_all else KEEP_LIMIT,
                self.path,
                arrow_records=self._slots is _ARROW_SLOTS,
            )
        keep = gather is not None
        for chunk in self._read(steps=steps, resets=resets or keep, records=records or keep):
            if gather is not None:
                gather.add(chunk)
            yield chunk
        if gather is not None and not gather.dropped:
            self._gathered = gather
            if gather.stats is not None:
                self._stats = gather.stats

    def scan(
        self, *, steps: bool = True, resets: bool = True, episode_records: bool = True
    ) -> Iterator[ChunkContents]:
        """Read each chunk once and yield what it holds, in file order.

        Leave out what you do not need: a chunk's step blocks are only decoded with ``steps``.
        Episode records are raw, as written (see :class:`ChunkContents`; :meth:`episodes`
        gives the table).
        A complete scan also fills the caches of :meth:`resets` and :meth:`episodes`.
        """
        path = self.path
        for chunk in self._pass(steps=steps, resets=resets, records=episode_records):
            yield ChunkContents(
                chunk.ref.offset,
                [batch for _, batch in chunk.steps] if steps else [],
                [_arrow_batch(data, path, fmt.TOPIC_RESETS) for _, data in chunk.resets]
                if resets
                else [],
                list(chunk.records) if episode_records else [],
            )

    # --------------------------------------------------------------- steps

    def iter_step_batches(self, columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
        """Yield the steps block by block (one record batch per written block).

        Each chunk is read once; the pass also keeps what :meth:`resets` and :meth:`episodes`
        need, so calling them afterwards reads nothing again.

        Every episode's rows come out contiguous and in step order. In a multi-stream file
        (vector sub-envs, agents) the streams' blocks interleave in the file, so there the
        batches are regrouped: an episode's rows are held until its stream moves on to its next
        episode (or the file ends), then yielded with the other episodes completed in the same
        chunk. Memory is then bounded by the longest open episode of each stream.
        """
        selected = None if columns is None else list(columns)
        batches: Iterable[pa.RecordBatch]
        if self.multi_stream:
            batches = _contiguous(self._pass(steps=True))
        else:
            batches = (batch for chunk in self._pass(steps=True) for _, batch in chunk.steps)
        for batch in batches:
            yield batch if selected is None else batch.select(selected)

    @property
    def multi_stream(self) -> bool:
        """Whether the file has more than one step stream (vector sub-envs, agents)."""
        return sum(ch.topic == fmt.TOPIC_STEPS for ch in self._channels.values()) > 1

    def steps(
        self,
        *,
        columns: Sequence[str] | None = None,
        episodes: Iterable[int] | None = None,
    ) -> pa.Table:
        """All steps (or those of ``episodes``) as one table, in recording order."""
        wanted = None if episodes is None else pa.array(sorted(set(episodes)), pa.int64())
        parts: list[pa.RecordBatch] = []
        for batch in self.iter_step_batches():
            if wanted is not None:
                batch = batch.filter(pc.is_in(batch.column(fmt.COL_EPISODE), wanted))
                if batch.num_rows == 0:
                    continue
            parts.append(batch if columns is None else batch.select(list(columns)))
        return self._table(parts, fmt.TOPIC_STEPS, columns)

    def _table(
        self, parts: list[pa.RecordBatch], topic: str, columns: Sequence[str] | None
    ) -> pa.Table:
        if parts:
            try:
                return pa.Table.from_batches(parts)
            except pa.ArrowInvalid as exc:
                raise CorruptEvidenceError(
                    self.path, f"blocks on {topic} do not share one schema: {str(exc)[:200]}"
                ) from None
        schema = self._topic_schema(topic)
        if columns is not None:
            if not schema.names:  # torn before its first block: the file never named a type
                schema = pa.schema([pa.field(c, pa.null()) for c in columns])
            schema = pa.schema([schema.field(c) for c in columns])
        return schema.empty_table()

    @property
    def steps_schema(self) -> pa.Schema:
        """The Arrow schema of the steps table (from the file, even when it has no steps)."""
        return self._topic_schema(fmt.TOPIC_STEPS)

    def _declared_schema(self, topic: str) -> pa.Schema | None:
        """The schema the file's Schema record declares for ``topic``, if any (unchecked)."""
        for channel in self._channels.values():
            if channel.topic == topic and channel.schema_id in self._schemas:
                return self._schemas[channel.schema_id]
        return None

    def _topic_schema(self, topic: str) -> pa.Schema:
        """The topic's schema as its Schema record declares it (checked like its blocks).

        A file without the topic's channel or schema (torn before any block) gets the
        required columns, the space columns null-typed.
        """
        schema = self._declared_schema(topic)
        if schema is None:
            return _minimal_schema(topic)
        problem = _columns_problem(schema, _REQUIRED[topic])
        if problem is not None:
            raise CorruptEvidenceError(
                self.path, f"the schema of {topic} does not have the expected columns: {problem}"
            )
        return schema

    @property
    def _schemas(self) -> dict[int, pa.Schema]:
        return getattr(self, "_schema_cache", {})

    def _gather(self) -> _Gathered:
        """Reset blocks and episode records, from the last complete pass or a new one."""
        if self._gathered is None:
            # A torn file's episodes need counts from its steps: count them in the same pass.
            for _ in self._pass(steps=not self.finished, keep_all=True):
                pass
        assert self._gathered is not None
        return self._gathered

    def resets(self) -> pa.Table:
        """One row per reset: episode, seed, rng_state (JSON), options (JSON), observation.

        The table is read once and cached.
        """
        if self._resets_cache is None:
            gathered = self._gather()
            parts = _decode_kept(gathered.resets, _reset_block, self.path)
            self._resets_cache = self._table(parts, fmt.TOPIC_RESETS, None)
            gathered.resets = []
        return self._resets_cache

    # --------------------------------------------------------------- episodes

    def episodes(self) -> pa.Table:
        """One row per episode (see :data:`EPISODE_COLUMNS`), including cut-off ones.

        The table is read once and cached. An episode with an end record takes every value
        from it; one without (cut off by a torn file) is counted from its reset row and steps.
        """
        if self._episodes_cache is None:
            self._episodes_cache = self._build_episodes()
        return self._episodes_cache

    def _build_episodes(self) -> pa.Table:
        gathered = self._gather()
        if self._slots is _ARROW_SLOTS:
            table = _episode_blocks(gathered.records, self.path)
            episodes = table.column("episode").to_numpy()
            increasing = bool((episodes[1:] > episodes[:-1]).all())
            if self.finished and increasing:
                reset = self.resets().column(fmt.COL_EPISODE).to_numpy()
                if bool(np.isin(reset, episodes).all()):
                    gathered.records = []
                    return table  # the common case: the blocks are the table
            ended = set(episodes.tolist())
            starts = self._starts(self.resets(), ended)
            columns = {name: table.column(name).to_pylist() for name in EPISODE_COLUMNS}
        else:
            # JSON records: the pass kept them as bytes
            columns = _end_record_columns(gathered.records, self.path)
            ended = set(columns["episode"])
            starts = self._starts(self.resets(), ended)
        stats = _StepStats()
        if not self.finished or any(index not in ended for index in starts):
            stats = self._step_stats()
        table = _episode_table(self.path, columns, starts, stats)
        gathered.records = []
        return table

    def _starts(self, resets: pa.Table, ended: set[int]) -> dict[int, Any]:
        """Reset rows (the last one of each episode) of the episodes without an end record.

        Every reset episode is a key; the value is None for those with an end record.
        """
        if resets.num_rows == 0:
            return {}
        episodes = resets.column(fmt.COL_EPISODE).to_pylist()
        starts: dict[int, Any] = dict.fromkeys(episodes)
        rows = [i for i, e in enumerate(episodes) if e not in ended]
        if rows:
            present = [c for c in _RESET_START_COLUMNS if c in resets.column_names]
            picked = resets.select(present).take(pa.array(rows, pa.int64()))
            for row in picked.to_pylist():
                starts[int(row["episode"])] = row
        return starts

    def _step_stats(self) -> _StepStats:
        if self._stats is None:
            stats = _StepStats()
            for chunk in self._read(steps=True, resets=False, records=False):
                for _, batch in chunk.steps:
                    stats.add(batch)
            self._stats = stats
        return self._stats

    def episode(self, index: int) -> EpisodeEvidence:
        """One episode, read from the chunks its time range covers only."""
        table = self.episodes()
        match = table.filter(pc.equal(table.column("episode"), index))
        if match.num_rows == 0:
            raise EvidenceError(
                self.path, f"no episode {index} (the file has {table.num_rows} episodes)"
            )
        record = match.to_pylist()[0]
        return self._load_episode(record)

    def _load_episode(self, record: dict[str, Any]) -> EpisodeEvidence:
        index = int(record["episode"])
        start = record.get("start_time_ns")
        end = record.get("end_time_ns") if record.get("ended") else None
        parts: list[pa.RecordBatch] = []
        key = pa.scalar(index, pa.int64())
        reset = None
        steps_done = resets_done = False
        path = self.path
        # A flush writes every stream's blocks into one chunk: the episode's last row is in the
        # first chunk with a block that ends at or after the episode (in any stream).
        for chunk in self._read(
            steps=True, resets=True, records=False, start_time=start, ahead=False
        ):
            for log_time, batch in [] if steps_done else chunk.steps:
                rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
                if rows.num_rows:
                    parts.append(rows)
                if end is not None and log_time >= end:
                    steps_done = True
            for log_time, data in [] if resets_done else chunk.resets:
                batch = _arrow_batch(data, path, fmt.TOPIC_RESETS)
                rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
                if rows.num_rows:
                    reset = rows.to_pylist()[0]
                    resets_done = True
                    break
                if start is not None and log_time > start:
                    resets_done = True
                    break
            if steps_done and resets_done:
                break
        return EpisodeEvidence(record, self._table(parts, fmt.TOPIC_STEPS, None), reset)

    def iter_episodes(self) -> Iterator[EpisodeEvidence]:
        """Yield every episode with its steps, one at a time."""
        for record in self.episodes().to_pylist():
            yield self._load_episode(record)

    @property
    def observation_codec(self) -> SpaceCodec | None:
        """Codec of the observation column, rebuilt from the file (``None`` if unsupported)."""
        return self._codec("observation_space")

    @property
    def action_codec(self) -> SpaceCodec | None:
        """Codec of the action column, rebuilt from the file (``None`` if unsupported)."""
        return self._codec("action_space")

    def _codec(self, name: str) -> SpaceCodec | None:
        cache: dict[str, SpaceCodec | None] = self.__dict__.setdefault("_codec_cache", {})
        if name not in cache:
            digest = (
                self.run.recorder.get("digest_min_bytes") if name == "observation_space" else None
            )
            column = fmt.COL_OBSERVATION if name == "observation_space" else fmt.COL_ACTION
            try:
                space = space_from_description(getattr(self.run, name))
                codec: SpaceCodec | None = codec_for(space, digest_min_bytes=digest)
                stored = self.steps_schema.field(column).type
                if codec is not None and not (
                    pa.types.is_null(stored) or codec.field(column).type.equals(stored)
                ):
                    codec = None  # the description does not describe the column: do not decode
            except Exception:
                codec = None
            cache[name] = codec
        return cache[name]

    def __enter__(self) -> Evidence:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


# ------------------------------------------------------------------- multi-stream order


def _contiguous(chunks: Iterable[_Chunk]) -> Iterator[pa.RecordBatch]:
    """The step blocks of a multi-stream file, regrouped so every episode's rows are contiguous.

    A stream's own rows are in order and its episodes follow one another, so an episode is
    complete once its stream shows a row of another episode (or the file ends). Complete
    episodes are yielded at the end of each chunk, those of one schema as one batch.
    """
    open_: dict[int, tuple[int, list[pa.RecordBatch]]] = {}  # channel -> (episode, parts)
    for chunk in chunks:
        done: list[pa.RecordBatch] = []
        for (_, batch), channel in zip(chunk.steps, chunk.step_channels, strict=True):
            if batch.num_rows == 0:
                continue
            episode = batch.column(fmt.COL_EPISODE).to_numpy(zero_copy_only=False)
            starts = [0, *(np.flatnonzero(episode[1:] != episode[:-1]) + 1).tolist()]
            stops = [*starts[1:], batch.num_rows]
            for start, stop in zip(starts, stops, strict=True):
                index = int(episode[start])
                part = batch.slice(start, stop - start)
                current = open_.get(channel)
                if current is not None and current[0] == index:
                    current[1].append(part)
                    continue
                if current is not None:
                    done.extend(current[1])
                open_[channel] = (index, [part])
        yield from _joined(done)
    rest = sorted(open_.values(), key=lambda item: item[0])
    yield from _joined([part for _, parts in rest for part in parts])


def _joined(parts: list[pa.RecordBatch]) -> Iterator[pa.RecordBatch]:
    """``parts`` as few batches as possible: consecutive parts of one schema are joined."""
    group: list[pa.RecordBatch] = []
    for part in parts:
        if group and not part.schema.equals(group[0].schema):
            yield pa.concat_batches(group) if len(group) > 1 else group[0]
            group = []
        group.append(part)
    if group:
        yield pa.concat_batches(group) if len(group) > 1 else group[0]


# ------------------------------------------------------------------- chunks


_RECOVER_HINT = "; `episode-audit recover` copies the intact chunks to a new file"


def _damaged(path: Path, offset: int, why: str) -> CorruptEvidenceError:
    return CorruptEvidenceError(path, f"chunk at byte {offset} is damaged ({why}){_RECOVER_HINT}")


def _read_chunk_record(f: IO[bytes], ref: _ChunkRef, path: Path) -> _RawChunk:
    """Read and check the chunk record at ``ref.offset`` (its records still compressed)."""
    offset = ref.offset
    try:
        f.seek(offset)
        head = f.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            raise _damaged(path, offset, "the file ends inside it")
        opcode, length = _RECORD_HEAD.unpack(head)
        if opcode != _OP_CHUNK:
            raise _damaged(path, offset, f"opcode {opcode:#04x} where a chunk record should be")
        if length > MAX_RECORD_BYTES:
            raise CorruptEvidenceError(
                path,
                f"chunk at byte {offset} declares a record of {length} bytes "
                f"(limit {MAX_RECORD_BYTES})",
            )
        if offset + _RECORD_HEAD.size + length > os.fstat(f.fileno()).st_size:
            raise _damaged(path, offset, f"its {length}-byte record runs past the end of the file")
        body = f.read(length)
    except OSError as exc:
        raise EvidenceError(path, f"cannot read chunk at byte {offset}: {exc}") from None
    if len(body) < length:
        raise _damaged(path, offset, "the file ends inside it")
    try:
        _, _, size, crc, name_length = _CHUNK_HEAD.unpack_from(body, 0)
        pos = _CHUNK_HEAD.size + name_length
        compression = body[_CHUNK_HEAD.size : pos].decode("utf-8")
        (records_length,) = _U64.unpack_from(body, pos)
    except (struct.error, UnicodeDecodeError):
        raise _damaged(path, offset, "its header is cut off or garbled") from None
    pos += _U64.size
    if pos + records_length > len(body):
        raise _damaged(
            path, offset, f"its records ({records_length} bytes) overrun the {length}-byte record"
        )
    view = memoryview(body)[pos : pos + records_length]
    return _raw_chunk(compression, size, crc, view, path, offset)


def _raw_chunk(
    compression: str, size: int, crc: int, data: bytes | memoryview, path: Path, offset: int
) -> _RawChunk:
    if size > MAX_RECORD_BYTES:
        raise CorruptEvidenceError(
            path,
            f"chunk at byte {offset} declares {size} uncompressed bytes (limit {MAX_RECORD_BYTES})",
        )
    if compression not in ("", "zstd", "lz4"):
        raise CorruptEvidenceError(
            path, f"chunk at byte {offset} uses unknown compression {compression!r}"
        )
    return _RawChunk(compression, size, crc, data)


def _decompress(raw: _RawChunk, path: Path, offset: int) -> memoryview:
    """Decompress a chunk's records to exactly their declared size and check their CRC.

    A zstd chunk is decompressed into Arrow's memory pool, which keeps its pages for the
    next chunk or file. A Python ``bytes`` object of a chunk's size is given fresh pages by
    the C allocator each time, and touching them (page faults) cost more than decompressing.
    """
    size = raw.uncompressed_size
    data: bytes | memoryview | pa.Buffer
    try:
        if raw.compression == "zstd":
            declared = zstandard.frame_content_size(raw.data)
            if declared not in (-1, size):
                raise _damaged(
                    path, offset, f"its zstd frame declares {declared} bytes, the chunk {size}"
                )
            if not size:
                data = b""
            elif _ARROW_ZSTD:  # (it fails unless the frame holds exactly ``size`` bytes)
                data = pa.decompress(raw.data, decompressed_size=size, codec="zstd")
            else:
                data = zstandard.ZstdDecompressor().decompress(raw.data, max_output_size=size)
        elif raw.compression == "lz4":
            decompressor = _lz4_frame(path).LZ4FrameDecompressor()
            data = decompressor.decompress(raw.data, max_length=size) if size else b""
            if size and not decompressor.eof:
                raise _damaged(path, offset, f"its lz4 frame holds more than {size} bytes")
        else:
            data = raw.data
    except EvidenceError:
        raise
    except Exception as exc:
        raise _damaged(path, offset, f"{type(exc).__name__}: {str(exc)[:120]}") from None
    if len(data) != size:
        raise _damaged(path, offset, f"it holds {len(data)} bytes, not the declared {size}")
    if raw.uncompressed_crc and _crc32(data) != raw.uncompressed_crc:
        raise _damaged(path, offset, "CRC mismatch")
    return memoryview(data)


def _read_and_decompress(
    f: IO[bytes], ref: _ChunkRef, path: Path, want: frozenset[int] | None = None
) -> tuple[memoryview, list[int] | None]:
    """The chunk's decompressed records and the offsets of the ``want`` channels' messages.

    The offsets come from the chunk's message index; ``None`` means: split every record.
    """
    data = _decompress(_read_chunk_record(f, ref, path), path, ref.offset)
    positions = None if want is None else _message_positions(f, ref, want, len(data))
    return data, positions


def _message_positions(
    f: IO[bytes], ref: _ChunkRef, want: frozenset[int], size: int
) -> list[int] | None:
    """Offsets, in the decompressed chunk, of the messages on ``want`` channels.

    Read from the chunk's MessageIndex records (written right after it in a finished file).
    Anything unexpected gives ``None``, and the caller splits every record instead.
    """
    if not ref.index_offsets or not 0 < ref.index_length <= MAX_RECORD_BYTES:
        return None
    start = min(offset for _, offset in ref.index_offsets)
    try:
        f.seek(start)
        region = f.read(ref.index_length)
    except OSError:
        return None
    if len(region) != ref.index_length:
        return None
    positions: list[int] = []
    try:
        for channel_id, offset in ref.index_offsets:
            if channel_id not in want:
                continue
            pos = offset - start
            if not 0 <= pos <= len(region) - _RECORD_HEAD.size:
                return None
            opcode, length = _RECORD_HEAD.unpack_from(region, pos)
            body = pos + _RECORD_HEAD.size
            if opcode != _OP_MESSAGE_INDEX or body + length > len(region):
                return None
            indexed_channel, count = _INDEX_HEAD.unpack_from(region, body)
            if indexed_channel != channel_id or count % 16 or 6 + count > length:
                return None
            entries = struct.unpack_from(f"<{count // 8}Q", region, body + 6)
            for at in entries[1::2]:
                if at >= size:
                    return None
                positions.append(at)
    except (struct.error, OverflowError):
        return None
    positions.sort()
    return positions


def _lz4_frame(path: Path) -> Any:
    try:
        return importlib.import_module("lz4.frame")
    except ImportError:
        raise EvidenceError(
            path, "the file is lz4-compressed: reading it needs the lz4 package"
        ) from None


def _split(
    data: bytes | memoryview,
    path: Path,
    offset: int,
    route: dict[int, int] | None,
    wanted: tuple[bool, bool, bool],
    channels: list[Channel],
    schemas: list[Schema] | None,
    slots: dict[str, int] = _SLOTS,
    positions: list[int] | None = None,
) -> list[tuple[int, int, memoryview, int]]:
    """Split a chunk's decompressed records; return (slot, log time, data) of wanted messages.

    ``route`` maps channel ids to slots and learns the chunk's own Channel records (appended to
    ``channels``); a message on a channel it does not know is an error. With ``route`` None
    messages are skipped (channel discovery). Schema records go to ``schemas`` when given.
    """
    view = memoryview(data)
    end = len(data)
    out: list[tuple[int, int, memoryview, int]] = []
    append = out.append
    record_head = _RECORD_HEAD.unpack_from
    message_head = _MESSAGE_HEAD.unpack_from
    keep = (False, *wanted)  # indexed by slot + 1: _OTHER, _STEPS, _RESETS, _ENDS
    if positions is not None and route is not None:
        found = _split_indexed(data, view, route, keep, positions)
        if found is not None:
            return found  # else: walk every record, which names what is wrong
    pos = 0
    try:
        while pos < end:
            opcode, length = record_head(data, pos)
            body = pos + 9
            stop = body + length
            if stop > end:
                raise _damaged(
                    path, offset, f"a record at {pos} of {length} bytes overruns its {end} bytes"
                )
            if opcode == _OP_MESSAGE:
                if route is not None:
                    if length < 22:
                        raise _damaged(path, offset, f"a message at {pos} is {length} bytes")
                    channel_id, log_time = message_head(data, body)
                    slot = route.get(channel_id)
                    if slot is None:
                        raise CorruptEvidenceError(
                            path,
                            f"message on unknown channel {channel_id} in chunk at byte {offset}",
                        )
                    if keep[slot + 1]:
                        append((slot, log_time, view[body + 22 : stop], channel_id))
            elif opcode == _OP_CHANNEL:
                channel = _inner_record(Channel, data[body:stop], path, offset, pos)
                channels.append(channel)
                if route is not None:
                    route.setdefault(channel.id, slots.get(channel.topic, _OTHER))
            elif opcode == _OP_SCHEMA and schemas is not None:
                schemas.append(_inner_record(Schema, data[body:stop], path, offset, pos))
            pos = stop
    except struct.error:
        raise _damaged(path, offset, f"a record header at {pos} is cut off") from None
    return out


def _split_indexed(
    data: bytes | memoryview,
    view: memoryview,
    route: dict[int, int],
    keep: tuple[bool, ...],
    positions: list[int],
) -> list[tuple[int, int, memoryview, int]] | None:
    """The wanted messages at the offsets a chunk's message index gave (no full walk).

    ``None`` when anything does not add up; the caller then walks every record.
    """
    end = len(data)
    out: list[tuple[int, int, memoryview, int]] = []
    try:
        for pos in positions:
            opcode, length = _RECORD_HEAD.unpack_from(data, pos)
            body = pos + 9
            stop = body + length
            if opcode != _OP_MESSAGE or stop > end or length < 22:
                return None
            channel_id, log_time = _MESSAGE_HEAD.unpack_from(data, body)
            slot = route.get(channel_id)
            if slot is None:
                return None
            if keep[slot + 1]:
                out.append((slot, log_time, view[body + 22 : stop], channel_id))
    except struct.error:
        return None
    return out


class _Exact(BytesIO):
    """A stream whose reads return exactly what was asked for, or raise."""

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        if size is not None and size >= 0 and len(data) != size:
            raise EOFError(f"{size} bytes asked for, {len(data)} left")
        return data


def _inner_record(kind: Any, body: bytes | memoryview, path: Path, offset: int, pos: int) -> Any:
    """Read a Channel or Schema record from its body (trailing bytes are allowed, per MCAP)."""
    try:
        return kind.read(ReadDataStream(_Exact(body)))
    except Exception as exc:
        raise _damaged(
            path,
            offset,
            f"the {kind.__name__} record at {pos} is unreadable ({type(exc).__name__})",
        ) from None


def _arrow_batch(data: bytes | memoryview, path: Path, topic: str) -> pa.RecordBatch:
    """Decode one block; check its framing, its data and (steps, resets) its columns."""
    # Blocks of one topic share their schema message: one already found good is not walked
    # or checked again (the record batch after it still is).
    known = _GOOD_SCHEMA_MESSAGES.get(topic, b"")
    schema_checked = len(data) > len(known) > 0 and bytes(data[: len(known)]) == known
    problem = _ipc_problem(data, len(known) if schema_checked else 0)
    if problem is not None:
        raise CorruptEvidenceError(path, f"a block on {topic} {problem}")
    try:
        reader = pa.ipc.open_stream(pa.py_buffer(data), options=_IPC_OPTIONS)
        batch = reader.read_next_batch()
        batch.validate(full=True)
    except (pa.ArrowException, StopIteration, ValueError, OSError, MemoryError) as exc:
        raise CorruptEvidenceError(
            path, f"a block on {topic} is not a valid Arrow stream: {_one_line(exc)}"
        ) from None
    schema = batch.schema
    if not schema_checked and not schema.equals(_CHECKED.get(topic, _NO_SCHEMA)):
        try:
            _decode_names(schema)
        except ValueError:
            raise CorruptEvidenceError(
                path, f"a block on {topic} has column names that are not UTF-8"
            ) from None
        required = _REQUIRED.get(topic)
        problem = None if required is None else _columns_problem(schema, required)
        if problem is not None:
            raise CorruptEvidenceError(
                path, f"a block on {topic} does not have the expected columns: {problem}"
            )
        _CHECKED[topic] = schema
    if not schema_checked:
        first = _first_message_end(data)
        if first is not None:
            _GOOD_SCHEMA_MESSAGES[topic] = bytes(data[:first])
    if topic in _NOT_NULL:
        for name in _NOT_NULL[topic]:
            if batch.column(name).null_count:
                raise CorruptEvidenceError(
                    path, f"a block on {topic} has nulls in its {name!r} column"
                )
    return batch


def step_block_rows(data: bytes | memoryview, path: Path) -> int:
    """How many rows one step block holds, the block checked as the reader checks it.

    Raises :class:`~episode_audit.errors.CorruptEvidenceError` (naming ``path``) for a block
    the reader would refuse, before decoding anything that could inflate.
    """
    return int(_arrow_batch(data, path, fmt.TOPIC_STEPS).num_rows)


def _decode_names(fields: Iterable[pa.Field]) -> None:
    """Decode every field name, nested ones too (``UnicodeDecodeError`` if one is not UTF-8)."""
    for f in fields:
        f.name  # noqa: B018 - pyarrow decodes the name here
        kind = f.type
        if isinstance(kind, (pa.StructType, pa.UnionType)):
            _decode_names(kind.field(i) for i in range(kind.num_fields))
        elif isinstance(kind, pa.MapType):
            _decode_names((kind.key_field, kind.item_field))
        elif isinstance(kind, (pa.ListType, pa.LargeListType, pa.FixedSizeListType)):
            _decode_names((kind.value_field,))


def _one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's message on one line, cut to ``limit`` characters."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


# Columns a block must have, with their types (None: any type; the space decides), and those
# that must have no nulls: from the block schemas' one definition.
_REQUIRED: dict[str, dict[str, pa.DataType | None]] = {
    topic: required_columns(topic) for topic in (fmt.TOPIC_STEPS, fmt.TOPIC_RESETS)
}
_NOT_NULL: dict[str, tuple[str, ...]] = {
    topic: key_columns(topic) for topic in (fmt.TOPIC_STEPS, fmt.TOPIC_RESETS)
}
_NO_SCHEMA = pa.schema([])
_CHECKED: dict[str, pa.Schema] = {}
"""The last block schema found good, per topic (blocks of one file share their schema)."""
_GOOD_SCHEMA_MESSAGES: dict[str, bytes] = {}
"""Per topic, the bytes of the last IPC schema message of a block found good."""


def _columns_problem(schema: pa.Schema, required: dict[str, pa.DataType | None]) -> str | None:
    """What is wrong with a block schema's columns, or None."""
    for name, kind in required.items():
        found = schema.get_all_field_indices(name)
        if len(found) != 1:
            return f"{name!r} is {'missing' if not found else 'there twice'}"
        actual = schema.field(found[0]).type
        if kind is not None and not actual.equals(kind):
            return f"{name!r} is {actual}, expected {kind}"
    return None


def _minimal_schema(topic: str) -> pa.Schema:
    """The required columns of ``topic`` (null-typed space columns): a file without blocks."""
    return pa.schema(
        [(name, pa.null() if kind is None else kind) for name, kind in _REQUIRED[topic].items()]
    )


_I32 = struct.Struct("<i")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_I64 = struct.Struct("<q")
_I32_PAIR = struct.Struct("<ii")  # continuation marker, metadata size
_IPC_SCHEMA, _IPC_DICTIONARY, _IPC_RECORD_BATCH = 1, 2, 3


def _first_message_end(data: bytes | memoryview) -> int | None:
    """Where the IPC stream's first message ends, if it is a schema without a body."""
    try:
        marker, size = _I32_PAIR.unpack_from(data, 0)
        if marker != -1 or not 0 < size <= len(data) - 8:
            return None
        kind, body_length, _ = _ipc_message(data, 8, size)
    except (struct.error, IndexError):
        return None
    return 8 + int(size) if kind == _IPC_SCHEMA and body_length == 0 else None


def _ipc_problem(data: bytes | memoryview, start: int = 0) -> str | None:
    """Refuse what our blocks never hold and what could inflate: compressed or dictionary bodies.

    Walks the Arrow IPC stream's framing (from the message at ``start``) up to its first record
    batch, reading each message's flatbuffer header by hand (an IPC body may be LZ4/ZSTD-
    compressed, buffer by buffer, with declared sizes that pyarrow would allocate before any
    check). Returns None when fine; a stream cut short is left to pyarrow to report.
    """
    end = len(data)
    pos = start
    try:
        while pos + 8 <= end:
            (size,) = _I32.unpack_from(data, pos)
            if size == -1:  # continuation marker, then the metadata size
                (size,) = _I32.unpack_from(data, pos + 4)
                pos += 8
            else:
                pos += 4
            if size <= 0 or pos + size > end:
                return None  # end of stream, or cut short: pyarrow says which
            kind, body_length, compressed = _ipc_message(data, pos, size)
            if kind == _IPC_DICTIONARY:
                return "holds an Arrow dictionary batch (blocks never do)"
            if compressed:
                return "uses Arrow IPC body compression (blocks never do)"
            if kind == _IPC_RECORD_BATCH:
                return None
            if kind != _IPC_SCHEMA or body_length < 0:
                return (
                    f"is not a valid Arrow stream: an IPC message of type {kind} before its batch"
                )
            pos += size + body_length
    except (struct.error, IndexError):
        return "is not a valid Arrow stream: its message headers are cut off or garbled"
    return None


def _ipc_message(data: bytes | memoryview, start: int, size: int) -> tuple[int, int, bool]:
    """(header type, body length, body compressed) of the Message flatbuffer at ``start``.

    Message: version (field 0), header_type (1), header (2), bodyLength (3). The header is a
    RecordBatch (compression: field 3) or a DictionaryBatch (data: field 1, a RecordBatch).
    """
    stop = start + size

    def table(at: int) -> tuple[int, int, int]:
        vtable = at - _I32.unpack_from(data, at)[0]
        if not start <= vtable < stop or not start <= at < stop:
            raise IndexError("flatbuffer offset outside the message")
        return at, vtable, _U16.unpack_from(data, vtable)[0]

    def field_at(t: tuple[int, int, int], index: int) -> int:
        """A field's position, 0 when absent."""
        at, vtable, vsize = t
        slot = 4 + 2 * index
        offset = _U16.unpack_from(data, vtable + slot)[0] if slot + 2 <= vsize else 0
        return at + offset if offset else 0

    def child(t: tuple[int, int, int], index: int) -> tuple[int, int, int] | None:
        at = field_at(t, index)
        return table(at + _U32.unpack_from(data, at)[0]) if at else None

    root = table(start + _U32.unpack_from(data, start)[0])
    kind_at = field_at(root, 1)
    kind = data[kind_at] if kind_at else 0
    length_at = field_at(root, 3)
    body_length = _I64.unpack_from(data, length_at)[0] if length_at else 0
    header = child(root, 2)
    if kind == _IPC_DICTIONARY and header is not None:
        header = child(header, 1)
    compressed = kind in (_IPC_RECORD_BATCH, _IPC_DICTIONARY) and (
        header is not None and child(header, 3) is not None
    )
    return kind, body_length, compressed


# ------------------------------------------------------------------- episode records

# Configured as json.loads's own decoder; scan_once(text, index) -> (value, end index).
_SCAN_ONCE: Any = json.JSONDecoder().scan_once  # type: ignore[attr-defined]
_COMPACT = json.JSONEncoder(separators=(",", ":"))  # as json.dumps(..., separators=(",", ":"))
_OUTCOMES = frozenset(fmt.OUTCOMES)
_NO_ERROR: dict[str, Any] = {}
_NO_TERMS: tuple[tuple[str, float], ...] = ()
_GROUP = 128  # end records parsed at a time (few parsed objects alive: less GC work)
_SPLIT_VALUE = "\x00episode-audit:split\x00"
_SPLIT = f",{_COMPACT.encode(_SPLIT_VALUE)},"


class _Irregular(Exception):
    """The fast parse cannot vouch for a record: parse them one by one instead."""


def _number(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, str):
        return float(value)  # "nan", "inf", "-inf"
    return float(value)


def _episode_record(data: bytes, path: Path) -> dict[str, Any]:
    if len(data) > MAX_JSON_BYTES:
        raise CorruptEvidenceError(
            path, f"episode record of {len(data)} bytes exceeds the 1 MiB limit"
        )
    try:
        record = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CorruptEvidenceError(path, f"episode record is not valid JSON: {exc}") from None
    except RecursionError:
        raise CorruptEvidenceError(
            path, "episode record is not valid JSON: nested too deeply"
        ) from None
    if not isinstance(record, dict):
        raise CorruptEvidenceError(path, "episode record is not a JSON object")
    for key, kind in (("episode", int), ("outcome", str), ("length", int)):
        if not isinstance(record.get(key), kind) or isinstance(record.get(key), bool):
            raise CorruptEvidenceError(
                path, f"episode record lacks {key!r} of type {kind.__name__}: {str(record)[:120]}"
            )
    if record["outcome"] not in fmt.OUTCOMES:
        raise CorruptEvidenceError(
            path, f"episode record has unknown outcome {record['outcome']!r}"
        )
    return record


def _episode_blocks(blocks: list[pa.RecordBatch | bytes], path: Path) -> pa.Table:
    """The episode Arrow blocks as one table of :data:`EPISODE_SCHEMA` (``ended`` all true).

    ``blocks`` are raw blocks or those :func:`_episode_part` already decoded.
    """
    parts = _decode_kept(blocks, _episode_part, path)
    if all(part.num_columns == len(_BLOCK_BASE) for part in parts):  # no block has game
        table = pa.Table.from_batches(parts, schema=_BLOCK_BASE).combine_chunks()
        table = table.append_column(
            _BLOCK_SCHEMA.field("game"), pa.nulls(table.num_rows, pa.int64())
        )
    else:
        parts = [
            part
            if part.num_columns == len(_BLOCK_SCHEMA)
            else pa.RecordBatch.from_arrays(
                [*part.columns, pa.nulls(part.num_rows, pa.int64())], schema=_BLOCK_SCHEMA
            )
            for part in parts
        ]
        table = pa.Table.from_batches(parts, schema=_BLOCK_SCHEMA).combine_chunks()
    for name in ("episode", "outcome", "length"):
        if table.column(name).null_count:
            raise CorruptEvidenceError(path, f"an episode block has nulls in its {name!r} column")
    unknown = pc.filter(
        table.column("outcome"),
        pc.invert(pc.is_in(table.column("outcome"), pa.array(fmt.OUTCOMES, pa.string()))),
    )
    if len(unknown):
        raise CorruptEvidenceError(
            path, f"an episode block has unknown outcome {unknown[0].as_py()!r}"
        )
    ended = pa.array(np.ones(table.num_rows, dtype=np.bool_))
    return table.append_column(EPISODE_SCHEMA.field("ended"), ended)


def _episode_part(data: bytes, path: Path) -> pa.RecordBatch:
    """One episode block, decoded and checked: the columns of :data:`_BLOCK_SCHEMA` it has.

    Blocks hold at least the columns of format 1.0's first files (:data:`_BLOCK_BASE`); the
    optional ``game`` column is null when a block lacks it; other columns are ignored.
    """
    batch = _arrow_batch(data, path, fmt.TOPIC_EPISODES)
    schema = batch.schema
    _check_episode_block(schema, path)
    target = _BLOCK_SCHEMA if "game" in schema.names else _BLOCK_BASE
    # Types were compared, never cast: a cast (or a null column made to fill in) before the
    # checks would allocate for the row count a block declares, which a hostile block can
    # make huge. Columns a later 1.x may add are left out (select() copies nothing).
    part = batch.select(target.names)
    if not part.schema.equals(target):  # names and types agree; nullability may not
        part = pa.RecordBatch.from_arrays(part.columns, schema=target)
    return part


def _reset_block(data: bytes, path: Path) -> pa.RecordBatch:
    return _arrow_batch(data, path, fmt.TOPIC_RESETS)


def _decode_kept(
    kept: list[pa.RecordBatch | bytes], decode: Callable[[bytes, Path], pa.RecordBatch], path: Path
) -> list[pa.RecordBatch]:
    """The blocks a pass kept, decoding those it kept as bytes (see :class:`_Gathered`)."""
    return [data if isinstance(data, pa.RecordBatch) else decode(data, path) for data in kept]


def _check_episode_block(schema: pa.Schema, path: Path) -> None:
    """An episode block starts with the base columns and has the episode columns' types."""
    names = schema.names
    if names[: len(_BLOCK_BASE)] != _BLOCK_BASE.names:
        raise CorruptEvidenceError(path, "an episode block does not have the episode columns")
    for name in _BLOCK_SCHEMA.names:
        if name not in names:
            continue
        actual, expected = schema.field(name).type, _BLOCK_SCHEMA.field(name).type
        if not actual.equals(expected):
            raise CorruptEvidenceError(
                path, f"an episode block has wrong types: {name!r} is {actual}, expected {expected}"
            )


def _end_record_columns(records: list[bytes], path: Path) -> dict[str, list[Any]]:
    """Parse and check the episode end records; return their columns, in file order.

    Records are parsed :data:`_GROUP` at a time, each group from one string, and turned into
    column values at once (so few parsed objects are alive at a time). Whenever the fast parse
    cannot vouch for giving exactly what ``json.loads`` of each record would (non-ASCII bytes,
    whitespace around a record, anything invalid or unexpected), the group is parsed record by
    record with the checks and error messages of :func:`_episode_record`.
    """
    columns: dict[str, list[Any]] = {name: [] for name in EPISODE_COLUMNS}
    for first in range(0, len(records), _GROUP):
        group = records[first : first + _GROUP]
        try:
            parsed = _parse_joined(group)
        except _Irregular:
            parsed = [_episode_record(data, path) for data in group]
        for name, values in _record_columns(parsed).items():
            columns[name].extend(values)
    return columns


def _parse_joined(records: list[bytes]) -> list[dict[str, Any]]:
    if any(len(data) > MAX_JSON_BYTES for data in records):
        raise _Irregular
    blob = b"\n".join(records)
    if not blob.isascii():
        raise _Irregular
    # ASCII: byte and character offsets agree, and json.loads would decode each record as UTF-8.
    text = blob.decode("ascii")
    scan = _SCAN_ONCE
    parsed: list[dict[str, Any]] = []
    append = parsed.append
    pos = 0
    try:
        for data in records:
            stop = pos + len(data)
            # A record that starts with "{" and parses as one value up to its last byte is
            # what json.loads parses it to: the scanner stops at the object's closing brace.
            if not data.startswith(b"{"):
                raise _Irregular
            record, end = scan(text, pos)
            if end != stop:
                raise _Irregular
            append(record)
            pos = stop + 1
    except (StopIteration, ValueError, RecursionError):
        raise _Irregular from None
    types = {type(r.get("episode")) for r in parsed} | {type(r.get("length")) for r in parsed}
    if parsed and types != {int}:
        raise _Irregular
    if not all(type(r.get("outcome")) is str and r["outcome"] in _OUTCOMES for r in parsed):
        raise _Irregular
    return parsed


def _record_columns(recs: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """The episodes-table values of checked end records (as the rows of ``from_pylist``).

    A record with a value that cannot be converted gets an :class:`_Unconvertible` in its
    ``ended`` column: it is an error only if no later record of its episode replaces it.
    """
    try:
        return _columns_of(recs)
    except (AttributeError, TypeError, ValueError, OverflowError):
        pass
    columns: dict[str, list[Any]] = {name: [] for name in EPISODE_COLUMNS}
    for r in recs:
        try:
            one = _columns_of([r])
        except (AttributeError, TypeError, ValueError, OverflowError) as exc:
            one = _columns_of([{k: r[k] for k in ("episode", "outcome", "length")}])
            one["ended"] = [_Unconvertible(f"{type(exc).__name__}: {exc}")]
        for name, values in one.items():
            columns[name].extend(values)
    return columns


def _columns_of(recs: list[dict[str, Any]]) -> dict[str, list[Any]]:
    errors = [r.get("error") or _NO_ERROR for r in recs]
    return {
        "episode": [r["episode"] for r in recs],
        "env_index": [r.get("env_index", 0) for r in recs],
        "agent": [r.get("agent") for r in recs],
        "seed": [r.get("seed") for r in recs],
        "rng_state": _json_column([r.get("rng_state") for r in recs]),
        "options": _json_column([r.get("options") for r in recs]),
        "outcome": [r["outcome"] for r in recs],
        "failure_label": [r.get("failure_label") for r in recs],
        "truncation_reason": [r.get("truncation_reason") for r in recs],
        "terminated": [bool(r.get("terminated", False)) for r in recs],
        "truncated": [bool(r.get("truncated", False)) for r in recs],
        "length": [r["length"] for r in recs],
        "return": [v if type(v) is float else _number(v) for v in [r.get("return") for r in recs]],
        "term_totals": [
            [(str(k), _number(v)) for k, v in t.items()] if t else _NO_TERMS
            for t in [r.get("term_totals") for r in recs]
        ],
        "start_time_ns": [r.get("start_time_ns") for r in recs],
        "end_time_ns": [r.get("end_time_ns") for r in recs],
        "error_type": [e.get("type") for e in errors],
        "error_message": [e.get("message") for e in errors],
        "error_during": [e.get("during") for e in errors],
        "notes": [r.get("notes", 0) for r in recs],
        "game": [r.get("game") for r in recs],
        "ended": [True] * len(recs),
    }


@dataclass(frozen=True)
class _Unconvertible:
    """In place of an end record whose values could not be converted (why)."""

    why: str


def _episode_table(
    path: Path, columns: dict[str, list[Any]], starts: dict[int, Any], stats: _StepStats
) -> pa.Table:
    """Order the end records' columns by episode and add the episodes that have none."""
    episodes = columns["episode"]
    increasing = all(a < b for a, b in pairwise(episodes))
    ended = set(episodes)
    missing = (starts.keys() | stats.lengths.keys()) - ended
    if missing or not increasing:
        position = {e: i for i, e in enumerate(episodes)}  # a later duplicate wins
        order = sorted(ended | missing)
        source = [position.get(e, -1) for e in order]
        for name, values in columns.items():
            values.append(None)  # what -1 picks, overwritten below
            columns[name] = [values[i] for i in source]
        for pos, index in enumerate(order):
            if index in missing:
                for name, value in _incomplete_row(index, starts.get(index), stats).items():
                    columns[name][pos] = value
    for kept in columns["ended"]:
        if isinstance(kept, _Unconvertible):
            raise CorruptEvidenceError(path, f"episode records have wrong types: {kept.why}")
    try:
        return pa.Table.from_arrays(
            [columns[name] for name in EPISODE_COLUMNS], schema=EPISODE_SCHEMA
        )
    except (pa.ArrowException, TypeError, ValueError, OverflowError) as exc:
        raise CorruptEvidenceError(
            path, f"episode records have wrong types: {_one_line(exc)}"
        ) from None


def _incomplete_row(index: int, start: dict[str, Any] | None, stats: _StepStats) -> dict[str, Any]:
    """The row of an episode without an end record: from its reset row and its steps."""
    start = start or {}
    return {
        "episode": index,
        "env_index": start.get("env_index", 0),
        "agent": start.get("agent"),
        "seed": start.get("seed"),
        "rng_state": start.get("rng_state"),
        "options": start.get("options"),
        "outcome": fmt.OUTCOME_INCOMPLETE,
        "failure_label": None,
        "truncation_reason": None,
        "terminated": False,
        "truncated": False,
        "length": stats.lengths.get(index, 0),
        "return": stats.returns.get(index, 0.0),
        "term_totals": None,
        "start_time_ns": start.get(fmt.COL_TIME),
        "end_time_ns": stats.last_time.get(index, start.get(fmt.COL_TIME)),
        "error_type": None,
        "error_message": None,
        "error_during": None,
        "notes": None,
        "game": start.get("game"),
        "ended": False,
    }


def _json_column(values: list[Any]) -> list[str | None]:
    """``_json_or_none`` of each value, all encoded in one call.

    The values are encoded as one JSON array with a sentinel string between them, and the text
    split at ``,<sentinel>,``. Inside an encoded value a quote after a comma always opens a
    string, so the separator occurs there only where a list holds the sentinel string itself
    (not first, not last); then the count is off and each value is encoded alone.
    """
    present = [v for v in values if v is not None]
    if not present:
        return [None] * len(values)
    encode = _COMPACT.encode
    texts: list[str | None] = []
    if len(present) > 1:
        spaced: list[Any] = [_SPLIT_VALUE] * (2 * len(present) - 1)
        spaced[::2] = present
        texts = list(encode(spaced)[1:-1].split(_SPLIT))
    if len(texts) != len(present):
        texts = [encode(v) for v in present]
    if len(present) == len(values):
        return texts
    it = iter(texts)
    return [None if v is None else next(it) for v in values]


# ------------------------------------------------------------------- opening


def open_evidence(path: str | os.PathLike[str]) -> Evidence:
    """Open an evidence file (finished, or torn by a crash) for reading.

    Raises :class:`~episode_audit.errors.NotEvidenceError` for a file that is not evidence,
    :class:`~episode_audit.errors.UnsupportedVersionError` for a newer major format version, and
    :class:`~episode_audit.errors.CorruptEvidenceError` for damage a crash cannot explain.

    >>> open_evidence("no/such/file.mcap")
    Traceback (most recent call last):
    ...
    episode_audit.errors.EvidenceError: no/such/file.mcap: cannot open: No such file or directory
    """
    p = Path(path)
    with _open_mcap(p) as f:
        damage = _summary_damage(f)
        f.seek(0)
        indexed = None if damage else _open_indexed(f, p)
        if indexed is None:
            f.seek(0)
            ev = _open_linear(f, p, past_data_end=damage is None)
            ev.summary_damage = damage
            return ev
        return indexed


def _open_mcap(p: Path) -> IO[bytes]:
    """Open ``p`` for reading, just after the MCAP magic bytes.

    Raises :class:`~episode_audit.errors.NotEvidenceError` for what is not a regular file
    (a FIFO would block) or does not start like MCAP, and
    :class:`~episode_audit.errors.EvidenceError` for a file that cannot be opened.
    """
    try:
        if not stat.S_ISREG(os.stat(p).st_mode):
            raise NotEvidenceError(p, "not a regular file")
        f = open(p, "rb")  # noqa: SIM115
    except OSError as exc:
        raise EvidenceError(p, f"cannot open: {exc.strerror}") from None
    try:
        head = f.read(len(_MAGIC))
        if len(head) == 0:
            raise NotEvidenceError(p, "the file is empty")
        if head != _MAGIC:
            raise NotEvidenceError(p, "not an MCAP file (wrong magic bytes)")
    except BaseException:
        f.close()
        raise
    return f


def _parse_run(
    path: Path, metadata: dict[str, dict[str, str]], header: Header | None, torn: str | None = None
) -> tuple[RunInfo, dict[str, str] | None]:
    if header is not None and header.profile != fmt.MCAP_PROFILE:
        raise NotEvidenceError(
            path,
            f"an MCAP file, but not evidence (profile {header.profile!r}, "
            f"expected {fmt.MCAP_PROFILE!r})",
        )
    raw = metadata.get(fmt.METADATA_RUN)
    if raw is None and torn is not None and header is not None:
        raise CorruptEvidenceError(
            path,
            f"an evidence file torn before its run metadata was written ({torn}): "
            "it holds no evidence (a recorder killed as it started leaves such a file)",
        )
    if raw is None:
        raise NotEvidenceError(
            path, f"no {fmt.METADATA_RUN!r} metadata record: not an evidence file"
        )
    version = raw.get("format_version", "")
    try:
        major = fmt.format_major(version)
    except ValueError:
        raise CorruptEvidenceError(path, f"format_version {version!r} is not a version") from None
    if major > fmt.FORMAT_MAJOR:
        raise UnsupportedVersionError(
            path,
            f"written with format {version}, newer than this reader ({fmt.FORMAT_VERSION}); "
            "upgrade episode-audit",
        )
    if any(len(v) > MAX_JSON_BYTES for v in raw.values()):
        raise CorruptEvidenceError(path, "run metadata value exceeds the 1 MiB limit")
    try:
        run = RunInfo.from_metadata(raw)
    except (ValueError, TypeError) as exc:
        raise CorruptEvidenceError(path, _one_line(exc)) from None
    except RecursionError:
        raise CorruptEvidenceError(path, "run metadata is nested too deeply") from None
    return run, metadata.get(fmt.METADATA_RUN_END)


def _schemas_of(schemas: Iterable[Schema]) -> dict[int, pa.Schema]:
    out: dict[int, pa.Schema] = {}
    for schema in schemas:
        if schema.encoding == fmt.ARROW_ENCODING:
            try:
                out[schema.id] = pa.ipc.read_schema(pa.py_buffer(schema.data))
            except (pa.ArrowException, OSError, ValueError):
                continue
    return out


def _open_indexed(f: IO[bytes], path: Path) -> Evidence | None:
    """Open through the summary; ``None`` when the file has no usable summary (torn)."""
    try:
        reader = SeekingReader(f, record_size_limit=MAX_RECORD_BYTES)
        summary = reader.get_summary()
        if summary is None:
            return None
        header = reader.get_header()
    except Exception:
        return None
    metadata: dict[str, dict[str, str]] = {}
    run_end_damage: str | None = None
    for index in summary.metadata_indexes:
        record = _metadata_at(f, index.offset, index.name)
        if record is not None:
            metadata[record.name] = dict(record.metadata)
            continue
        if not _footer_crc(f):  # a summary nothing vouches for: scan the data section instead
            return None
        what = f"the {index.name} metadata record at byte {index.offset} is garbled"
        if index.name == fmt.METADATA_RUN:
            raise CorruptEvidenceError(
                path,
                f"{what}: the spaces, env and settings of the run it held are lost, so the "
                "file cannot be read as evidence",
            )
        if index.name == fmt.METADATA_RUN_END:
            run_end_damage = what
    run, run_end = _parse_run(path, metadata, header)
    chunks = sorted(
        (
            _ChunkRef(
                c.chunk_start_offset,
                c.message_start_time,
                c.message_end_time,
                c.compressed_size,
                c.uncompressed_size,
                tuple(sorted(c.message_index_offsets.items())),
                c.message_index_length,
            )
            for c in summary.chunk_indexes
        ),
        key=lambda c: c.offset,
    )
    finished = run_end is not None or run_end_damage is not None
    ev = Evidence(path, run, finished, run_end, None, chunks, dict(summary.channels))
    ev.run_end_damage = run_end_damage
    ev._schema_cache = _schemas_of(summary.schemas.values())  # type: ignore[attr-defined]
    return ev


def _metadata_at(f: IO[bytes], offset: int, name: str) -> Metadata | None:
    """The metadata record ``name`` a summary locates at ``offset``; ``None`` if garbled.

    Its body must parse to exactly its declared length, as :func:`iter_records` reads it.
    """
    try:
        f.seek(offset)
        opcode, length = _RECORD_HEAD.unpack(f.read(_RECORD_HEAD.size))
        if opcode != _OP_METADATA or length > MAX_RECORD_BYTES:
            return None
        body = f.read(length)
        record = _top_level(opcode, body) if len(body) == length else None
    except (struct.error, OSError, _Unreadable):
        return None
    return record if isinstance(record, Metadata) and record.name == name else None


_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, offsets start, summary CRC
_OP_FOOTER_BODY = 20  # the footer's length field: three fields of 8, 8 and 4 bytes


def _summary_damage(f: IO[bytes]) -> str | None:
    """Why the end of a finished file (summary, footer, magic) is damaged, or ``None``.

    ``None`` also for a torn file, which ends with neither a footer nor the magic. The
    footer's CRC covers the summary section through the footer's own offset fields (MCAP
    spec); a writer may leave it 0 (not computed), which is accepted.
    """
    size = os.fstat(f.fileno()).st_size
    tail = _tail(f, size)
    if tail is None:
        return None
    start, crc = tail.summary_start, tail.summary_crc
    if not tail.magic_ok:
        # a whole footer, pointing inside the file, before 8 bytes that are not the magic:
        # the magic was damaged (a torn file does not end with a footer)
        inside = max(start, tail.offsets_start) < size - _TAIL_BYTES
        return "the closing magic bytes are damaged" if tail.footer_ok and inside else None
    if not tail.footer_ok:
        return "the footer record before the closing magic is damaged"
    if start == 0 or crc == 0:
        return None
    end = size - len(_MAGIC) - 4  # through the footer's summary_offset_start field
    if not len(_MAGIC) <= start < end:
        return f"the footer puts the summary section at byte {start}, outside the file"
    f.seek(start)
    crc_now, left = 0, end - start
    while left:
        block = f.read(min(left, 1 << 20))
        if not block:
            break
        crc_now = _crc32(block, crc_now)
        left -= len(block)
    if crc_now != crc:
        return f"the summary section at bytes {start}-{end} does not match the footer's CRC"
    return None


class _Tail(NamedTuple):
    """The last bytes of a file, read as a footer record and the closing magic."""

    footer_ok: bool  # the footer record's opcode and length are right
    magic_ok: bool
    summary_start: int
    offsets_start: int
    summary_crc: int


_TAIL_BYTES = _FOOTER.size + len(_MAGIC)


def _tail(f: IO[bytes], size: int) -> _Tail | None:
    """Where a footer and the closing magic go, at the end of a file (``None``: too short)."""
    if size < len(_MAGIC) + _TAIL_BYTES:
        return None
    f.seek(size - _TAIL_BYTES)
    raw = f.read(_TAIL_BYTES)
    opcode, length, start, offsets, crc = _FOOTER.unpack(raw[: _FOOTER.size])
    footer_ok = opcode == _OP_FOOTER and length == _OP_FOOTER_BODY
    return _Tail(footer_ok, raw[_FOOTER.size :] == _MAGIC, start, offsets, crc)


def _footer(f: IO[bytes]) -> tuple[int, int] | None:
    """A whole footer's (summary start, summary CRC) before the closing magic, if any."""
    tail = _tail(f, os.fstat(f.fileno()).st_size)
    if tail is None or not (tail.footer_ok and tail.magic_ok):
        return None
    return tail.summary_start, tail.summary_crc


def _footer_crc(f: IO[bytes]) -> int:
    """The footer's summary CRC (0 without a footer, or when the writer did not compute it)."""
    found = _footer(f)
    return 0 if found is None else found[1]


def _open_linear(f: IO[bytes], path: Path, *, past_data_end: bool = True) -> Evidence:
    """Scan a file without a usable summary; keep every complete chunk.

    With ``past_data_end`` false (a file whose footer and closing magic are there, but whose
    summary does not match the footer's CRC) the scan stops at the data section's end record:
    what follows is the summary, which only repeats and indexes the data section.
    """
    reader = StreamReader(f, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES)
    header: Header | None = None
    metadata: dict[str, dict[str, str]] = {}
    chunks: list[_ChunkRef] = []
    channels: dict[int, Channel] = {}
    schemas: list[Schema] = []
    torn: str | None = None
    good_end = 0
    footer = False
    size = os.fstat(f.fileno()).st_size
    records = reader.records
    while True:
        start = good_end
        try:
            record = next(records)
        except StopIteration:
            break
        except (
            McapError,
            EvidenceError,
            ValueError,
            EOFError,
            zlib.error,
            OSError,
            MemoryError,
        ):
            if start >= size and footer:  # the closing magic bytes were never written
                torn = f"ends at byte {size} without the closing magic: the writer did not finish"
                break
            if start >= size:  # stopped at a record boundary: nothing to drop
                break
            torn = (
                f"torn at byte {start} of {size}: the last {size - start} bytes "
                "(a record cut short) were dropped"
            )
            break
        except Exception:
            torn = (
                f"torn at byte {start} of {size}: the record there is cut short or garbled; "
                "the rest was dropped"
            )
            break
        good_end = f.tell()
        if isinstance(record, Header):
            header = record
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Chunk):
            chunks.append(
                _ChunkRef(
                    start,
                    record.message_start_time,
                    record.message_end_time,
                    len(record.data),
                    record.uncompressed_size,
                )
            )
            if not channels:
                raw = _raw_chunk(
                    record.compression,
                    record.uncompressed_size,
                    record.uncompressed_crc,
                    record.data,
                    path,
                    start,
                )
                found: list[Channel] = []
                _split(_decompress(raw, path, start), path, start, None, _NOTHING, found, schemas)
                channels.update((channel.id, channel) for channel in found)
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Schema):
            schemas.append(record)
        elif isinstance(record, DataEnd) and not past_data_end:
            footer = True  # (the footer was found already, behind the damaged summary)
            break
        elif isinstance(record, Footer):
            footer = True
    if header is None:
        raise NotEvidenceError(path, "no MCAP header: the file is torn before any evidence")
    if torn is None and not footer:
        torn = f"ends at byte {size} without a summary: the writer did not finish"
    run, run_end = _parse_run(path, metadata, header, torn)
    finished = footer and run_end is not None and torn is None
    ev = Evidence(path, run, finished, run_end, None if finished else torn, chunks, channels)
    ev._schema_cache = _schemas_of(schemas)  # type: ignore[attr-defined]
    return ev


# ------------------------------------------------------------------- raw records (recovery)

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
_FULL_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_DATA_END = struct.Struct("<BQI")  # opcode, length (4), data section CRC


@dataclass(frozen=True)
class ChunkRecords:
    """One complete chunk as :func:`iter_records` yields it.

    Attributes:
        offset: The chunk record's byte offset in the file.
        records: Its Schema, Channel and Message records (``mcap.records`` types), in order.
    """

    offset: int
    records: list[Schema | Channel | Message]


@dataclass(frozen=True)
class FileEnd:
    """Where the readable part of a file ends, as the last item of :func:`iter_records`.

    Attributes:
        offset: The byte offset just after the last complete record read.
        size: The file's size; ``size - offset`` bytes were not read (a torn tail).
        cut_opcode: The MCAP opcode of the record cut off at ``offset`` (``None`` when nothing
            was cut, or when the tail is too short to hold one).
        footer: Whether the walk reached the footer (the writer finished the file).
    """

    offset: int
    size: int
    cut_opcode: int | None
    footer: bool


@dataclass(frozen=True)
class DamagedRegion:
    """Bytes :func:`iter_records` skipped with ``skip_damaged``.

    A damaged chunk, or a stretch whose record framing is garbled (then up to the next record
    the file's summary locates).

    Attributes:
        offset: Where the skipped bytes start (a chunk record's offset for a damaged chunk).
        length: How many bytes were skipped.
        why: What was wrong, in words (e.g. ``chunk at byte 24389 is damaged (CRC mismatch)``).
        metadata: The name of the metadata record the file's summary locates at ``offset``
            (e.g. ``episode_audit.run_end``), when the skipped bytes are that record.
    """

    offset: int
    length: int
    why: str
    metadata: str | None = None


def iter_records(
    path: str | os.PathLike[str], *, skip_damaged: bool = False
) -> Iterator[
    Header | Metadata | Schema | Channel | Message | ChunkRecords | DamagedRegion | FileEnd
]:
    """Walk a file's data section record by record, in file order (what recovery copies).

    Yields the Header, Metadata records, each complete chunk's records (decompressed and
    CRC-checked), records written outside chunks, and last a :class:`FileEnd`. The walk stops
    at the footer or at the first record that is cut off or unreadable (the torn tail a killed
    writer leaves); summary records are skipped.

    Damage inside a complete chunk raises :class:`~episode_audit.errors.CorruptEvidenceError`;
    with ``skip_damaged`` the walk yields a :class:`DamagedRegion` for it instead and goes on
    with the next record. When the file has a readable summary (it was finished), garbled
    framing is skipped too, up to the next chunk or metadata record the summary locates: only
    bytes after the last of those end the walk.
    """
    p = Path(path)
    with _open_mcap(p) as f:
        size = os.fstat(f.fileno()).st_size
        known, names = _record_starts(f) if skip_damaged else ([], {})
        f.seek(len(_MAGIC))
        pos = len(_MAGIC)
        summary = False

        while True:
            head = f.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                yield FileEnd(pos, size, head[0] if head else None, False)
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            stop = pos + _RECORD_HEAD.size + length
            bad: str | None = None
            at = bisect.bisect_right(known, pos)  # the next record the summary locates, if any
            nxt = known[at] if at < len(known) else None
            name = names.get(pos)  # the metadata record the summary locates here, if any
            what = "a record" if name is None else f"the {name} metadata record"
            if length > MAX_RECORD_BYTES or stop > size:
                bad = f"{what} at byte {pos} declares {length} bytes, past the end of the file"
            elif not summary and nxt is not None and stop > nxt:
                bad = f"{what} at byte {pos} overruns the record the summary locates at {nxt}"
            elif name is not None and opcode != _OP_METADATA:
                bad = f"{what} at byte {pos} is garbled (opcode {opcode:#04x})"
            if bad is not None:
                if nxt is None:
                    yield FileEnd(pos, size, opcode, False)
                    return
                yield DamagedRegion(pos, nxt - pos, bad, name)
                pos = nxt
                f.seek(pos)
                continue
            if opcode == _OP_CHUNK and not summary:
                try:
                    raw = _read_chunk_record(f, _ChunkRef(pos, 0, 0, 0, 0), p)
                    item: ChunkRecords | DamagedRegion = ChunkRecords(
                        pos, _chunk_records(_decompress(raw, p, pos).tobytes(), p, pos)
                    )
                except CorruptEvidenceError as exc:
                    if not skip_damaged:
                        raise
                    item = DamagedRegion(pos, stop - pos, exc.problem.removesuffix(_RECOVER_HINT))
                yield item
            else:
                body = f.read(length)
                if opcode == _OP_FOOTER:
                    yield FileEnd(stop, size, None, True)
                    return
                if opcode == _OP_DATA_END:
                    summary = True
                elif not summary and opcode in _TOP_LEVEL:
                    try:
                        yield _top_level(opcode, body)
                    except _Unreadable:
                        if nxt is None:
                            yield FileEnd(pos, size, opcode, False)
                            return
                        yield DamagedRegion(
                            pos, nxt - pos, f"{what} at byte {pos} is garbled", name
                        )
                        stop = nxt
            pos = stop
            f.seek(pos)


def _record_starts(f: IO[bytes]) -> tuple[list[int], dict[int, str]]:
    """Offsets of the records a file's summary locates, and the metadata records' names.

    The chunks and metadata records, and the data-end record just before the summary
    section: so a garbled record is skipped up to the next one even when it is the last
    metadata record (the run-end record). None without a summary.
    """
    summary = _summary(f)
    if summary is None:
        return [], {}
    starts = {c.chunk_start_offset for c in summary.chunk_indexes}
    names = {m.offset: m.name for m in summary.metadata_indexes}
    starts.update(names)
    found = _footer(f)
    data_end = (found[0] if found else 0) - _DATA_END.size
    if data_end > len(_MAGIC):
        f.seek(data_end)
        head = f.read(_DATA_END.size)
        if len(head) == _DATA_END.size and _DATA_END.unpack(head)[:2] == (_OP_DATA_END, 4):
            starts.add(data_end)
    return sorted(starts), names


def _summary(f: IO[bytes]) -> Any:
    """The file's MCAP summary, or ``None`` when it has no readable one (torn, damaged)."""
    if _summary_damage(f):
        return None
    try:
        f.seek(0)
        return SeekingReader(f, record_size_limit=MAX_RECORD_BYTES).get_summary()
    except Exception:
        return None


def summary_definitions(path: str | os.PathLike[str]) -> tuple[list[Schema], list[Channel]]:
    """The Schema and Channel records of a file's summary (empty lists without a summary).

    A finished file repeats there the definitions its first chunk holds, so a recovery can
    decode the later chunks even when that one is damaged.
    """
    with _open_mcap(Path(path)) as f:
        summary = _summary(f)
    if summary is None:
        return [], []
    return list(summary.schemas.values()), list(summary.channels.values())


class _Unreadable(Exception):
    """A complete top-level record whose body does not parse: the walk stops there."""


_TOP_LEVEL = frozenset({_OP_HEADER, _OP_METADATA, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE})


def _top_level(opcode: int, body: bytes) -> Header | Metadata | Schema | Channel | Message:
    try:
        if opcode == _OP_MESSAGE:
            return _message(body, 0, len(body))
        kind: Any = {
            _OP_HEADER: Header,
            _OP_METADATA: Metadata,
            _OP_SCHEMA: Schema,
            _OP_CHANNEL: Channel,
        }[opcode]
        record: Header | Metadata | Schema | Channel = kind.read(ReadDataStream(_Exact(body)))
        return record
    except Exception:
        raise _Unreadable from None


def _message(data: bytes, body: int, stop: int) -> Message:
    channel_id, sequence, log_time, publish_time = _FULL_MESSAGE_HEAD.unpack_from(data, body)
    return Message(
        channel_id=channel_id,
        log_time=log_time,
        data=data[body + _FULL_MESSAGE_HEAD.size : stop],
        publish_time=publish_time,
        sequence=sequence,
    )


def _chunk_records(data: bytes, path: Path, offset: int) -> list[Schema | Channel | Message]:
    """Every Schema, Channel and Message record of a decompressed chunk, in order."""
    out: list[Schema | Channel | Message] = []
    pos, end = 0, len(data)
    try:
        while pos < end:
            opcode, length = _RECORD_HEAD.unpack_from(data, pos)
            body = pos + _RECORD_HEAD.size
            stop = body + length
            if stop > end:
                raise _damaged(
                    path, offset, f"a record at {pos} of {length} bytes overruns its {end} bytes"
                )
            if opcode == _OP_MESSAGE:
                if length < _FULL_MESSAGE_HEAD.size:
                    raise _damaged(path, offset, f"a message at {pos} is {length} bytes")
                out.append(_message(data, body, stop))
            elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
                kind = Schema if opcode == _OP_SCHEMA else Channel
                out.append(_inner_record(kind, data[body:stop], path, offset, pos))
            pos = stop
    except struct.error:
        raise _damaged(path, offset, f"a record header at {pos} is cut off") from None
    return out
