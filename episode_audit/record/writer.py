"""The evidence writer: with ``chunks.py``, the only module that touches ``mcap.writer``.

:class:`EvidenceWriter` lays out one evidence file: run metadata as MCAP metadata records,
columnar step blocks as Arrow IPC stream messages, per-episode records as JSON messages, and a
run-end metadata record written by :meth:`EvidenceWriter.finish`. Every :meth:`flush` closes the
current MCAP chunk and hands it to the OS whole (``sink.StagedFile``), so a process killed
afterwards leaves every flushed block readable. A flush the OS refuses (a full disk) leaves the
file as it was and is retried by the next one; past :data:`RETRY_LIMIT_BYTES` it is dropped,
the MCAP writer's own state going back to the last good flush, and counted (:attr:`lost`).

Closing a chunk (zstd, its CRC, its indexes) and writing it run in a writer thread, so that a
recorder's flush costs its training loop little: zstd, the CRC and the write release the GIL
and run beside the loop (MuJoCo's physics releases it too). The writer thread is started per
flush and ends with it; every other call waits for it first.
"""

from __future__ import annotations

import copy
import errno
import json
import os
import struct
import threading
from collections import Counter
from collections.abc import Callable, Mapping
from typing import IO, Any, cast

import pyarrow as pa
from mcap.data_stream import RecordBuilder
from mcap.records import MessageIndex
from mcap.writer import CompressionType, Writer

from ..errors import ConfigurationError, RecorderError
from ..format import names as fmt
from . import native
from .chunks import ChunkWriter
from .lock import LockedStream, claim_output
from .sink import StagedFile

__all__ = ["RETRY_LIMIT_BYTES", "EvidenceWriter"]

# Chunks are closed by our own flushes, not by size: one chunk holds one flushed block
# plus the JSON records written since the previous flush.
_CHUNK_SIZE = 64 * 1024 * 1024

RETRY_LIMIT_BYTES = 64 << 20
"""Most bytes of refused flushes a writer keeps in memory to retry; beyond, it drops them."""


class _McapState:
    """What ``mcap.Writer`` keeps about the file written so far: saved at each good flush.

    Going back to it after dropping what the OS refused keeps the summary's indexes and
    statistics true to the file. ``None`` from :meth:`of` when this ``mcap`` keeps its state
    elsewhere (the writer then stops writing after a drop rather than write a false summary).
    """

    _LISTS = ("chunk_indices", "metadata_indexes", "attachment_indexes", "summary_offsets")
    _OTHERS = ("statistics", "chunk_builder", "record_builder", "schemas", "channels")

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._lengths: list[int] = []
        self._statistics: Any = None
        self.save()

    @classmethod
    def of(cls, writer: Writer) -> _McapState | None:
        names = (*cls._LISTS, *cls._OTHERS)
        return cls(writer) if all(hasattr(writer, f"_Writer__{n}") for n in names) else None

    def _get(self, name: str) -> Any:
        return getattr(self._writer, f"_Writer__{name}")

    def save(self) -> None:
        """Remember the state now (after a good flush: no chunk in progress)."""
        self._lengths = [len(self._get(name)) for name in self._LISTS]
        self._statistics = _copy_statistics(self._get("statistics"))

    def restore(self) -> None:
        """Go back to the state saved last, dropping the chunk in progress.

        The chunk dropped may have held the file's first Schema and Channel records (``mcap``
        writes them into the chunk open when they are registered): all of them go into the
        next chunk again, so that what follows stays readable without a summary.
        """
        for name, length in zip(self._LISTS, self._lengths, strict=True):
            del self._get(name)[length:]
        self._writer._Writer__statistics = _copy_statistics(self._statistics)  # type: ignore[attr-defined]
        builder = self._get("chunk_builder")
        if builder is not None:
            builder.reset()
            for schema in self._get("schemas").values():
                builder.add_schema(schema)
            for channel in self._get("channels").values():
                builder.add_channel(channel)
        self._get("record_builder").end()


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, times
_MESSAGE_OPCODE = 0x05
_MESSAGE_FIXED = _MESSAGE_HEAD.size - 9  # a message record's length beside its data
_TIMES = ("message_start_time", "message_end_time")


