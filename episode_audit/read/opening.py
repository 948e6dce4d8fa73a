"""Opening evidence files: through their summary when it is sound, else by a linear scan.

:func:`open_evidence` checks the file's end (:func:`_summary_damage`: the summary against the
footer's CRC, the footer, the closing magic), then opens it through the summary (chunk index,
channels, schemas, metadata: :func:`_open_indexed`) or, for a torn or damaged file, by scanning
its data section and keeping every complete chunk (:func:`_open_linear`). Both check the run
metadata (:func:`_parse_run`) and return an :class:`~episode_audit.read.evidence.Evidence`.
"""

from __future__ import annotations

import errno
import io
import os
import stat
import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Final, NamedTuple

import pyarrow as pa
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Metadata, Schema
from mcap.stream_reader import StreamReader

from ..errors import CorruptEvidenceError, EvidenceError, NotEvidenceError, UnsupportedVersionError
from ..format import names as fmt
from ..format.paths import path_argument
from ..format.records import RunInfo
from ..format.run_end import RunEnd
from . import chunks
from .blocks import _one_line
from .chunks import _NOTHING, _ChunkRef, _crc32_of, _decompress, _raw_chunk, _split
from .episodes import MAX_JSON_BYTES
from .evidence import Evidence
from .layout import (
    _FOOTER,
    _MAGIC,
    _OP_FOOTER,
    _OP_FOOTER_BODY,
    _OP_METADATA,
    _RECORD_HEAD,
    _top_level,
    _Unreadable,
)
from .liveness import Holder, probe, still_written
from .resync import next_intact
from .storage import RemoteFile, Source, as_source, file_size, first_bytes, open_source


