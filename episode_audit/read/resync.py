"""The next intact record after damage, in a file without a summary to say where it is.

A failed write (a full disk) leaves part of a record, and a writer that went on leaves intact
records after it. :func:`next_intact` scans forward for the first offset where a record begins
that parses and checks: a chunk whose records decompress to their declared size and match its
CRC, or a metadata record whose fields fill it exactly. :func:`index_framing_holds` checks a
message index record (what follows each chunk) the same way, so that a partial one is not
taken for a whole one whose length skips over the records after it.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import IO

from ..errors import CorruptEvidenceError
from . import chunks
from .chunks import _ChunkRef, _decompress, _read_chunk_record
from .layout import _OP_CHUNK, _OP_METADATA, _RECORD_HEAD, _top_level, _Unreadable

__all__ = ["Resync", "index_framing_holds", "next_intact"]

# Where a record may begin: a chunk (its compression named in place), or a metadata record
# (under 4 GiB). A lookahead, so that overlapping candidates are all found.
_CANDIDATE = re.compile(
    rb"(?=\x06.{36}(?:\x04\x00\x00\x00zstd|\x03\x00\x00\x00lz4|\x00\x00\x00\x00)"
    rb"|\x0c.{4}\x00\x00\x00\x00)",
    re.DOTALL,
)
_WINDOW = 1 << 22  # bytes scanned at a time
_OVERLAP = 64  # longer than any candidate's pattern: one cut by a window's end is found whole
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4 + 8  # a chunk's fields besides its compression and records
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_INDEX_HEAD = struct.Struct("<HI")  # a message index: channel id, byte length of its entries
_INDEX_ENTRY = 16  # log time, offset


def next_intact(f: IO[bytes], path: Path, start: int, size: int) -> int | None:
    """The offset of the first intact chunk or metadata record at or after ``start``.

    ``size`` is the file's size; ``None`` when no record after ``start`` checks.
    """
    pos = start
    while pos < size:
        f.seek(pos)
        window = f.read(_WINDOW)
        last = pos + len(window) >= size
        limit = len(window) if last else len(window) - _OVERLAP
        for match in _CANDIDATE.finditer(window, 0, len(window)):
            if match.start() >= limit:
                break
            if _intact(f, path, pos + match.start(), size):
                return pos + match.start()
        if last:
            return None
        pos += limit
    return None


class Resync:
    """:func:`next_intact` over one open file of ``size`` bytes.

    It remembers where no intact record is left: damaged records in a row, with nothing intact
    after them, cost one scan.
    """

    def __init__(self, f: IO[bytes], path: Path, size: int) -> None:
        self._f, self._path, self._size = f, path, size
        self._barren = size  # no intact record starts at or after this offset

    def after(self, pos: int) -> int | None:
        """The offset of the first intact record after ``pos``, or None."""
        start = pos + 1
        if start >= self._barren:
            return None
        found = next_intact(self._f, self._path, start, self._size)
        if found is None:
            self._barren = start
        return found


def _intact(f: IO[bytes], path: Path, pos: int, size: int) -> bool:
    """Whether the record at ``pos`` is a whole chunk or metadata record that checks."""
    f.seek(pos)
    head = f.read(_RECORD_HEAD.size)
    if len(head) < _RECORD_HEAD.size:
        return False
    opcode, length = _RECORD_HEAD.unpack(head)
    if length > chunks.MAX_RECORD_BYTES or pos + _RECORD_HEAD.size + length > size:
        return False
    if opcode == _OP_CHUNK:
        return _chunk_holds(f, path, pos, length)
    return opcode == _OP_METADATA and _metadata_holds(f, length)


def _chunk_holds(f: IO[bytes], path: Path, pos: int, length: int) -> bool:
    """Whether the chunk record at ``pos`` fills its length and its records check."""
    fields = f.read(_CHUNK_FIXED - 8)  # up to the compression name's length
    if len(fields) < _CHUNK_FIXED - 8:
        return False
    (name,) = _U32.unpack_from(fields, len(fields) - 4)
    f.seek(name, 1)
    records = f.read(8)
    if len(records) < 8 or _CHUNK_FIXED + name + _U64.unpack(records)[0] != length:
        return False
    try:
        raw = _read_chunk_record(f, _ChunkRef(pos, 0, 0, 0, 0), path)
        if not raw.compression and not raw.uncompressed_crc:
            return False  # nothing to check its records against
        _decompress(raw, path, pos)
    except CorruptEvidenceError:
        return False
    return True


def _metadata_holds(f: IO[bytes], length: int) -> bool:
    """Whether the metadata record whose body starts here is filled exactly by its fields."""
    try:
        (name,) = _U32.unpack(f.read(4))
        if 8 + name > length:
            return False
        f.seek(name, 1)
        (entries,) = _U32.unpack(f.read(4))
    except struct.error:  # the file ends
        return False
    if 8 + name + entries != length:
        return False
    f.seek(-(8 + name), 1)
    try:
        _top_level(_OP_METADATA, f.read(length))
    except _Unreadable:
        return False
    return True


def index_framing_holds(body: bytes) -> bool:
    """Whether a message index record's ``body`` is filled exactly by its entries.

    >>> index_framing_holds(_INDEX_HEAD.pack(1, 16) + bytes(16))
    True
    >>> index_framing_holds(_INDEX_HEAD.pack(1, 32) + bytes(16))
    False
    """
    if len(body) < _INDEX_HEAD.size:
        return False
    _, entries = _INDEX_HEAD.unpack_from(body)
    return bool(_INDEX_HEAD.size + entries == len(body) and entries % _INDEX_ENTRY == 0)
