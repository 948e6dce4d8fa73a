"""The MCAP record layout the reader parses by hand (https://mcap.dev/spec).

Every record is an opcode (u8), a body length (u64) and the body: :data:`_RECORD_HEAD`. Here are
the magic bytes, the opcodes and the fixed heads of the records the reader looks into (chunk,
message, message index, data end, footer), and :func:`_top_level`, which parses one complete
record written outside a chunk into its ``mcap.records`` type.
"""

from __future__ import annotations

import struct
from io import BytesIO
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Header, Message, Metadata, Schema

_MAGIC = b"\x89MCAP0\r\n"

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_MESSAGE_INDEX = 0x07
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F

_RECORD_HEAD = struct.Struct("<BQ")
# Chunk body: message start time, message end time, uncompressed size, uncompressed CRC, and the
# compression string's length; then the string, the records' length (u64) and the records.
_CHUNK_HEAD = struct.Struct("<QQQII")
_U64 = struct.Struct("<Q")
# Message body: channel id u16, sequence u32, log time u64, publish time u64, then the data.
_MESSAGE_HEAD = struct.Struct("<H4xQ8x")
_FULL_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_INDEX_HEAD = struct.Struct("<HI")  # a message index: channel id, then its entries' length
_DATA_END = struct.Struct("<BQI")  # opcode, length (4), data section CRC
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, offsets start, summary CRC
_OP_FOOTER_BODY = 20  # the footer's length field: three fields of 8, 8 and 4 bytes


class _Exact(BytesIO):
    """A stream whose reads return exactly what was asked for, or raise."""

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        if size is not None and size >= 0 and len(data) != size:
            raise EOFError(f"{size} bytes asked for, {len(data)} left")
        return data


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
