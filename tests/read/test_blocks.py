"""One Arrow block, decoded and checked."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest

from episode_audit import (
    CorruptEvidenceError,
    open_evidence,
)
from episode_audit.format import names as fmt
from episode_audit.read import blocks


def test_a_known_schema_message_still_has_its_batch_checked(recorded: Path) -> None:
    """The block after a good one shares its schema message bytes; its batch is still walked."""
    batch = open_evidence(recorded).steps().to_batches()[0]

    def stream(**options: Any) -> bytes:
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, batch.schema, options=pa.ipc.IpcWriteOptions(**options)) as w:
            w.write_batch(batch)
        return bytes(sink.getvalue())

    good, compressed = stream(), stream(compression="zstd")
    known = blocks._first_message_end(good)
    assert known is not None and good[:known] == compressed[:known]  # the same schema message
    where = Path("x.mcap")
    assert blocks._arrow_batch(good, where, fmt.TOPIC_STEPS).equals(batch)
    assert blocks._GOOD_SCHEMA_MESSAGES[fmt.TOPIC_STEPS] == good[:known]
    with pytest.raises(CorruptEvidenceError, match="uses Arrow IPC body compression"):
        blocks._arrow_batch(compressed, where, fmt.TOPIC_STEPS)
    # a stream cut inside its schema message is not taken for the known one
    with pytest.raises(CorruptEvidenceError, match="not a valid Arrow stream"):
        blocks._arrow_batch(good[: known - 1], where, fmt.TOPIC_STEPS)
