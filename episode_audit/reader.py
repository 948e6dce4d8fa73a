r"""Read evidence files: the only module that touches ``mcap``'s readers.

:func:`open_evidence` returns an :class:`Evidence`: the run metadata, an episodes table and a
steps table as ``pyarrow.Table``\\ s (with column and episode selection), block-by-block
streaming, and episode-by-episode iteration.

A finished file is read through its summary (chunk index). A file whose writer was killed has no
summary: it is scanned linearly, every complete chunk is kept, and :attr:`Evidence.finished` is
``False`` with :attr:`Evidence.torn` saying what was dropped. Nothing here loads a whole file into
memory: chunks are read one at a time, and a single episode is read from the chunks its time range
covers.

Every error raised on purpose is an :class:`~episode_audit.errors.EvidenceError` naming the file.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import pyarrow as pa
import pyarrow.compute as pc
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from . import format as fmt
from .columns import TERMS_TYPE
from .errors import (
    CorruptEvidenceError,
    EvidenceError,
    NotEvidenceError,
    UnsupportedVersionError,
)
from .records import RunInfo
from .spaces import SpaceCodec, codec_for, space_from_description

__all__ = ["EPISODE_COLUMNS", "Evidence", "EpisodeEvidence", "open_evidence"]

MAX_RECORD_BYTES = 1 << 30
"""Largest MCAP record (and decompressed chunk) the reader accepts: 1 GiB."""
MAX_JSON_BYTES = 1 << 20
"""Largest JSON episode record or metadata value the reader accepts: 1 MiB."""

_MAGIC = b"\x89MCAP0\r\n"

EPISODE_SCHEMA = pa.schema(
    [
        pa.field("episode", pa.int64(), nullable=False),
        pa.field("env_index", pa.int64()),
        pa.field("agent", pa.string()),
        pa.field("seed", pa.int64()),
        pa.field("rng_state", pa.string()),
        pa.field("options", pa.string()),
        pa.field("outcome", pa.string(), nullable=False),
        pa.field("failure_label", pa.string()),
        pa.field("truncation_reason", pa.string()),
        pa.field("terminated", pa.bool_()),
        pa.field("truncated", pa.bool_()),
        pa.field("length", pa.int64(), nullable=False),
        pa.field("return", pa.float64()),
        pa.field("term_totals", TERMS_TYPE),
        pa.field("start_time_ns", pa.int64()),
        pa.field("end_time_ns", pa.int64()),
        pa.field("error_type", pa.string()),
        pa.field("error_message", pa.string()),
        pa.field("error_during", pa.string()),
        pa.field("notes", pa.int64()),
        pa.field("ended", pa.bool_(), nullable=False),
    ]
)
EPISODE_COLUMNS: tuple[str, ...] = tuple(EPISODE_SCHEMA.names)
"""Columns of :meth:`Evidence.episodes`; ``ended`` is False for episodes a torn file cut off."""


@dataclass(frozen=True)
class _ChunkRef:
    offset: int
    start_time: int
    end_time: int
    compressed_size: int
    uncompressed_size: int


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
    """

    path: Path
    run: RunInfo
    finished: bool
    run_end: dict[str, str] | None
    torn: str | None
    _chunks: list[_ChunkRef] = field(repr=False)
    _channels: dict[int, Channel] = field(repr=False)
    _episodes_cache: pa.Table | None = field(default=None, repr=False)

    # --------------------------------------------------------------- raw access

    def _open(self) -> IO[bytes]:
        try:
            return open(self.path, "rb")
        except OSError as exc:
            raise EvidenceError(self.path, f"cannot open: {exc.strerror}") from None

    def _read_chunk(self, f: IO[bytes], ref: _ChunkRef) -> list[Any]:
        f.seek(ref.offset + 1 + 8)
        try:
            chunk = Chunk.read(ReadDataStream(f))
            return _chunk_records(chunk, self.path, ref.offset)
        except EvidenceError:
            raise
        except Exception as exc:
            raise CorruptEvidenceError(
                self.path, f"chunk at byte {ref.offset} is unreadable ({type(exc).__name__})"
            ) from None

    def _messages(
        self, topics: Iterable[str], *, start_time: int | None = None
    ) -> Iterator[tuple[str, Message]]:
        wanted = set(topics)
        with self._open() as f:
            for ref in self._chunks:
                if start_time is not None and ref.end_time < start_time:
                    continue
                for record in self._read_chunk(f, ref):
                    if isinstance(record, Channel):
                        self._channels.setdefault(record.id, record)
                    elif isinstance(record, Message):
                        channel = self._channels.get(record.channel_id)
                        if channel is None:
                            raise CorruptEvidenceError(
                                self.path,
                                f"message on unknown channel {record.channel_id} "
                                f"in chunk at byte {ref.offset}",
                            )
                        if channel.topic in wanted:
                            yield channel.topic, record

    def _batches(
        self, topic: str, *, start_time: int | None = None
    ) -> Iterator[tuple[int, pa.RecordBatch]]:
        for _, message in self._messages([topic], start_time=start_time):
            yield message.log_time, _arrow_batch(message.data, self.path, topic)

    # --------------------------------------------------------------- steps

    def iter_step_batches(self, columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
        """Yield the steps block by block (one record batch per written block)."""
        for _, batch in self._batches(fmt.TOPIC_STEPS):
            yield batch if columns is None else batch.select(list(columns))

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
            return pa.Table.from_batches(parts)
        schema = self._topic_schema(topic)
        if columns is not None:
            schema = pa.schema([schema.field(c) for c in columns])
        return schema.empty_table()

    @property
    def steps_schema(self) -> pa.Schema:
        """The Arrow schema of the steps table (from the file, even when it has no steps)."""
        return self._topic_schema(fmt.TOPIC_STEPS)

    def _topic_schema(self, topic: str) -> pa.Schema:
        for channel in self._channels.values():
            if channel.topic == topic and channel.schema_id in self._schemas:
                return self._schemas[channel.schema_id]
        return pa.schema([])

    @property
    def _schemas(self) -> dict[int, pa.Schema]:
        return getattr(self, "_schema_cache", {})

    def resets(self) -> pa.Table:
        """One row per reset: episode, seed, rng_state (JSON), options (JSON), observation."""
        parts = [batch for _, batch in self._batches(fmt.TOPIC_RESETS)]
        return self._table(parts, fmt.TOPIC_RESETS, None)

    # --------------------------------------------------------------- episodes

    def episodes(self) -> pa.Table:
        """One row per episode (see :data:`EPISODE_COLUMNS`), including cut-off ones."""
        if self._episodes_cache is None:
            self._episodes_cache = self._build_episodes()
        return self._episodes_cache

    def _build_episodes(self) -> pa.Table:
        ended: dict[int, dict[str, Any]] = {}
        starts: dict[int, dict[str, Any]] = {}
        lengths: dict[int, int] = {}
        returns: dict[int, float] = {}
        last_time: dict[int, int] = {}
        topics = [fmt.TOPIC_EPISODE_END, fmt.TOPIC_RESETS, fmt.TOPIC_STEPS]
        for topic, message in self._messages(topics):
            if topic == fmt.TOPIC_EPISODE_END:
                record = _episode_record(message.data, self.path)
                ended[int(record["episode"])] = record
            elif topic == fmt.TOPIC_RESETS:
                batch = _arrow_batch(message.data, self.path, topic)
                cols = batch.select(
                    ["episode", "env_index", fmt.COL_TIME, "seed", "rng_state", "options"]
                )
                for row in cols.to_pylist():
                    starts[int(row["episode"])] = row
            else:
                batch = _arrow_batch(message.data, self.path, topic)
                episode = batch.column(fmt.COL_EPISODE)
                grouped = (
                    pa.table(
                        {
                            "e": episode,
                            "r": batch.column(fmt.COL_REWARD),
                            "t": batch.column(fmt.COL_TIME),
                        }
                    )
                    .group_by("e")
                    .aggregate([("r", "count"), ("r", "sum"), ("t", "max")])
                )
                for e, n, s, t in zip(  # noqa: B905 - equal-length columns of one table
                    grouped.column("e").to_pylist(),
                    grouped.column("r_count").to_pylist(),
                    grouped.column("r_sum").to_pylist(),
                    grouped.column("t_max").to_pylist(),
                ):
                    lengths[e] = lengths.get(e, 0) + n
                    returns[e] = returns.get(e, 0.0) + (s or 0.0)
                    last_time[e] = t
        rows: list[dict[str, Any]] = []
        for index in sorted(set(ended) | set(starts) | set(lengths)):
            start = starts.get(index, {})
            if index in ended:
                rec = ended[index]
                error = rec.get("error") or {}
                rows.append(
                    {
                        "episode": index,
                        "env_index": rec.get("env_index", 0),
                        "agent": rec.get("agent"),
                        "seed": rec.get("seed"),
                        "rng_state": _json_or_none(rec.get("rng_state")),
                        "options": _json_or_none(rec.get("options")),
                        "outcome": rec["outcome"],
                        "failure_label": rec.get("failure_label"),
                        "truncation_reason": rec.get("truncation_reason"),
                        "terminated": bool(rec.get("terminated", False)),
                        "truncated": bool(rec.get("truncated", False)),
                        "length": int(rec["length"]),
                        "return": _number(rec.get("return")),
                        "term_totals": [
                            (str(k), _number(v)) for k, v in (rec.get("term_totals") or {}).items()
                        ],
                        "start_time_ns": rec.get("start_time_ns"),
                        "end_time_ns": rec.get("end_time_ns"),
                        "error_type": error.get("type"),
                        "error_message": error.get("message"),
                        "error_during": error.get("during"),
                        "notes": rec.get("notes", 0),
                        "ended": True,
                    }
                )
            else:
                rows.append(
                    {
                        "episode": index,
                        "env_index": start.get("env_index", 0),
                        "agent": None,
                        "seed": start.get("seed"),
                        "rng_state": start.get("rng_state"),
                        "options": start.get("options"),
                        "outcome": fmt.OUTCOME_INCOMPLETE,
                        "length": lengths.get(index, 0),
                        "return": returns.get(index, 0.0),
                        "term_totals": None,
                        "start_time_ns": start.get(fmt.COL_TIME),
                        "end_time_ns": last_time.get(index, start.get(fmt.COL_TIME)),
                        "terminated": False,
                        "truncated": False,
                        "notes": None,
                        "ended": False,
                    }
                )
        try:
            return pa.Table.from_pylist(rows, schema=EPISODE_SCHEMA)
        except (pa.ArrowException, TypeError, ValueError) as exc:
            raise CorruptEvidenceError(
                self.path, f"episode records have wrong types: {exc}"
            ) from None

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
        for log_time, batch in self._batches(fmt.TOPIC_STEPS, start_time=start):
            rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
            if rows.num_rows:
                parts.append(rows)
            if end is not None and log_time >= end:
                break
        reset = None
        for log_time, batch in self._batches(fmt.TOPIC_RESETS, start_time=start):
            rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
            if rows.num_rows:
                reset = rows.to_pylist()[0]
                break
            if start is not None and log_time > start:
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
            try:
                space = space_from_description(getattr(self.run, name))
                cache[name] = codec_for(space, digest_min_bytes=digest)
            except Exception:
                cache[name] = None
        return cache[name]

    def __enter__(self) -> Evidence:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


# ------------------------------------------------------------------- decoding helpers


def _number(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, str):
        return float(value)  # "nan", "inf", "-inf"
    return float(value)


def _json_or_none(value: Any) -> str | None:
    return None if value is None else json.dumps(value, separators=(",", ":"))


def _episode_record(data: bytes, path: Path) -> dict[str, Any]:
    if len(data) > MAX_JSON_BYTES:
        raise CorruptEvidenceError(
            path, f"episode record of {len(data)} bytes exceeds the 1 MiB limit"
        )
    try:
        record = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CorruptEvidenceError(path, f"episode record is not valid JSON: {exc}") from None
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


def _arrow_batch(data: bytes, path: Path, topic: str) -> pa.RecordBatch:
    try:
        reader = pa.ipc.open_stream(data)
        batch = reader.read_next_batch()
        batch.validate(full=True)
    except (pa.ArrowException, StopIteration, ValueError, OSError) as exc:
        raise CorruptEvidenceError(
            path, f"a block on {topic} is not a valid Arrow stream: {exc}"
        ) from None
    return batch


def _chunk_records(chunk: Chunk, path: Path, offset: int) -> list[Any]:
    if chunk.uncompressed_size > MAX_RECORD_BYTES:
        raise CorruptEvidenceError(
            path,
            f"chunk at byte {offset} declares {chunk.uncompressed_size} uncompressed bytes "
            f"(limit {MAX_RECORD_BYTES})",
        )
    if chunk.compression not in ("", "zstd", "lz4"):
        raise CorruptEvidenceError(
            path, f"chunk at byte {offset} uses unknown compression {chunk.compression!r}"
        )
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except Exception as exc:
        raise CorruptEvidenceError(
            path, f"chunk at byte {offset} is damaged ({type(exc).__name__}: {str(exc)[:120]})"
        ) from None


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
    try:
        f = open(p, "rb")  # noqa: SIM115
    except OSError as exc:
        raise EvidenceError(p, f"cannot open: {exc.strerror}") from None
    with f:
        head = f.read(len(_MAGIC))
        if len(head) == 0:
            raise NotEvidenceError(p, "the file is empty")
        if head != _MAGIC:
            raise NotEvidenceError(p, "not an MCAP file (wrong magic bytes)")
        f.seek(0)
        indexed = _open_indexed(f, p)
        if indexed is None:
            f.seek(0)
            return _open_linear(f, p)
        return indexed


def _parse_run(
    path: Path, metadata: dict[str, dict[str, str]], header: Header | None
) -> tuple[RunInfo, dict[str, str] | None]:
    if header is not None and header.profile != fmt.MCAP_PROFILE:
        raise NotEvidenceError(
            path,
            f"an MCAP file, but not evidence (profile {header.profile!r}, "
            f"expected {fmt.MCAP_PROFILE!r})",
        )
    raw = metadata.get(fmt.METADATA_RUN)
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
        raise CorruptEvidenceError(path, str(exc)) from None
    return run, metadata.get(fmt.METADATA_RUN_END)


def _schemas_of(schemas: Iterable[Schema]) -> dict[int, pa.Schema]:
    out: dict[int, pa.Schema] = {}
    for schema in schemas:
        if schema.encoding == fmt.ARROW_ENCODING:
            try:
                out[schema.id] = pa.ipc.read_schema(pa.py_buffer(schema.data))
            except pa.ArrowException:
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
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except Exception:
        return None
    run, run_end = _parse_run(path, metadata, header)
    chunks = sorted(
        (
            _ChunkRef(
                c.chunk_start_offset,
                c.message_start_time,
                c.message_end_time,
                c.compressed_size,
                c.uncompressed_size,
            )
            for c in summary.chunk_indexes
        ),
        key=lambda c: c.offset,
    )
    ev = Evidence(path, run, run_end is not None, run_end, None, chunks, dict(summary.channels))
    ev._schema_cache = _schemas_of(summary.schemas.values())  # type: ignore[attr-defined]
    return ev


def _open_linear(f: IO[bytes], path: Path) -> Evidence:
    """Scan a file without a usable summary; keep every complete chunk."""
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
        ) as exc:
            torn = (
                f"torn at byte {start} of {size}: the last {size - start} bytes "
                f"({type(exc).__name__}) were dropped"
            )
            break
        except Exception as exc:
            torn = f"torn at byte {start} of {size}: {type(exc).__name__}; the rest was dropped"
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
                for inner in _chunk_records(record, path, start):
                    if isinstance(inner, Channel):
                        channels[inner.id] = inner
                    elif isinstance(inner, Schema):
                        schemas.append(inner)
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Schema):
            schemas.append(record)
        elif isinstance(record, Footer):
            footer = True
    if header is None:
        raise NotEvidenceError(path, "no MCAP header: the file is torn before any evidence")
    run, run_end = _parse_run(path, metadata, header)
    if torn is None and not footer:
        torn = f"ends at byte {size} without a summary: the writer did not finish"
    finished = footer and run_end is not None and torn is None
    ev = Evidence(path, run, finished, run_end, None if finished else torn, chunks, channels)
    ev._schema_cache = _schemas_of(schemas)  # type: ignore[attr-defined]
    return ev