def open_evidence(
    path: str | os.PathLike[str],
    *,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> Evidence:
    """Open an evidence file (finished, or torn by a crash) for reading.

    ``path`` may be a URL (``s3://``, ``gs://``, ``az://``, ``http(s)://``), read by byte
    ranges through ``fsspec``: ``filesystem`` (an ``fsspec`` filesystem) reads it, or one made
    with ``storage_options`` (``docs/storage.md``).

    Raises :class:`~episode_audit.errors.ConfigurationError` for a ``path`` that is not one
    (:func:`~episode_audit.format.paths.path_argument`: ``bytes``, ``None``, ``""`` …),
    :class:`~episode_audit.errors.NotEvidenceError` for a file that is not evidence,
    :class:`~episode_audit.errors.UnsupportedVersionError` for a newer major format version, and
    :class:`~episode_audit.errors.CorruptEvidenceError` for damage a crash cannot explain.

    >>> open_evidence("no/such/file.mcap")
    Traceback (most recent call last):
    ...
    episode_audit.errors.EvidenceError: no/such/file.mcap: cannot open: No such file or directory
    """
    path = path_argument("path", path)
    return _open(as_source(path, filesystem=filesystem, storage_options=storage_options))


def open_own_output(path: Path) -> Evidence:
    """Open the unfinished file this process is writing itself (a recovery's output).

    As :func:`open_evidence`, but the file's lock is this process's own writer, never told as
    a live recorder's: the file reads as the torn file it would be if the writer stopped now.
    """
    return _open(as_source(path), live=False)


def _open(p: Source, *, live: bool = True) -> Evidence:
    """:func:`open_evidence` of ``p``; ``live``: a file without a summary may be a recorder's."""
    with _open_mcap(p) as f:
        damage = _summary_damage(f)
        f.seek(0)
        indexed = None if damage else _open_indexed(f, p)
        if indexed is None:
            # a file without a summary: torn, or still being written
            writer = _writer(f, p) if live else None
            f.seek(0)
            ev = _open_linear(f, p, past_data_end=damage is None, writer=writer)
            ev.summary_damage = damage
            return ev
        return indexed


def declared_steps(path: Source) -> tuple[int | None, int]:
    """The steps a file's run-end record declares (``None``: it has none) and the file's size.

    Read through the summary as :func:`open_evidence` reads a finished file (locally, or two
    ranged GETs), never by a scan: a torn file, which has no summary, costs the look at its
    end only. Raises as :func:`open_evidence` does for a file that is not evidence.
    """
    with _open_mcap(path) as f:
        size = file_size(f)
        damage = _summary_damage(f)
        f.seek(0)
        ev = None if damage else _open_indexed(f, path)
    return (None if ev is None else RunEnd.of(ev.run_end).steps), size


def _writer(f: IO[bytes], p: Source) -> Holder | None:
    """The live recorder writing a local file (a remote file has none: recording is local)."""
    return None if isinstance(p, RemoteFile) else probe(f.fileno())


def broken_link(p: str | os.PathLike[str], exc: OSError) -> str | None:
    """Why the symbolic link ``p`` cannot be opened (``exc``: what trying raised), else ``None``.

    ``broken symbolic link (to TARGET, which does not exist)`` or ``symbolic link loop``:
    the system's words (``No such file or directory``, ``Too many levels of symbolic links``)
    do not say that the name is a link.
    """
    if not os.path.islink(p):
        return None
    if exc.errno == errno.ELOOP:
        return "symbolic link loop"
    if exc.errno == errno.ENOENT:
        return f"broken symbolic link (to {os.readlink(p)}, which does not exist)"
    return None


def _open_mcap(p: Source) -> IO[bytes]:
    """Open ``p`` for reading, just after the MCAP magic bytes.

    Raises :class:`~episode_audit.errors.NotEvidenceError` for what is not a regular file
    (a FIFO would block) or does not start like MCAP, and
    :class:`~episode_audit.errors.EvidenceError` for a file that cannot be opened.
    """
    if isinstance(p, RemoteFile):
        f = open_source(p)
    else:
        try:
            mode = os.stat(p).st_mode
            if stat.S_ISDIR(mode):
                raise NotEvidenceError(
                    p,
                    "a directory, not an evidence file; its *.mcap files are "
                    "episode_audit.read.evidence_files([directory]) (as the command line "
                    "finds them)",
                )
            if not stat.S_ISREG(mode):
                raise NotEvidenceError(p, "not a regular file")
        except OSError as exc:
            why = broken_link(p, exc) or exc.strerror
            raise EvidenceError(p, f"cannot open: {why}") from None
        f = open_source(p)
    try:
        head = f.read(len(_MAGIC))
        if len(head) == 0:
            writer = _writer(f, p)
            if writer is not None:
                raise EvidenceError(p, f"{still_written(writer)}: it holds nothing yet; {_WAIT}")
            raise NotEvidenceError(p, "the file is empty")
        if head != _MAGIC:
            raise NotEvidenceError(p, _not_mcap(head))
    except BaseException:
        f.close()
        raise
    return f


_OTHER_FILES: Final = {
    b"RRF": "a Rerun recording (what export --to rerun writes)",
    b"PAR1": "a Parquet file (what export --to parquet writes)",
}
"""What a file starting with these bytes is, instead of MCAP: our exports' formats."""


def _not_mcap(head: bytes) -> str:
    """Why a file starting with ``head`` (not the MCAP magic) is not evidence."""
    for magic, what in _OTHER_FILES.items():
        if head.startswith(magic):
            return f"{what}, not evidence: pass the evidence files (*.mcap) instead"
    return "not an MCAP file (wrong magic bytes)"


def _other_mcap(header: Header, metadata: dict[str, dict[str, str]]) -> str:
    """Why an MCAP file without our profile is not evidence: our Foxglove export is named."""
    export = metadata.get(fmt.METADATA_EXPORT)
    if export is None:
        return (
            f"an MCAP file, but not evidence (profile {header.profile!r}, "
            f"expected {fmt.MCAP_PROFILE!r})"
        )
    source = export.get("source")
    of = f" of {source!r}" if source else ""
    return (
        f"episode-audit's Foxglove export{of} (a viewer file), not evidence: pass the evidence "
        "files, or their directory (its viewer exports are left out)"
    )


def viewer_export(path: str | os.PathLike[str]) -> bool:
    """Whether the file ``path`` is a viewer export of episode-audit's, not evidence.

    The Foxglove export (``export --to foxglove``) is MCAP without our profile, and its summary
    lists the :data:`~episode_audit.format.names.METADATA_EXPORT` record. An evidence file's
    header says so at once (its first bytes are read, nothing more). A file that cannot be
    opened or is not that is not one: opening it as evidence says what it is.
    """
    head = _head(path, summary=True)
    if head is None or head[0]:
        return False
    summary = head[1]
    return summary is not None and any(
        index.name == fmt.METADATA_EXPORT for index in summary.metadata_indexes
    )


def evidence_header(path: str | os.PathLike[str]) -> bool:
    """Whether the local file ``path`` starts as evidence: MCAP with episode-audit's profile.

    Only its header is read: a finished, torn or recovered evidence file alike. A file that is
    not a regular file, not MCAP or cannot be read is not.
    """
    head = _head(path, summary=False)
    return head is not None and head[0]


def remote_viewer_exports(files: list[RemoteFile]) -> list[bool]:
    """:func:`viewer_export` of each of ``files`` (one listing's), reading little of each.

    Their first bytes are read together (:func:`~.storage.first_bytes`); only an MCAP file
    whose header names another profile is opened for its summary.
    """
    heads = first_bytes(files, _HEAD_BYTES)
    return [
        head is not None and _other_profile(head) and viewer_export(file)
        for file, head in zip(files, heads, strict=True)
    ]


_HEAD_BYTES = 4096  # (the magic and the header record: a profile and a library name)


def _other_profile(head: bytes) -> bool:
    """Whether ``head`` (a file's first bytes) starts an MCAP file of another profile than ours."""
    try:
        record = next(iter(StreamReader(io.BytesIO(head), record_size_limit=len(head)).records))
    except Exception:  # (not MCAP, or a header longer than ``head``: not looked at further)
        return False
    return isinstance(record, Header) and record.profile != fmt.MCAP_PROFILE


def _head(path: str | os.PathLike[str], *, summary: bool) -> tuple[bool, Any] | None:
    """Whether the MCAP header of the regular file ``path`` names our profile; its summary.

    The summary is read only when asked (``summary``) and the profile is not ours. ``None``:
    not a regular file, not MCAP, or unreadable.
    """
    try:
        if not isinstance(path, RemoteFile) and not stat.S_ISREG(os.stat(path).st_mode):
            return None  # (a FIFO would block)
        with open_source(path) if isinstance(path, RemoteFile) else open(path, "rb") as f:
            reader = SeekingReader(f, record_size_limit=chunks.MAX_RECORD_BYTES)
            ours = reader.get_header().profile == fmt.MCAP_PROFILE
            return ours, (reader.get_summary() if summary and not ours else None)
    except Exception:  # (not MCAP, unreadable, torn)
        return None


def _parse_run(
    path: Source,
    metadata: dict[str, dict[str, str]],
    header: Header | None,
    torn: str | None = None,
) -> tuple[RunInfo, dict[str, str] | None]:
    if header is not None and header.profile != fmt.MCAP_PROFILE:
        raise NotEvidenceError(path, _other_mcap(header, metadata))
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


def _open_indexed(f: IO[bytes], path: Source) -> Evidence | None:
    """Open through the summary; ``None`` when the file has no usable summary (torn)."""
    try:
        reader = SeekingReader(f, record_size_limit=chunks.MAX_RECORD_BYTES)
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
        if index.name == fmt.METADATA_RUN:
            raise _garbled_run(path, index.offset)
        if index.name == fmt.METADATA_RUN_END:
            run_end_damage = f"the {index.name} metadata record at byte {index.offset} is garbled"
    run, run_end = _parse_run(path, metadata, header)
    refs = sorted(
        (
            _ChunkRef(
                c.chunk_start_offset,
                c.message_start_time,
                c.message_end_time,
                c.compressed_size,
                c.uncompressed_size,
                tuple(sorted(c.message_index_offsets.items())),
                c.message_index_length,
                c.chunk_length,
            )
            for c in summary.chunk_indexes
        ),
        key=lambda c: c.offset,
    )
    finished = run_end is not None or run_end_damage is not None
    schemas = _schemas_of(summary.schemas.values())
    ev = Evidence(
        path, run, finished, run_end, None, refs, dict(summary.channels), _schemas=schemas
    )
    ev.run_end_damage = run_end_damage
    return ev


def _garbled_run(path: Source, offset: int) -> CorruptEvidenceError:
    """The error for a file whose run metadata record, at byte ``offset``, is garbled."""
    return CorruptEvidenceError(
        path,
        f"the {fmt.METADATA_RUN} metadata record at byte {offset} is garbled: the spaces, env "
        "and settings of the run it held are lost, so the file cannot be read as evidence",
    )


def _metadata_at(f: IO[bytes], offset: int, name: str) -> Metadata | None:
    """The metadata record ``name`` a summary locates at ``offset``; ``None`` if garbled.

    Its body must parse to exactly its declared length, as :func:`iter_records` reads it.
    """
    try:
        f.seek(offset)
        opcode, length = _RECORD_HEAD.unpack(f.read(_RECORD_HEAD.size))
        if opcode != _OP_METADATA or length > chunks.MAX_RECORD_BYTES:
            return None
        body = f.read(length)
        record = _top_level(opcode, body) if len(body) == length else None
    except (struct.error, OSError, _Unreadable):
        return None
    return record if isinstance(record, Metadata) and record.name == name else None


def _summary_damage(f: IO[bytes]) -> str | None:
    """Why the end of a finished file (summary, footer, magic) is damaged, or ``None``.

    ``None`` also for a torn file, which ends with neither a footer nor the magic. The
    footer's CRC covers the summary section through the footer's own offset fields (MCAP
    spec); a writer may leave it 0 (not computed), which is accepted.
    """
    size = file_size(f)
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
    if _crc32_of(f, start, end) != crc:
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
    tail = _tail(f, file_size(f))
    if tail is None or not (tail.footer_ok and tail.magic_ok):
        return None
    return tail.summary_start, tail.summary_crc


def _footer_crc(f: IO[bytes]) -> int:
    """The footer's summary CRC (0 without a footer, or when the writer did not compute it)."""
    found = _footer(f)
    return 0 if found is None else found[1]


# What mcap's StreamReader raises for a record cut short (anything else: a garbled one).
_CUT_SHORT = (McapError, EvidenceError, ValueError, EOFError, zlib.error, OSError, MemoryError)


@dataclass
class _Scan:
    """What a linear scan found: the records it keeps, and whether the file was torn."""

    path: Source
    header: Header | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    chunks: list[_ChunkRef] = field(default_factory=list)
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: list[Schema] = field(default_factory=list)
    footer: bool = False
    torn: str | None = None

    def add(self, record: object, start: int) -> None:
        """Keep what ``record`` (read at byte ``start``) says about the file."""
        if isinstance(record, Header):
            self.header = record
        elif isinstance(record, Metadata):
            self.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Chunk):
            self.chunks.append(
                _ChunkRef(
                    start,
                    record.message_start_time,
                    record.message_end_time,
                    len(record.data),
                    record.uncompressed_size,
                )
            )
            if not self.channels:
                self._discover_channels(record, start)
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        elif isinstance(record, Schema):
            self.schemas.append(record)
        elif isinstance(record, Footer):
            self.footer = True

    def _discover_channels(self, record: Chunk, start: int) -> None:
        """The channels (and schemas) the first chunk defines, for a file that has no others."""
        path = self.path
        raw = _raw_chunk(
            record.compression,
            record.uncompressed_size,
            record.uncompressed_crc,
            record.data,
            path,
            start,
        )
        found: list[Channel] = []
        _split(_decompress(raw, path, start), path, start, None, _NOTHING, found, self.schemas)
        self.channels.update((channel.id, channel) for channel in found)


