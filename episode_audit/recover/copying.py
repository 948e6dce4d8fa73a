"""The record walk of a recovery: the input's records copied into the new file.

:class:`RecordCopy` copies schemas, channels and messages (times and sequence numbers kept)
chunk by chunk, with old-to-new id maps, counts what it copied, and keeps what the walk met
besides: the file's end, the old run-end record (or its damage) and the damaged stretches.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from mcap.records import Channel, Header, Message, Metadata, Schema

from ..errors import CorruptEvidenceError
from ..format import names as fmt
from ..read import ChunkRecords, DamagedRegion, FileEnd, step_block_rows, summary_definitions
from ..record.writer import EvidenceWriter
from .kept import Damage

__all__ = ["RecordCopy"]


class RecordCopy:
    """Schemas, channels and messages copied so far, with the old-to-new id maps."""

    def __init__(self, src: Path, writer: EvidenceWriter) -> None:
        self.src = src
        self.writer = writer
        self.schemas: dict[int, int] = {0: 0}
        self.channels: dict[int, int] = {}
        self.steps_channels: set[int] = set()
        self.chunks = self.messages = self.steps = self.blocks = 0
        self.last_time = 0
        self.last_chunk = -1  # the offset of the last chunk copied
        self.run_end: dict[str, str] | None = None  # the input's, when it could be read
        self.run_end_damage: str | None = None  # the run-end record is there, but garbled
        self.damaged: list[DamagedRegion] = []

    @property
    def closed(self) -> bool:
        """Whether ``close()`` ran on the input: it has a run-end record, intact or garbled."""
        return self.run_end is not None or self.run_end_damage is not None

    @property
    def damage(self) -> Damage:
        """Where the walk met damage: nowhere, before an intact chunk, or after the last one."""
        if not self.damaged:
            return ""
        return "at the end" if self.damaged[-1].offset > self.last_chunk else "inside"

    def copy(self, items: Iterator[object]) -> FileEnd:
        """Copy the summary's definitions, then the walk's ``items``; return the file's end.

        A finished file repeats its schemas and channels in its summary: with them, chunks
        after a damaged first chunk (which held the definitions) still decode.
        """
        schemas, channels = summary_definitions(self.src)
        for record in [*schemas, *channels]:
            self.record(record)
        end: FileEnd | None = None
        for item in items:
            if isinstance(item, FileEnd):
                end = item
            elif isinstance(item, DamagedRegion):
                if item.metadata == fmt.METADATA_RUN_END:
                    self.run_end_damage = item.why
                else:
                    self.damaged.append(item)
            elif isinstance(item, Metadata):
                if item.name == fmt.METADATA_RUN_END:
                    self.run_end = dict(item.metadata)
                else:
                    self.writer.add_metadata(item.name, item.metadata)
            elif isinstance(item, ChunkRecords):
                self.chunk(item)
            elif not isinstance(item, Header):
                self.record(item)
        assert end is not None  # iter_records always ends with one
        self.writer.flush()
        return end

    def chunk(self, item: ChunkRecords) -> None:
        """Copy one intact chunk's records, as one chunk of the new file."""
        for record in item.records:
            self.record(record)
        self.writer.flush()
        self.chunks += 1
        self.last_chunk = item.offset

    def record(self, record: object) -> None:
        """Copy one record (a schema or channel once, with a new id; every message)."""
        writer = self.writer
        if isinstance(record, Message):
            channel = self.channels.get(record.channel_id)
            if channel is None:
                raise CorruptEvidenceError(
                    self.src, f"a message on unknown channel {record.channel_id}"
                )
            writer.write_message(
                channel, record.data, record.log_time, record.publish_time, record.sequence
            )
            self.messages += 1
            self.last_time = max(self.last_time, record.log_time)
            if channel in self.steps_channels:
                self.steps += step_block_rows(record.data, self.src)
                self.blocks += 1
        elif isinstance(record, Schema) and record.id not in self.schemas:
            self.schemas[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = self.schemas.get(record.schema_id)
            if schema is None:
                raise CorruptEvidenceError(
                    self.src, f"channel {record.topic!r} names unknown schema {record.schema_id}"
                )
            new = writer.register_channel(
                record.topic, record.message_encoding, schema, record.metadata
            )
            self.channels[record.id] = new
            if record.topic == fmt.TOPIC_STEPS:
                self.steps_channels.add(new)