def _message_head(channel_id: int, size: int, sequence: int, log_time: int) -> bytes:
    """The bytes of an MCAP Message record before its ``size`` bytes of data (at ``log_time``)."""
    return _MESSAGE_HEAD.pack(
        _MESSAGE_OPCODE,
        _MESSAGE_FIXED + size,
        channel_id,
        sequence & 0xFFFFFFFF,
        log_time,
        log_time,
    )


class _OpenChunk:
    """Many messages of one channel written at once into ``mcap.Writer``'s open chunk.

    ``Writer.add_message`` costs ~55 k instructions a message in Python (a record object, a
    struct per field, statistics and index updates): most of what recording an episode's JSON
    record costs. This writes the same records, index entries and statistics for a whole list
    in one go (the bytes are the same: tests/record/test_writer.py compares them). ``None``
    from :meth:`of` when this ``mcap`` keeps its state otherwise: messages then go one by one
    through ``add_message``. The records are framed by the extension when it is built
    (:func:`.native.frame_messages`), else here.
    """

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._frame = native.frame_messages if native.compiled() else None

    @classmethod
    def of(cls, writer: Writer) -> _OpenChunk | None:
        builder = getattr(writer, "_Writer__chunk_builder", None)
        needed = (
            (writer, ("_Writer__chunk_size", "_Writer__statistics")),
            (builder, ("message_indices", "num_messages", *_TIMES)),
            (getattr(builder, "record_writer", None), ("_buffer",)),
            (
                getattr(writer, "_Writer__statistics", None),
                ("message_count", "channel_message_counts", *_TIMES),
            ),
        )
        ok = builder is not None and all(hasattr(o, n) for o, names in needed for n in names)
        return cls(writer) if ok else None

    def fits(self, size: int) -> bool:
        """Whether ``size`` more bytes stay within the chunk (else ``add_message`` closes it)."""
        builder = self._writer._Writer__chunk_builder  # type: ignore[attr-defined]
        return bool(builder.count + size <= self._writer._Writer__chunk_size)  # type: ignore[attr-defined]

    def add(self, channel_id: int, datas: list[bytes], times: list[int], sequence: int) -> None:
        """Append the messages as ``add_message`` would, one after another.

        ``sequence`` numbers the first; each time is the message's log and publish time.
        """
        buffer = self._writer._Writer__chunk_builder.record_writer._buffer  # type: ignore[attr-defined]
        if self._frame is not None:
            framed, entries = self._frame(datas, times, channel_id, sequence, buffer.tell())
        else:
            framed, entries = _framed(datas, times, channel_id, sequence, buffer.tell())
        buffer.write(framed)
        self._count(channel_id, entries, min(times), max(times))

    def add_parts(
        self, channel_id: int, parts: _Parts, size: int, log_time: int, sequence: int
    ) -> None:
        """Append one message whose data is ``parts`` (``size`` bytes in all), as ``add``."""
        buffer = self._writer._Writer__chunk_builder.record_writer._buffer  # type: ignore[attr-defined]
        entry = (log_time, buffer.tell())
        buffer.write(_message_head(channel_id, size, sequence, log_time))
        for part in parts:
            buffer.write(part)
        self._count(channel_id, [entry], log_time, log_time)

    def add_stream(
        self, channel_id: int, batch: pa.RecordBatch, size: int, log_time: int, sequence: int
    ) -> bool:
        """Append one message whose data is ``batch`` as an Arrow IPC stream of ``size`` bytes.

        The stream is written straight into the chunk's memory, not serialized apart and then
        copied in: for big blocks (camera frames) that copy, into memory new to the process,
        cost more than the rest of the flush. Whether it was written: not when the chunk's
        memory is ``mcap``'s own, or when the stream's size is not ``size`` (then nothing is).
        """
        buffer = self._writer._Writer__chunk_builder.record_writer._buffer  # type: ignore[attr-defined]
        if type(buffer) is not _ChunkBuffer:
            return False
        start = buffer.tell()
        buffer.write(_message_head(channel_id, size, sequence, log_time))
        sink = pa.FixedSizeBufferWriter(pa.py_buffer(buffer.reserve(size)))
        try:
            with pa.ipc.new_stream(sink, batch.schema) as ipc:
                ipc.write_batch(batch)
            written = sink.tell()
        except BaseException as exc:  # (a Ctrl-C too: the chunk never holds half a message)
            buffer.cut(start)
            if not isinstance(exc, Exception):
                raise
            return False
        if written != size:
            buffer.cut(start)
            return False
        self._count(channel_id, [(log_time, start)], log_time, log_time)
        return True

    def _count(
        self, channel_id: int, entries: list[tuple[int, int]], first: int, last: int
    ) -> None:
        """Index and count messages just written (``entries``: their times and offsets)."""
        builder = self._writer._Writer__chunk_builder  # type: ignore[attr-defined]
        stats = self._writer._Writer__statistics  # type: ignore[attr-defined]
        _widen(builder, builder.num_messages, first, last)
        index = builder.message_indices.get(channel_id)
        if not index:
            index = builder.message_indices[channel_id] = MessageIndex(
                channel_id=channel_id, records=[]
            )
        index.records.extend(entries)
        builder.num_messages += len(entries)
        _widen(stats, stats.message_count, first, last)
        stats.channel_message_counts[channel_id] += len(entries)
        stats.message_count += len(entries)