def _open_linear(
    f: IO[bytes], path: Source, *, past_data_end: bool = True, writer: Holder | None = None
) -> Evidence:
    """Scan a file without a usable summary; keep every complete chunk.

    With ``past_data_end`` false (a file whose footer and closing magic are there, but whose
    summary does not match the footer's CRC) the scan stops at the data section's end record:
    what follows is the summary, which only repeats and indexes the data section.
    ``writer``: the live recorder still writing the file, if any.
    """
    reader = StreamReader(f, emit_chunks=True, record_size_limit=chunks.MAX_RECORD_BYTES)
    scan = _Scan(path)
    good_end = 0
    size = file_size(f)
    records = reader.records
    while True:
        start = good_end
        try:
            record = next(records)
        except StopIteration:
            break
        except _CUT_SHORT:
            _refuse_garbled_run(f, scan, start, size)
            scan.torn = _cut_short(start, size, scan.footer)
            break
        except Exception:
            _refuse_garbled_run(f, scan, start, size)
            scan.torn = (
                f"torn at byte {start} of {size}: the record there is cut short or garbled; "
                "the rest was dropped"
            )
            break
        good_end = f.tell()
        if isinstance(record, Metadata) and _declared_end(f, start, good_end) != good_end:
            # (read from fewer bytes than its length declares: the file ends inside it)
            _refuse_garbled_run(f, scan, start, size)
            scan.torn = _cut_short(start, size, scan.footer)
            break
        if isinstance(record, DataEnd) and not past_data_end:
            scan.footer = True  # (the footer was found already, behind the damaged summary)
            break
        scan.add(record, start)
    return _scanned_evidence(scan, size, writer)


