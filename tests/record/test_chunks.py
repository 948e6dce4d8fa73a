"""Chunks compressed by ``record/chunks.py``: mcap's records, zstd with long-distance matching."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from episode_audit import RecordEvidence, open_evidence
from episode_audit.record import chunks
from episode_audit.record.chunks import ChunkWriter, compress_zstd


def _file(kind: type[Writer], compression: CompressionType = CompressionType.ZSTD) -> bytes:
    """Two chunks of JSON messages on two channels, metadata, the summary: written by ``kind``."""
    out = io.BytesIO()
    w = kind(out, chunk_size=1 << 20, compression=compression)
    w.start(profile="test", library="test")
    schema = w.register_schema(name="s", encoding="jsonschema", data=b"{}")
    a = w.register_channel(topic="/a", message_encoding="json", schema_id=schema)
    b = w.register_channel(topic="/b", message_encoding="json", schema_id=schema)
    for i in range(300):
        data = b'{"episode": %d, "outcome": "success", "return": %d.5}' % (i, i * 7)
        w.add_message(channel_id=a if i % 3 else b, log_time=i, publish_time=i, data=data)
        if i == 150:
            w.flush()  # type: ignore[no-untyped-call]
    w.add_metadata("m", {"k": "v"})
    w.finish()  # type: ignore[no-untyped-call]
    return out.getvalue()


def _chunks(data: bytes) -> list[Chunk]:
    return [
        r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records if isinstance(r, Chunk)
    ]


def test_with_level_3_the_file_is_the_bytes_mcaps_own_writer_writes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(chunks, "compress_zstd", zstandard.compress)
    assert _file(ChunkWriter) == _file(Writer)


@pytest.mark.parametrize("compression", [CompressionType.LZ4, CompressionType.NONE])
def test_other_compressions_are_mcaps_own(compression: CompressionType) -> None:
    assert _file(ChunkWriter, compression) == _file(Writer, compression)


def test_a_writer_whose_state_is_not_mcaps_known_one_closes_chunks_as_mcap_does(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    made: list[ChunkWriter] = []

    class Unknown(ChunkWriter):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self._ours = False  # as when this mcap names its state otherwise
            made.append(self)

    assert _file(Unknown) == _file(Writer)
    assert made


def test_chunks_are_compressed_with_long_distance_matching_and_read_back() -> None:
    data = _file(ChunkWriter)
    found = _chunks(data)
    assert len(found) == 2
    ldm = zstandard.ZstdCompressor(
        compression_params=zstandard.ZstdCompressionParameters(compression_level=3, enable_ldm=True)
    )
    for chunk in found:
        assert chunk.compression == "zstd"
        raw = zstandard.decompress(chunk.data)
        assert len(raw) == chunk.uncompressed_size
        assert chunk.data == ldm.compress(raw)
    ours = [m.data for _, _, m in make_reader(io.BytesIO(data)).iter_messages()]
    theirs = [m.data for _, _, m in make_reader(io.BytesIO(_file(Writer))).iter_messages()]
    assert ours == theirs and len(ours) == 300


def test_chunks_past_the_size_limit_are_compressed_at_plain_level_3(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(chunks, "LDM_MAX_BYTES", 1000)
    for chunk in _chunks(_file(ChunkWriter)):
        raw = zstandard.decompress(chunk.data)
        assert len(raw) > 1000
        assert chunk.data == zstandard.compress(raw) == compress_zstd(raw)


def test_a_recorded_file_is_smaller_than_at_level_3_and_reads_the_same(tmp_path: Path) -> None:
    env = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "run.mcap")
    env.action_space.seed(0)
    env.reset(seed=0)
    for episode in range(1, 200):
        while True:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                break
        env.reset(seed=episode)
    env.close()
    found = _chunks(env.path.read_bytes())
    ours = sum(len(c.data) for c in found)
    level_3 = sum(len(zstandard.compress(zstandard.decompress(c.data))) for c in found)
    assert ours < 0.99 * level_3
    with open_evidence(env.path) as evidence:
        assert len(evidence.episodes()) == 200