class _ChunkBuffer:
    """The open chunk's bytes, in memory kept from one chunk to the next.

    ``mcap``'s ``RecordBuilder`` writes each chunk into a fresh ``io.BytesIO``, whose memory
    the OS gives back when it is freed: every page of the next chunk is new to the process,
    and on a virtual machine each first write to a page traps (~3 us a 4 KiB page here, ten
    times the copy itself; a 400 KB block cost ~340 us to add, ~30 us here). Only the
    calls its ``RecordBuilder`` and :class:`_OpenChunk` make are served. Memory past
    :data:`_KEEP_BYTES` is given back after a chunk that needed it.
    """

    __slots__ = ("_data", "_pos", "_size")

    def __init__(self) -> None:
        self._data = bytearray(_FIRST_BYTES)
        self._pos = 0
        self._size = 0

    def write(self, data: bytes | memoryview) -> int:
        """Write ``data`` at the position (as ``BytesIO.write``); its size."""
        n = memoryview(data).nbytes
        start, end = self._pos, self._pos + n
        if end > len(self._data):
            self._grow(end)
        self._data[start:end] = data  # (the same length: a copy into the kept memory)
        self._pos = end
        self._size = max(self._size, end)
        return n

    def reserve(self, n: int) -> memoryview:
        """The next ``n`` bytes from the position, to be written in place (it moves past them)."""
        start, end = self._pos, self._pos + n
        if end > len(self._data):
            self._grow(end)
        self._pos = end
        self._size = max(self._size, end)
        return memoryview(self._data)[start:end]

    def cut(self, pos: int) -> None:
        """Drop everything from ``pos`` on (written at the end: what failed to be written)."""
        self._pos = self._size = pos

    def _grow(self, end: int) -> None:
        grown = bytearray(max(end, 2 * len(self._data)))
        grown[: self._size] = memoryview(self._data)[: self._size]
        self._data = grown

    def tell(self) -> int:
        """The position."""
        return self._pos

    def seek(self, pos: int) -> int:
        """Move to ``pos`` (from the start)."""
        self._pos = pos
        return pos

    def take(self) -> memoryview:
        """The chunk's bytes (valid until the next write), and start the next chunk."""
        data = memoryview(self._data)[: self._size]
        if self._size > _KEEP_BYTES:
            self._data = bytearray(_FIRST_BYTES)
        self._pos = self._size = 0
        return data