def _declared_end(f: IO[bytes], start: int, at: int) -> int:
    """Where the record at ``start`` ends by its declared length (``f`` is left at ``at``)."""
    f.seek(start)
    head = f.read(_RECORD_HEAD.size)
    f.seek(at)
    if len(head) < _RECORD_HEAD.size:
        return -1
    length: int = _RECORD_HEAD.unpack(head)[1]
    return start + _RECORD_HEAD.size + length


def _refuse_garbled_run(f: IO[bytes], scan: _Scan, start: int, size: int) -> None:
    """Raise when the record at ``start`` that a scan cannot read is a garbled run metadata record.

    It is one when it is a metadata record where the run metadata goes (before any other
    metadata or chunk; or named so) and an intact record follows it: then the file was not torn
    there (a recorder killed as it started leaves nothing after it), its length or fields are
    garbled.
    """
    if fmt.METADATA_RUN in scan.metadata:
        return
    at = f.tell()
    try:
        f.seek(start)
        head = f.read(_RECORD_HEAD.size + 4)
        if len(head) < _RECORD_HEAD.size or head[0] != _OP_METADATA:
            return
        first = not scan.metadata and not scan.chunks
        if not (first or _named(f, head, fmt.METADATA_RUN)):
            return
        if next_intact(f, Path(str(scan.path)), start + 1, size) is None:
            return  # torn there: nothing intact after it
    finally:
        f.seek(at)
    raise _garbled_run(scan.path, start)


