"""The evidence writer: the only module that touches ``mcap.writer``.

:class:`EvidenceWriter` lays out one evidence file: run metadata as MCAP metadata records,
columnar step blocks as Arrow IPC stream messages, per-episode records as JSON messages, and a
run-end metadata record written by :meth:`EvidenceWriter.finish`. Every :meth:`flush` closes the
current MCAP chunk, so a process killed afterwards leaves every flushed block readable.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import IO, Any, cast

import pyarrow as pa
from mcap.writer import CompressionType, Writer

from ..errors import ConfigurationError, RecorderError
from ..format import names as fmt
from .lock import LockedStream, claim_output

__all__ = ["EvidenceWriter"]

# Chunks are closed by our own flushes, not by size: one chunk holds one flushed block
# plus the JSON records written since the previous flush.
_CHUNK_SIZE = 64 * 1024 * 1024


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
        self._fsync = fsync
        modes = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": None}
        if compression not in modes:
            raise ConfigurationError(
                f"compression: expected one of {sorted(modes)}, actually: {compression!r}"
            )
        # the file is created (or, with overwrite, opened) and locked before a byte is written
        output = claim_output(path, overwrite=overwrite, template=template)
        self.path = output.path
        self.indexed = output.indexed  # (an {index} path: its recorder may give it back)
        file = open(output.fd, "wb")  # noqa: SIM115 - closed by finish() or abandon()
        self._stream: IO[bytes] = cast(IO[bytes], LockedStream(file, output))
        kind = modes[compression]
        self._writer = Writer(
            self._stream,
            chunk_size=_CHUNK_SIZE,
            compression=kind if kind is not None else CompressionType.NONE,
        )
        self._writer.start(profile=fmt.MCAP_PROFILE, library=library)
        self._finished = False
        self._messages = 0
        self.flush()

    @property
    def finished(self) -> bool:
        """Whether :meth:`finish` has run."""
        return self._finished

    def _check_open(self) -> None:
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
        data = schema.serialize().to_pybytes()
        schema_id = self.register_schema(schema_name, fmt.ARROW_ENCODING, data)
        return self.register_channel(topic, fmt.ARROW_ENCODING, schema_id, metadata)

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
        """Write one record batch as a self-contained Arrow IPC stream; returns its byte size."""
        self._check_open()
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, batch.schema) as ipc:
            ipc.write_batch(batch)
        data = memoryview(sink.getvalue())  # (the chunk copies it: no bytes copy before that)
        self._add(channel_id, data, log_time)
        return len(data)

    def write_json(self, channel_id: int, data: bytes, log_time: int) -> None:
        """Write one JSON message (already encoded, UTF-8)."""
        self._check_open()
        self._add(channel_id, data, log_time)

    def _add(self, channel_id: int, data: bytes | memoryview, log_time: int) -> None:
        self._writer.add_message(
            channel_id=channel_id,
            log_time=log_time,
            # (typed bytes, but the chunk builder only writes it to a BytesIO: any buffer does)
            data=data,  # type: ignore[arg-type]
            publish_time=log_time,
            sequence=self._messages & 0xFFFFFFFF,
        )
        self._messages += 1

    def flush(self) -> None:
        """Close the current chunk and hand everything to the OS (and ``fsync`` if asked)."""
        self._check_open()
        self._writer.flush()  # type: ignore[no-untyped-call]
        if self._fsync:
            os.fsync(self._stream.fileno())

    def finish(self, run_end: Mapping[str, str]) -> None:
        """Write the run-end record, the summary and the footer, and close the file."""
        if self._finished:
            return
        try:
            self._writer.add_metadata(fmt.METADATA_RUN_END, dict(run_end))
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._stream.flush()
            if self._fsync:
                os.fsync(self._stream.fileno())
        finally:
            self._finished = True
            self._stream.close()

    def abandon(self) -> None:
        """Close the file without a summary (used only when finishing itself failed)."""
        if not self._finished:
            self._finished = True
            self._stream.close()