_FIRST_BYTES = 1 << 16
_KEEP_BYTES = 48 << 20
"""The largest chunk whose memory a writer keeps for the next one (up to twice as much, as the
buffer grew). The recorder aims for chunks of at most 32 MiB of rows (``file.CHUNK_TARGET_BYTES``),
plus its other messages: big rows (camera frames) fill every chunk up to about that, and
memory new to the process costs ~3 us a 4 KiB page on first write here, a chunk of them ~25 ms."""

_DIRECT_BYTES = 128 << 10
"""Blocks of at least this many bytes are written straight into the chunk
(:meth:`_OpenChunk.add_stream`); smaller ones are serialized apart (:func:`ipc_parts`), which
costs less for them (a block of 60 KB: 10 us a write against 12; of 180 KB: 17 against 13; of
600 KB: 45 against 28)."""


class _KeptRecords(RecordBuilder):
    """``mcap``'s chunk ``RecordBuilder`` on a :class:`_ChunkBuffer`.

    Its ``end`` gives a view of the chunk's bytes, which ``Writer`` compresses (or copies) and
    writes before it returns; every later write to the chunk comes after that (each call of
    :class:`EvidenceWriter` waits for its writer thread first).
    """

    def __init__(self) -> None:  # (not RecordBuilder's: no BytesIO)
        self._buffer = _ChunkBuffer()  # type: ignore[assignment]

    def end(self) -> memoryview:
        """The chunk's bytes; the next chunk starts empty."""
        return self._buffer.take()  # type: ignore[attr-defined,no-any-return]

    @classmethod
    def install(cls, writer: Writer) -> None:
        """Put one in ``writer``'s chunk builder, when it has the builder this is made for."""
        builder = getattr(writer, "_Writer__chunk_builder", None)
        records = getattr(builder, "record_writer", None)
        if type(records) is RecordBuilder and records.count == 0:
            builder.record_writer = cls()  # type: ignore[union-attr]


def _framed(
    datas: list[bytes], times: list[int], channel_id: int, sequence: int, offset: int
) -> tuple[bytes, list[tuple[int, int]]]:
    """:func:`.native.frame_messages` in Python: the records, and their index entries."""
    head, fixed, opcode = _MESSAGE_HEAD.pack, _MESSAGE_FIXED, _MESSAGE_OPCODE
    parts: list[bytes] = []
    entries: list[tuple[int, int]] = []
    for data, t in zip(datas, times, strict=True):
        entries.append((t, offset))
        parts.append(head(opcode, fixed + len(data), channel_id, sequence & 0xFFFFFFFF, t, t))
        parts.append(data)
        offset += fixed + 9 + len(data)
        sequence += 1
    return b"".join(parts), entries


_Parts = tuple[Any, ...]
"""The pieces of one message's data, each a bytes-like object, in order."""

_IPC_END = b"\xff\xff\xff\xff\x00\x00\x00\x00"  # an Arrow IPC stream's end-of-stream marker


def ipc_parts(batch: pa.RecordBatch, schema_message: pa.Buffer | None = None) -> _Parts:
    """``batch`` as a self-contained Arrow IPC stream (schema, batch, end), in pieces.

    The pieces are the bytes ``pa.ipc.new_stream`` writes (``tests/record/test_writer.py``
    compares them), made without a stream: the batch is measured and written once, into one
    buffer of its size. ``schema_message``: ``batch.schema.serialize()``, when the caller keeps
    it. A schema with dictionaries takes ``new_stream`` (its stream holds dictionary batches).

    >>> batch = pa.record_batch([pa.array([1, 2])], names=["x"])
    >>> data = b"".join(ipc_parts(batch))
    >>> pa.ipc.open_stream(data).read_all().column("x").to_pylist()
    [1, 2]
    """
    if schema_message is None:
        if _has_dictionary(batch.schema):
            out = pa.BufferOutputStream()
            with pa.ipc.new_stream(out, batch.schema) as ipc:
                ipc.write_batch(batch)
            return (out.getvalue(),)
        schema_message = batch.schema.serialize()
    return schema_message, batch.serialize(), _IPC_END


