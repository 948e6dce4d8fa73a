"""Chunks: reading, decompressing and splitting them, with the read-ahead thread.

:func:`_decoded` yields each chunk's decompressed records (a worker thread reads and
decompresses the next few while the caller works on one); :func:`_split` cuts them into the
wanted messages with :mod:`struct`, at the offsets the chunk's message index gives when it has
one. A chunk's declared sizes are checked against :data:`MAX_RECORD_BYTES` before anything is
decompressed, and its records against its CRC. :class:`_ChunkRef` locates a chunk.
"""

from __future__ import annotations

import importlib
import struct
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import IO, Any

import pyarrow as pa
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Schema

from ..errors import CorruptEvidenceError, EvidenceError
from ..format import names as fmt
from .layout import (
    _CHUNK_HEAD,
    _INDEX_HEAD,
    _MESSAGE_HEAD,
    _OP_CHANNEL,
    _OP_CHUNK,
    _OP_MESSAGE,
    _OP_MESSAGE_INDEX,
    _OP_SCHEMA,
    _RECORD_HEAD,
    _U64,
    _Exact,
)
from .storage import Source, file_size, open_source

try:  # zlib-ng's CRC-32 (the same checksum) runs ~4x faster than the system zlib's
    from zlib_ng.zlib_ng import crc32 as _crc32
except ImportError:  # pragma: no cover - a platform without zlib-ng wheels
    from zlib import crc32 as _crc32

MAX_RECORD_BYTES = 1 << 30
"""Largest MCAP record (and decompressed chunk) the reader accepts: 1 GiB.

The other modules of the wing read it as ``chunks.MAX_RECORD_BYTES``: one assignment here
changes the cap everywhere (the fuzz harness lowers it)."""
READ_AHEAD = 4
"""Most chunks read and decompressed ahead of the one being worked on."""
READ_AHEAD_BYTES = 256 << 20
"""Most decompressed bytes read ahead (one chunk is always allowed, however large)."""

_ARROW_ZSTD = pa.Codec.is_available("zstd")
"""Whether this pyarrow decompresses zstd (PyPI's wheels do); else ``zstandard`` does."""
_THREADED_MIN_CHUNKS = 3

# What a message is to the reader, by its channel's topic.
_STEPS, _RESETS, _ENDS, _OTHER = 0, 1, 2, -1
_SLOTS = {fmt.TOPIC_STEPS: _STEPS, fmt.TOPIC_RESETS: _RESETS, fmt.TOPIC_EPISODE_END: _ENDS}
# Files with Arrow episode blocks: read those, skip the JSON copies of the same records.
_ARROW_SLOTS = {fmt.TOPIC_STEPS: _STEPS, fmt.TOPIC_RESETS: _RESETS, fmt.TOPIC_EPISODES: _ENDS}
_NOTHING = (False, False, False)

RECOVER_HINT = "; `episode-audit recover` copies the intact chunks to a new file"
"""How a damaged chunk's message ends (recovery takes it off when it names the damage)."""
"""The end of a damaged chunk's message (recovery takes it off when it reports the damage)."""


@dataclass(frozen=True)
class _ChunkRef:
    """Where a chunk record is in its file, the log times it spans and its sizes."""

    offset: int
    start_time: int
    end_time: int
    compressed_size: int
    uncompressed_size: int
    # finished files: file offsets of the chunk's MessageIndex records, by channel id
    index_offsets: tuple[tuple[int, int], ...] = ()
    index_length: int = 0
    # finished files: the chunk record's length (opcode and length prefix included), as the
    # summary's chunk index gives it; the record is then read in one request (object storage)
    record_length: int = 0


@dataclass(frozen=True)
class _RawChunk:
    """A chunk record's fields, checked, with its still compressed records."""

    compression: str
    uncompressed_size: int
    uncompressed_crc: int
    data: bytes | memoryview


def _damaged(path: Source, offset: int, why: str) -> CorruptEvidenceError:
    return CorruptEvidenceError(path, f"chunk at byte {offset} is damaged ({why}){RECOVER_HINT}")


def _decoded(
    path: Source, refs: Sequence[_ChunkRef], *, ahead: bool, want: frozenset[int] | None = None
) -> Iterator[tuple[_ChunkRef, tuple[memoryview, list[int] | None]]]:
    """Yield each chunk's decompressed records and its wanted messages' offsets.

    With ``ahead``, a worker thread reads and decompresses ahead.
    """
    f = open_source(path, edges=False)
    with f:
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


def _read_chunk_record(f: IO[bytes], ref: _ChunkRef, path: Source) -> _RawChunk:
    """Read and check the chunk record at ``ref.offset`` (its records still compressed)."""
    offset = ref.offset
    try:
        f.seek(offset)
        file_end = file_size(f)
        known = ref.record_length
        most = min(file_end - offset, _RECORD_HEAD.size + MAX_RECORD_BYTES)
        guess = known if _RECORD_HEAD.size < known <= most else 0  # (the summary may lie)
        first = f.read(guess or _RECORD_HEAD.size)
        head = first[: _RECORD_HEAD.size]
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
        if offset + _RECORD_HEAD.size + length > file_end:
            raise _damaged(path, offset, f"its {length}-byte record runs past the end of the file")
        if len(first) == _RECORD_HEAD.size + length:  # the index's length was right: read
            body: bytes | memoryview = memoryview(first)[_RECORD_HEAD.size :]
        else:
            f.seek(offset + _RECORD_HEAD.size)
            body = f.read(length)
    except OSError as exc:
        raise EvidenceError(path, f"cannot read chunk at byte {offset}: {exc}") from None
    if len(body) < length:
        raise _damaged(path, offset, "the file ends inside it")
    try:
        _, _, size, crc, name_length = _CHUNK_HEAD.unpack_from(body, 0)
        pos = _CHUNK_HEAD.size + name_length
        compression = bytes(body[_CHUNK_HEAD.size : pos]).decode("utf-8")
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
    compression: str, size: int, crc: int, data: bytes | memoryview, path: Source, offset: int
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


def _decompress(raw: _RawChunk, path: Source, offset: int) -> memoryview:
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
    f: IO[bytes], ref: _ChunkRef, path: Source, want: frozenset[int] | None = None
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


def _crc32_of(f: IO[bytes], start: int, end: int) -> int:
    """The CRC-32 of the file's bytes ``start`` to ``end`` (to its end, if that comes first)."""
    f.seek(start)
    crc, left = 0, end - start
    while left:
        block = f.read(min(left, 1 << 20))
        if not block:
            break
        crc = _crc32(block, crc)
        left -= len(block)
    return crc


def _lz4_frame(path: Source) -> Any:
    try:
        return importlib.import_module("lz4.frame")
    except ImportError:
        raise EvidenceError(
            path, "the file is lz4-compressed: reading it needs the lz4 package"
        ) from None


def _split(
    data: bytes | memoryview,
    path: Source,
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


def _inner_record(kind: Any, body: bytes | memoryview, path: Source, offset: int, pos: int) -> Any:
    """Read a Channel or Schema record from its body (trailing bytes are allowed, per MCAP)."""
    try:
        return kind.read(ReadDataStream(_Exact(body)))
    except Exception as exc:
        raise _damaged(
            path,
            offset,
            f"the {kind.__name__} record at {pos} is unreadable ({type(exc).__name__})",
        ) from None
