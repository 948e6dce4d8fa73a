"""One Arrow block (step, reset or episode block): decoded in place and checked.

:func:`_arrow_batch` decodes a block after walking its IPC framing by hand (:func:`_ipc_problem`
refuses compressed bodies and dictionary batches before pyarrow allocates anything), validates
it fully, and checks its columns against the block schemas' one definition
(:mod:`episode_audit.format.schemas`). :func:`_reset_block`, :func:`_episode_part` and
:func:`step_block_rows` decode one block of their topic.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Iterable, Sequence

import pyarrow as pa
from mcap.records import Channel

from ..errors import CorruptEvidenceError
from ..format import names as fmt
from ..format.schemas import (
    EPISODE_BLOCK_BASE,
    EPISODE_BLOCK_COLUMNS,
    not_null_columns,
    required_columns,
)
from .storage import Source

# Blocks are read in place from the decompressed chunk, at any offset: buffers that are not
# aligned for their type are copied (compute kernels and numpy want them aligned).
_IPC_OPTIONS = pa.ipc.IpcReadOptions(ensure_alignment=pa.ipc.Alignment.DataTypeSpecific)
# Columns a block must have, with their types (None: any type; the space decides), and those
# that must have no nulls (declared not nullable): from the block schemas' one definition.
_REQUIRED: dict[str, dict[str, pa.DataType | None]] = {
    topic: required_columns(topic) for topic in (fmt.TOPIC_STEPS, fmt.TOPIC_RESETS)
}
_NOT_NULL: dict[str, tuple[str, ...]] = {
    topic: not_null_columns(topic) for topic in (fmt.TOPIC_STEPS, fmt.TOPIC_RESETS)
}
_NO_SCHEMA = pa.schema([])
_CHECKED: dict[str, pa.Schema] = {}
"""The last block schema found good, per topic (blocks of one file share their schema)."""
_GOOD_SCHEMA_MESSAGES: dict[str, bytes] = {}
"""Per topic, the bytes of the last IPC schema message of a block found good."""


def _arrow_batch(data: bytes | memoryview, path: Source, topic: str) -> pa.RecordBatch:
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
    for name in _NOT_NULL.get(topic, ()):
        nulls = batch.column(name).null_count  # (kept in the block's framing: no data read)
        if nulls:
            raise CorruptEvidenceError(path, _nulls_problem(f"a block on {topic}", nulls, name))
    return batch


def _nulls_problem(where: str, nulls: int, name: str) -> str:
    """What is wrong with a block that has ``nulls`` nulls in the never-null column ``name``."""
    return (
        f"{where} has {nulls} null(s) in its {name!r} column, which the format declares never null"
    )


def step_block_rows(data: bytes | memoryview, path: Source) -> int:
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


def _reset_block(data: bytes, path: Source) -> pa.RecordBatch:
    """One reset block, decoded and checked."""
    return _arrow_batch(data, path, fmt.TOPIC_RESETS)


def _episode_part(data: bytes, path: Source) -> pa.RecordBatch:
    """One episode block, decoded and checked: the columns of ``EPISODE_BLOCK_COLUMNS`` it has.

    Blocks hold at least the columns of format 1.0's first files (``EPISODE_BLOCK_BASE``); of
    the optional ``game`` and ``options_typed``, those it has (in that order); other columns
    are ignored.
    """
    batch = _arrow_batch(data, path, fmt.TOPIC_EPISODES)
    schema = batch.schema
    _check_episode_block(schema, path)
    names = schema.names
    target = _PART_SCHEMAS[tuple(name in names for name in _OPTIONAL_EPISODE_COLUMNS)]
    # Types were compared, never cast: a cast (or a null column made to fill in) before the
    # checks would allocate for the row count a block declares, which a hostile block can
    # make huge. Columns a later 1.x may add are left out (select() copies nothing).
    part = batch.select(target.names)
    if not part.schema.equals(target):  # names and types agree; nullability may not
        part = pa.RecordBatch.from_arrays(part.columns, schema=target)
    return part


_OPTIONAL_EPISODE_COLUMNS = tuple(
    name for name in EPISODE_BLOCK_COLUMNS.names if name not in EPISODE_BLOCK_BASE.names
)
_PART_SCHEMAS = {
    has: pa.schema(
        [
            f
            for f in EPISODE_BLOCK_COLUMNS
            if f.name not in _OPTIONAL_EPISODE_COLUMNS
            or has[_OPTIONAL_EPISODE_COLUMNS.index(f.name)]
        ]
    )
    for has in itertools.product((False, True), repeat=len(_OPTIONAL_EPISODE_COLUMNS))
}
"""An episode block's part, by which of the optional columns (``game``, ...) the block has."""


def _check_episode_block(schema: pa.Schema, path: Source) -> None:
    """An episode block starts with the base columns and has the episode columns' types."""
    names = schema.names
    if names[: len(EPISODE_BLOCK_BASE)] != EPISODE_BLOCK_BASE.names:
        raise CorruptEvidenceError(path, "an episode block does not have the episode columns")
    for name in EPISODE_BLOCK_COLUMNS.names:
        if name not in names:
            continue
        actual, expected = schema.field(name).type, EPISODE_BLOCK_COLUMNS.field(name).type
        if not actual.equals(expected):
            raise CorruptEvidenceError(
                path, f"an episode block has wrong types: {name!r} is {actual}, expected {expected}"
            )


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


def _declared_schema(
    channels: dict[int, Channel], schemas: dict[int, pa.Schema], topic: str
) -> pa.Schema | None:
    """The schema the file's Schema record declares for ``topic``, if any (unchecked)."""
    for channel in channels.values():
        if channel.topic == topic and channel.schema_id in schemas:
            return schemas[channel.schema_id]
    return None


def _topic_schema(path: Source, declared: pa.Schema | None, topic: str) -> pa.Schema:
    """The topic's schema as its Schema record declares it (checked like its blocks).

    A file without the topic's channel or schema (torn before any block) gets the
    required columns, the space columns null-typed.
    """
    if declared is None:
        return _minimal_schema(topic)
    problem = _columns_problem(declared, _REQUIRED[topic])
    if problem is not None:
        raise CorruptEvidenceError(
            path, f"the schema of {topic} does not have the expected columns: {problem}"
        )
    return declared


def _blocks_table(parts: list[pa.RecordBatch], topic: str, path: Source) -> pa.Table:
    """Blocks of ``topic`` as one table (they must share one schema)."""
    try:
        return pa.Table.from_batches(parts)
    except pa.ArrowInvalid as exc:
        raise CorruptEvidenceError(
            path, f"blocks on {topic} do not share one schema: {str(exc)[:200]}"
        ) from None


def _empty_table(schema: pa.Schema, columns: Sequence[str] | None) -> pa.Table:
    """An empty table with ``schema`` (its ``columns`` only, when given)."""
    if columns is not None:
        if not schema.names:  # torn before its first block: the file never named a type
            schema = pa.schema([pa.field(c, pa.null()) for c in columns])
        schema = pa.schema([schema.field(c) for c in columns])
    return schema.empty_table()


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