def ipc_stream(batch: pa.RecordBatch) -> bytes:
    """``batch`` as a self-contained Arrow IPC stream (:func:`ipc_parts`), in one piece."""
    return b"".join(ipc_parts(batch))


def _has_dictionary(schema: pa.Schema) -> bool:
    """Whether any field of ``schema``, at any depth, is dictionary-encoded."""
    kinds = [field.type for field in schema]
    while kinds:
        kind = kinds.pop()
        if pa.types.is_dictionary(kind):
            return True
        kinds.extend(kind.field(i).type for i in range(kind.num_fields))
    return False


def _widen(times: Any, count: int, first: int, last: int) -> None:
    """Widen the message times of ``times`` (``count`` messages so far), as ``add_message``.

    ``first`` and ``last`` are the earliest and latest log times of the messages added.
    """
    start = first if count == 0 else min(times.message_start_time, first)
    times.message_start_time = start
    times.message_end_time = max(times.message_end_time, last)


def _copy_statistics(statistics: Any) -> Any:
    saved = copy.copy(statistics)
    saved.channel_message_counts = copy.copy(statistics.channel_message_counts)
    return saved


class _WriterThread:
    """A writer thread's work, one piece at a time; what failed in the background, kept.

    >>> thread = _WriterThread()
    >>> thread.run(lambda failed: failed.append(OSError("full")), background=True)
    []
    >>> thread.wait()
    >>> thread.take_failures()
    [OSError('full')]
    """

    __slots__ = ("_failures", "_flushing")

    def __init__(self) -> None:
        self._flushing: tuple[threading.Thread, list[Exception]] | None = None
        self._failures: list[Exception] = []  # of background work, for take_failures()

    def run(self, work: Callable[[list[Exception]], None], *, background: bool) -> list[Exception]:
        """Run ``work(failed)`` in a new writer thread (here, if no thread can be had).

        Waits for it and returns what it put in ``failed``, unless ``background``: then it
        returns ``[]`` at once, and :meth:`wait` keeps its failures for :meth:`take_failures`.
        Call :meth:`wait` first: one thread at a time.
        """
        failed: list[Exception] = []
        thread = threading.Thread(target=work, args=(failed,), name="episode-audit-writer")
        try:
            thread.start()
        except RuntimeError:  # (no thread to be had: the caller's thread does it)
            work(failed)
            return failed
        self._flushing = thread, failed
        if background:
            return []
        self.wait(keep=False)
        return failed

    def wait(self, *, keep: bool = True) -> None:
        """Wait for the writer thread, if one is under way; ``keep`` its failures for later.

        A Ctrl-C while waiting is raised once the thread has ended (it is short: a chunk's
        compression and write), so nothing here sees the writer half way through a flush.
        """
        flushing = self._flushing
        if flushing is None:
            return
        thread, failed = flushing
        interrupted: BaseException | None = None
        while True:
            try:
                thread.join()
                break
            except BaseException as exc:  # (KeyboardInterrupt)
                interrupted = exc
        self._flushing = None
        if keep:
            self._failures.extend(failed)
            del failed[:]
        if interrupted is not None:
            raise interrupted

    def take_failures(self) -> list[Exception]:
        """What failed in the background work waited for since the last call (each once)."""
        failures, self._failures = self._failures, []
        return failures


