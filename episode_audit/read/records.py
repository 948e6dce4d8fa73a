"""The record walk recovery uses: a file's data section, record by record, in file order.

:func:`iter_records` yields the Header, Metadata and other records written outside chunks, each
complete chunk's records (:class:`ChunkRecords`), the bytes it skipped (:class:`DamagedRegion`,
with ``skip_damaged``), and last where the readable part ends (:class:`FileEnd`).
:func:`summary_definitions` gives the Schema and Channel records a finished file's summary
repeats.
"""

from __future__ import annotations

import bisect
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Message, Metadata, Schema

from ..errors import CorruptEvidenceError
from . import chunks
from .chunks import (
    RECOVER_HINT,
    _ChunkRef,
    _damaged,
    _decompress,
    _inner_record,
    _read_chunk_record,
)
from .layout import (
    _DATA_END,
    _FULL_MESSAGE_HEAD,
    _MAGIC,
    _OP_CHANNEL,
    _OP_CHUNK,
    _OP_DATA_END,
    _OP_FOOTER,
    _OP_MESSAGE,
    _OP_MESSAGE_INDEX,
    _OP_METADATA,
    _OP_SCHEMA,
    _RECORD_HEAD,
    _TOP_LEVEL,
    _message,
    _top_level,
    _Unreadable,
)
from .opening import _footer, _open_mcap, _summary_damage
from .resync import Resync, index_framing_holds
from .storage import Source


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
    bytes after the last of those end the walk. Without one (a torn file), it goes on at the
    next record that checks (:class:`~.resync.Resync`), if any.
    """
    p = Path(path)
    with _open_mcap(p) as f:
        size = os.fstat(f.fileno()).st_size
        known, names = _record_starts(f) if skip_damaged else ([], {})
        # without a summary to say where records start, the walk looks for them after damage
        resync = Resync(f, p, size) if skip_damaged and not known else None
        f.seek(len(_MAGIC))
        pos = len(_MAGIC)
        summary = False  # past the data-end record: the summary section, skipped

        while True:
            head = f.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                yield FileEnd(pos, size, head[0] if head else None, False)
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            stop = pos + _RECORD_HEAD.size + length
            at = bisect.bisect_right(known, pos)  # the next record the summary locates, if any
            nxt = known[at] if at < len(known) else None
            name = names.get(pos)  # the metadata record the summary locates here, if any
            what = "a record" if name is None else f"the {name} metadata record"
            bad = _bad_framing(what, pos, opcode, length, size, None if summary else nxt, name)
            index = resync is not None and opcode == _OP_MESSAGE_INDEX  # (it may be partial)
            if bad is None and index and not index_framing_holds(f.read(length)):
                bad = f"a message index at byte {pos} is garbled"
            if bad is not None:
                skipped = _skipped(pos, _resume_at(pos, nxt, resync), bad, name, size, opcode)
                yield skipped
                if isinstance(skipped, FileEnd):
                    return
                pos += skipped.length
                f.seek(pos)
                continue
            if opcode == _OP_CHUNK and not summary:
                item = _chunk_item(f, p, pos, stop, skip_damaged)
                if resync is not None and isinstance(item, DamagedRegion):
                    # a partial chunk declares bytes of the records written after it
                    stop = resync.after(pos) or stop
                    item = DamagedRegion(pos, stop - pos, item.why)
                yield item
            elif not index:
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
                        bad = f"{what} at byte {pos} is garbled"
                        nxt = _resume_at(pos, nxt, resync)
                        skipped = _skipped(pos, nxt, bad, name, size, opcode)
                        yield skipped
                        if isinstance(skipped, FileEnd):
                            return
                        stop = pos + skipped.length
            pos = stop
            f.seek(pos)


def _skipped(
    pos: int, resume: int | None, why: str, name: str | None, size: int, opcode: int
) -> DamagedRegion | FileEnd:
    """Damage at ``pos``: the region skipped up to ``resume``, or where the walk ends (None)."""
    if resume is None:
        return FileEnd(pos, size, opcode, False)
    return DamagedRegion(pos, resume - pos, why, name)


def _resume_at(pos: int, nxt: int | None, resync: Resync | None) -> int | None:
    """Where a walk goes on after damage at ``pos`` (None: the damage ends it).

    At the next record the summary locates (``nxt``), else, with ``resync``, at the next one
    that checks: a failed write leaves a partial record, and a writer that went on, whole ones
    after it.
    """
    if nxt is None and resync is not None:
        return resync.after(pos)
    return nxt


def _bad_framing(
    what: str, pos: int, opcode: int, length: int, size: int, nxt: int | None, name: str | None
) -> str | None:
    """What is wrong with the framing of the record at ``pos``, or None.

    ``nxt`` is the next record the summary locates (None: none, or in the summary section);
    ``name`` the metadata record it locates at ``pos``, if any.
    """
    stop = pos + _RECORD_HEAD.size + length
    if length > chunks.MAX_RECORD_BYTES or stop > size:
        return f"{what} at byte {pos} declares {length} bytes, past the end of the file"
    if nxt is not None and stop > nxt:
        return f"{what} at byte {pos} overruns the record the summary locates at {nxt}"
    if name is not None and opcode != _OP_METADATA:
        return f"{what} at byte {pos} is garbled (opcode {opcode:#04x})"
    return None


def _chunk_item(
    f: IO[bytes], path: Source, pos: int, stop: int, skip_damaged: bool
) -> ChunkRecords | DamagedRegion:
    """The records of the chunk at ``pos`` (``stop`` is where it ends), or the damage."""
    try:
        raw = _read_chunk_record(f, _ChunkRef(pos, 0, 0, 0, 0), path)
        return ChunkRecords(pos, _chunk_records(_decompress(raw, path, pos).tobytes(), path, pos))
    except CorruptEvidenceError as exc:
        if not skip_damaged:
            raise
        return DamagedRegion(pos, stop - pos, exc.problem.removesuffix(RECOVER_HINT))


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
        return SeekingReader(f, record_size_limit=chunks.MAX_RECORD_BYTES).get_summary()
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


def _chunk_records(data: bytes, path: Source, offset: int) -> list[Schema | Channel | Message]:
    """Every Schema, Channel and Message record of a decompressed chunk, in order.

    The walk is :func:`~episode_audit.read.chunks._split`'s, which keeps its own inline: it is
    the reader's chunk loop, where a call per record would cost.
    """
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