def _named(f: IO[bytes], head: bytes, name: str) -> bool:
    """Whether the metadata record whose head (and name length) is ``head`` is named ``name``."""
    if len(head) < _RECORD_HEAD.size + 4:
        return False
    (length,) = struct.unpack_from("<I", head, _RECORD_HEAD.size)
    return length == len(name) and f.read(length) == name.encode()


def _cut_short(start: int, size: int, footer: bool) -> str | None:
    """What a linear scan dropped when the record at ``start`` is cut short (None: nothing)."""
    if start >= size and footer:  # the closing magic bytes were never written
        return f"ends at byte {size} without the closing magic: the writer did not finish"
    if start >= size:  # stopped at a record boundary: nothing to drop
        return None
    return (
        f"torn at byte {start} of {size}: the last {size - start} bytes "
        "(a record cut short) were dropped"
    )


def _scanned_evidence(scan: _Scan, size: int, writer: Holder | None) -> Evidence:
    """The evidence a linear scan found (finished only with a footer and a run-end record).

    An unfinished file that a live recorder (``writer``) still writes is not torn: its
    ``torn`` says it is still being written, and what was read.
    """
    path, torn = scan.path, scan.torn
    live = writer is not None and not (scan.footer and torn is None)
    if live and (scan.header is None or fmt.METADATA_RUN not in scan.metadata):
        assert writer is not None
        raise EvidenceError(path, f"{still_written(writer)}: it holds no evidence yet; {_WAIT}")
    if scan.header is None:
        raise NotEvidenceError(path, "no MCAP header: the file is torn before any evidence")
    if torn is None and not scan.footer:
        torn = f"ends at byte {size} without a summary: the writer did not finish"
    if live and writer is not None:
        torn = f"{still_written(writer)}: what it had flushed by byte {size} was read"
    run, run_end = _parse_run(path, scan.metadata, scan.header, torn)
    finished = scan.footer and run_end is not None and torn is None
    return Evidence(
        path,
        run,
        finished,
        run_end,
        None if finished else torn,
        scan.chunks,
        scan.channels,
        _schemas=_schemas_of(scan.schemas),
        writer=None if finished else writer,
    )


_WAIT = "wait for its recorder to flush or close it"