class _Staging:
    """What a file holds beyond its last good flush, by channel, and what was given up of it.

    :meth:`commit` hands the staged bytes to the OS and saves the MCAP writer's state. A commit
    the OS refuses keeps them for the next one; past :data:`RETRY_LIMIT_BYTES` it drops them
    (:meth:`drop`): their rows and messages go to ``lost`` / ``lost_messages``, and the
    writer's state back to the last good flush.
    """

    __slots__ = (
        "dead",
        "fsync",
        "lost",
        "lost_messages",
        "messages",
        "path",
        "rows",
        "sink",
        "state",
    )

    def __init__(self, sink: StagedFile, path: str, fsync: bool) -> None:
        self.sink = sink
        self.path = path
        self.fsync = fsync
        self.state: _McapState | None = None
        self.dead = False  # the file's end is unknown after a failure: write nothing more
        self.rows: Counter[int] = Counter()  # rows of Arrow blocks since the last commit
        self.messages: Counter[int] = Counter()
        self.lost: Counter[int] = Counter()
        self.lost_messages: Counter[int] = Counter()

    def commit(self) -> None:
        """Hand the staged bytes to the OS; raises ``OSError`` when it refuses them."""
        sink = self.sink
        try:
            if self.dead:
                raise OSError(
                    errno.EIO,
                    f"{self.path}: the file could not be cut back after a failed write; "
                    "nothing more is written to it",
                )
            sink.commit(self.fsync)
        except OSError:
            if sink.broken:
                self.dead = True
            if self.dead or sink.staged_bytes > RETRY_LIMIT_BYTES:
                self.drop()
            raise
        if self.state is not None:
            self.state.save()
        self.rows.clear()
        self.messages.clear()

    def drop(self) -> None:
        """Drop the staged bytes, counting what they held as lost."""
        self.lost.update(self.rows)
        self.lost_messages.update(self.messages)
        self.rows.clear()
        self.messages.clear()
        self.sink.drop()
        if self.state is None:
            self.dead = True  # (the summary would index what is not there)
        else:
            self.state.restore()


