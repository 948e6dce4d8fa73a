"""Hostile evidence files: what someone who hand-edits a file can put in it.

The recorder never writes such content (env ids are validated by Gymnasium, notes are capped),
so these files are made by copying a real recording through ``mcap``'s own reader and writer
and changing what an attacker would change.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
from mcap.reader import make_reader
from mcap.writer import Writer

from episode_audit.format import names as fmt

HOSTILE = "[red]x[/red][link=http://e.invalid]y[/link]\x1b[31mz\x07|a\nb`c`<b>"
"""Rich markup, a Rich link, an ANSI escape, a bell, a Markdown pipe, a newline, a code span and
HTML, in one string."""

PIECES = ["[red]x[/red]", "[link=http://e.invalid]y[/link]", "\\x1b[31mz", "\\x07"]
"""How the parts of :data:`HOSTILE` must appear in table output: literally, control characters
as visible escapes."""

RunEdit = Callable[[dict[str, str]], dict[str, str]]
BatchEdit = Callable[[pa.RecordBatch], pa.RecordBatch]


def _arrow(batch: pa.RecordBatch) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema) as ipc:
        ipc.write_batch(batch)
    return bytes(sink.getvalue().to_pybytes())


def rewrite(
    src: Path,
    dst: Path,
    *,
    run: RunEdit | None = None,
    steps: BatchEdit | None = None,
    resets: BatchEdit | None = None,
    episodes: BatchEdit | None = None,
) -> Path:
    """Copy an evidence file, editing its run metadata and / or its Arrow blocks."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = [(c, m) for _, c, m in reader.iter_messages(log_time_order=False)]
    edits = {fmt.TOPIC_STEPS: steps, fmt.TOPIC_RESETS: resets, fmt.TOPIC_EPISODES: episodes}
    with open(dst, "wb") as out:
        writer = Writer(out)
        writer.start(profile=header.profile, library=header.library)
        schema_ids = {}
        for sid in sorted(summary.schemas):
            s = summary.schemas[sid]
            data = s.data
            channel = next(c for c in summary.channels.values() if c.schema_id == sid)
            edit = edits.get(channel.topic)
            if edit is not None:
                first = next(m for c, m in messages if c.topic == channel.topic)
                batch = pa.ipc.open_stream(first.data).read_next_batch()
                data = edit(batch).schema.serialize().to_pybytes()
            schema_ids[sid] = writer.register_schema(s.name, s.encoding, data)
        channel_ids = {}
        for cid in sorted(summary.channels):
            c = summary.channels[cid]
            channel_ids[cid] = writer.register_channel(
                c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata
            )
        meta = metadata[fmt.METADATA_RUN]
        writer.add_metadata(fmt.METADATA_RUN, run(meta) if run is not None else meta)
        for channel, message in messages:
            data = message.data
            edit = edits.get(channel.topic)
            if edit is not None:
                data = _arrow(edit(pa.ipc.open_stream(data).read_next_batch()))
            writer.add_message(
                channel_ids[channel.id],
                message.log_time,
                data,
                message.publish_time,
                message.sequence,
            )
        if fmt.METADATA_RUN_END in metadata:
            writer.add_metadata(fmt.METADATA_RUN_END, metadata[fmt.METADATA_RUN_END])
        writer.finish()
    return dst


def replace_column(batch: pa.RecordBatch, name: str, values: list[object]) -> pa.RecordBatch:
    """``batch`` with column ``name`` replaced by ``values`` (same type)."""
    i = batch.schema.get_field_index(name)
    column = pa.array(values, batch.schema.field(name).type)
    return batch.set_column(i, batch.schema.field(name), column)