class EvidenceWriter:
    """Write one evidence file.

    The file is created exclusively: an existing file is never overwritten unless
    ``overwrite=True``, so a mistyped path cannot destroy earlier evidence; and it is locked
    before a byte is written, so a file another live recorder writes is refused even then
    (:func:`~episode_audit.record.lock.claim_output`; with ``template``, ``path`` is a
    :class:`~episode_audit.record.lock.PathTemplate`). :attr:`path` is the file's path.

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.mcap"
    >>> w = EvidenceWriter(path, library="doctest")
    >>> w.add_metadata("episode_audit.run", {"format_version": "1.0"})
    >>> w.finish({"status": "finished"})
    >>> path.stat().st_size > 0
    True
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        library: str,
        fsync: bool = False,
        overwrite: bool = False,
        compression: str = "zstd",
        template: bool = False,
    ) -> None:
        modes = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": None}
        if compression not in modes:
            raise ConfigurationError(
                f"compression: expected one of {sorted(modes)}, actually: {compression!r}"
            )
        # the file is created (or, with overwrite, opened) and locked before a byte is written
        output = claim_output(path, overwrite=overwrite, template=template)
        self.path = output.path
        self.indexed = output.indexed  # (an {index} path: its recorder may give it back)
        raw = open(output.fd, "wb", buffering=0)  # noqa: SIM115 - closed by finish() or abandon()
        self._stream = LockedStream(raw, output)
        f = cast(IO[bytes], self._stream)
        kind = modes[compression]
        self._sink = StagedFile(f)
        self._staging = _Staging(self._sink, str(self.path), fsync)
        self._writer = ChunkWriter(
            self._sink,
            chunk_size=_CHUNK_SIZE,
            compression=kind if kind is not None else CompressionType.NONE,
        )
        _KeptRecords.install(self._writer)
        self._writer.start(profile=fmt.MCAP_PROFILE, library=library)
        self._finished = False
        self._deleted = False
        self._messages = 0
        self._staging.state = _McapState.of(self._writer)
        self._chunk = _OpenChunk.of(self._writer)
        # each Arrow channel's schema and its IPC message (a stream's first), made once
        self._arrow_schemas: dict[int, tuple[pa.Schema, pa.Buffer]] = {}
        self.lost: Counter[int] = self._staging.lost
        """Rows of Arrow blocks dropped after the OS refused them, by channel."""
        self.lost_messages: Counter[int] = self._staging.lost_messages
        """Messages dropped after the OS refused them, by channel."""
        self._thread = _WriterThread()
        try:
            self.flush()
        except BaseException:  # (a full disk): the file is closed, its lock released
            self.abandon()
            raise

    @property
    def finished(self) -> bool:
        """Whether :meth:`finish` has run."""
        return self._finished

    def newly_deleted(self) -> bool:
        """Whether the file lost its last name (deleted while written) since the last call.

        True once: what it holds and what follows are lost with it.
        """
        if self._deleted:
            return False
        try:
            self._deleted = os.fstat(self._stream.fileno()).st_nlink == 0
        except (OSError, ValueError):  # (closed: not this question's to answer)
            return False
        return self._deleted

    def _check_open(self) -> None:
        self._thread.wait()
        if self._finished:
            raise RecorderError(
                f"{self.path}: the evidence file is finished; nothing more can be written"
            )

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a metadata record (string keys and values)."""
        self._check_open()
        self._writer.add_metadata(name, dict(data))

    def register_arrow_channel(
        self,
        topic: str,
        schema_name: str,
        schema: pa.Schema,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Register a channel of Arrow IPC stream messages (the MCAP schema is the Arrow schema)."""
        message = schema.serialize()
        schema_id = self.register_schema(schema_name, fmt.ARROW_ENCODING, message.to_pybytes())
        channel_id = self.register_channel(topic, fmt.ARROW_ENCODING, schema_id, metadata)
        if not _has_dictionary(schema):
            self._arrow_schemas[channel_id] = schema, message
        return channel_id

    def register_json_channel(
        self,
        topic: str,
        schema_name: str,
        json_schema: Mapping[str, Any],
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Register a channel of JSON messages described by a JSON Schema."""
        data = json.dumps(json_schema).encode()
        schema_id = self.register_schema(schema_name, fmt.JSONSCHEMA_ENCODING, data)
        return self.register_channel(topic, fmt.JSON_ENCODING, schema_id, metadata)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register an MCAP schema as given (recovery copies them); returns its id."""
        self._check_open()
        return int(self._writer.register_schema(name=name, encoding=encoding, data=data))

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Register an MCAP channel as given (recovery copies them); returns its id."""
        self._check_open()
        return int(
            self._writer.register_channel(
                topic=topic,
                message_encoding=message_encoding,
                schema_id=schema_id,
                metadata=dict(metadata or {}),
            )
        )

    def write_message(
        self, channel_id: int, data: bytes, log_time: int, publish_time: int, sequence: int
    ) -> None:
        """Write one message with its own times and sequence number (recovery copies them)."""
        self._check_open()
        self._writer.add_message(
            channel_id=channel_id,
            log_time=log_time,
            data=data,
            publish_time=publish_time,
            sequence=sequence,
        )
        self._messages += 1

    def write_batch(self, channel_id: int, batch: pa.RecordBatch, log_time: int) -> int:
        """Write one record batch as a self-contained Arrow IPC stream; returns its byte size.

        The stream's pieces are copied straight into the open chunk when it can take them.
        """
        self._check_open()
        known = self._arrow_schemas.get(channel_id)
        schema_message = (
            known[1]
            if known is not None and batch.schema.equals(known[0], check_metadata=True)
            else None
        )
        chunk = self._chunk
        if chunk is not None and schema_message is not None:
            size = int(schema_message.size + pa.ipc.get_record_batch_size(batch)) + len(_IPC_END)
            if (
                size >= _DIRECT_BYTES
                and chunk.fits(size + _MESSAGE_HEAD.size)
                and chunk.add_stream(channel_id, batch, size, log_time, self._messages)
            ):
                self._counted(channel_id, 1)
                self._staging.rows[channel_id] += batch.num_rows
                return size
        parts = ipc_parts(batch, schema_message)
        size = sum(memoryview(part).nbytes for part in parts)
        if chunk is not None and chunk.fits(size + _MESSAGE_HEAD.size):
            chunk.add_parts(channel_id, parts, size, log_time, self._messages)
            self._counted(channel_id, 1)
        else:
            self._add(channel_id, b"".join(parts), log_time)
        self._staging.rows[channel_id] += batch.num_rows
        return size

    def write_json(self, channel_id: int, data: bytes, log_time: int) -> None:
        """Write one JSON message (already encoded, UTF-8)."""
        self._check_open()
        self._add(channel_id, data, log_time)

    def write_json_many(self, channel_id: int, datas: list[bytes], log_times: list[int]) -> None:
        """Write JSON messages (already encoded), one per log time.

        The file is the same as :meth:`write_json` one by one would make, at a fraction of the
        cost.
        """
        self._check_open()
        chunk = self._chunk
        if (
            chunk is None
            or not datas
            or not chunk.fits(sum(map(len, datas)) + _MESSAGE_HEAD.size * len(datas))
        ):
            for data, log_time in zip(datas, log_times, strict=True):
                self._add(channel_id, data, log_time)
            return
        chunk.add(channel_id, datas, log_times, self._messages)
        self._counted(channel_id, len(datas))

    def _add(self, channel_id: int, data: bytes | memoryview, log_time: int) -> None:
        self._writer.add_message(
            channel_id=channel_id,
            log_time=log_time,
            # (typed bytes, but the chunk builder only writes it to a BytesIO: any buffer does)
            data=data,  # type: ignore[arg-type]
            publish_time=log_time,
            sequence=self._messages & 0xFFFFFFFF,
        )
        self._counted(channel_id, 1)

    def _counted(self, channel_id: int, n: int) -> None:
        """``n`` messages were added to ``channel_id``: they number on, staged until a commit."""
        self._messages += n
        self._staging.messages[channel_id] += n

    def flush(self, *, background: bool = False) -> None:
        """Close the current chunk and hand it to the OS whole (and ``fsync`` if asked).

        Raises ``OSError`` when the OS refuses it: the file then ends where it did before, and
        what was refused is written by the next flush (or dropped and counted in :attr:`lost`,
        past :data:`RETRY_LIMIT_BYTES`).

        The chunk is closed and written by a writer thread; this waits for it, unless
        ``background``: then the caller goes on at once, the next call to this writer waits
        for the thread, and what failed in it is kept for :meth:`take_failures`, not raised.
        """
        self._check_open()
        failed = self._thread.run(self._flush_now, background=background)
        if failed:
            raise failed[0]

    def _flush_now(self, failed: list[Exception]) -> None:
        """Close the chunk and commit it; what fails is put in ``failed``."""
        try:
            self._writer.flush()  # type: ignore[no-untyped-call]
            self._staging.commit()
        except Exception as exc:
            failed.append(exc)

    def take_failures(self) -> list[Exception]:
        """What failed in the background flushes waited for since the last call (each once).

        A flush the OS refused is retried by the next, as in :meth:`flush`.
        """
        return self._thread.take_failures()

    def drop(self) -> None:
        """Drop what was refused since the last good flush, counting it in :attr:`lost`."""
        self._thread.wait()
        self._staging.drop()

    def finish(self, run_end: Mapping[str, str]) -> None:
        """Write the run-end record, the summary and the footer, and close the file.

        Raises ``OSError`` when the OS refuses them: the file then ends after the last good
        flush, still open, what was refused dropped (:attr:`lost`); call again with a run-end
        record that says so, or :meth:`abandon`.
        """
        self._thread.wait()
        if self._finished:
            return
        try:
            self._writer.add_metadata(fmt.METADATA_RUN_END, dict(run_end))
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._staging.commit()
        except OSError:
            if self._sink.staged_bytes:
                self._staging.drop()
            raise
        except BaseException:
            self.abandon()
            raise
        self._finished = True
        self._sink.close()

    def close_inherited(self) -> None:
        """In a forked child: close its copy of the file, writing nothing, the lock kept."""
        if not self._finished:
            self._finished = True
            self._sink.drop()
            self._stream.close_copy()

    def abandon(self) -> None:
        """Close the file without a summary (used only when finishing itself failed)."""
        self._thread.wait()
        if not self._finished:
            self._finished = True
            self._sink.drop()
            self._sink.close()
