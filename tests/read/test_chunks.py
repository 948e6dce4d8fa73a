"""The chunk reader: splitting as mcap does, decompression, and damage inside a chunk."""

from __future__ import annotations

import random
import struct
import zlib
from pathlib import Path

import pyarrow as pa
import pytest
from mcap.writer import CompressionType

from episode_audit import (
    CorruptEvidenceError,
    EvidenceError,
    open_evidence,
)
from episode_audit.format import names as fmt
from episode_audit.read import chunks
from tests.read.helpers import mcap_messages, patched, rewrite


def _split_file(path: Path) -> list[tuple[str, int, bytes]]:
    """The same, from the fast chunk reader and splitter."""
    ev = open_evidence(path)
    topic_of = {0: fmt.TOPIC_STEPS, 1: fmt.TOPIC_RESETS, 2: fmt.TOPIC_EPISODE_END}
    route = {cid: chunks._SLOTS.get(c.topic, -1) for cid, c in ev._channels.items()}
    out = []
    with open(path, "rb") as f:
        for ref in ev._chunks:
            raw = chunks._read_chunk_record(f, ref, path)
            data = chunks._decompress(raw, path, ref.offset)
            messages = chunks._split(data, path, ref.offset, route, (True,) * 3, [], None)
            out.extend((topic_of[slot], t, view.tobytes()) for slot, t, view, _ in messages)
    return out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_splitter_equals_mcaps_own_reader(recorded: Path, tmp_path: Path, compression: str) -> None:
    path = recorded
    if compression != "zstd":
        kind = CompressionType.LZ4 if compression == "lz4" else CompressionType.NONE
        path = rewrite(recorded, tmp_path / f"{compression}.mcap", compression=kind)
    expected = mcap_messages(path)
    assert len(expected) > 10
    assert _split_file(path) == [m for m in expected if m[0] in chunks._SLOTS]
    # and the public single pass yields the same blocks and records, chunk by chunk
    ev = open_evidence(path)
    contents = list(ev.scan())
    assert len(contents) == len(ev._chunks)
    steps = [b for c in contents for b in c.steps]
    assert pa.Table.from_batches(steps).equals(open_evidence(recorded).steps())
    assert pa.Table.from_batches([b for c in contents for b in c.resets]).equals(
        open_evidence(recorded).resets()
    )
    records = [r for c in contents for r in c.episode_records]
    # files with Arrow episode blocks: those are the records a pass reads
    assert records == [d for t, _, d in expected if t == fmt.TOPIC_EPISODES]
    assert ev.episodes().equals(open_evidence(recorded).episodes())


def _uncompressed_chunk(path: Path, index: int) -> tuple[int, int, int]:
    """(chunk offset, offset of its records in the file, their length) of an uncompressed file."""
    ref = open_evidence(path)._chunks[index]
    data = path.read_bytes()
    name_length = struct.unpack_from("<I", data, ref.offset + 9 + 28)[0]
    at = ref.offset + 9 + 32 + name_length
    (length,) = struct.unpack_from("<Q", data, at)
    return ref.offset, at + 8, length


@pytest.mark.parametrize("fix_crc", [True, False])
@pytest.mark.parametrize(
    ("which", "new_length", "why"),
    [
        (1, 1 << 40, "overruns"),  # a record claims more bytes than the chunk holds
        (0, 5, "is 5 bytes"),  # a message too short for its own header
    ],
)
def test_corrupted_record_length_is_corruption(
    recorded: Path, tmp_path: Path, fix_crc: bool, which: int, new_length: int, why: str
) -> None:
    plain = rewrite(recorded, tmp_path / "plain.mcap")
    offset, records_at, records_length = _uncompressed_chunk(plain, 1)
    data = plain.read_bytes()
    # find the message records of the chunk and corrupt the length of the chosen one
    steps_channel = next(
        cid for cid, c in open_evidence(plain)._channels.items() if c.topic == fmt.TOPIC_STEPS
    )
    pos, found, on_steps = records_at, [], []
    while pos < records_at + records_length:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x05:
            found.append(pos)
            if struct.unpack_from("<H", data, pos + 9)[0] == steps_channel:
                on_steps.append(pos)
        pos += 9 + length
    # the damaged message is one a read needs (a step block), or the chunk's first message
    target = on_steps[0] if which == 1 else found[which]
    bad = patched(data, target + 1, struct.pack("<Q", new_length))
    crc_at = offset + 9 + 24
    crc = zlib.crc32(bad[records_at : records_at + records_length]) if fix_crc else 0
    bad[crc_at : crc_at + 4] = struct.pack("<I", crc)
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(bad))
    ev = open_evidence(path)
    with pytest.raises(CorruptEvidenceError, match=rf"bad\.mcap: chunk at byte {offset} .*{why}"):
        ev.steps()
    # episodes() of a finished file reads only what its message index points at: a damaged
    # step block it does not need is not its business (check still finds it through steps)
    try:
        open_evidence(path).episodes()
    except CorruptEvidenceError as exc:
        assert f"chunk at byte {offset}" in str(exc)


def test_crc_mismatch_and_bad_sizes_are_corruption(recorded: Path, tmp_path: Path) -> None:
    plain = rewrite(recorded, tmp_path / "plain.mcap")
    offset, records_at, _ = _uncompressed_chunk(plain, 1)
    data = plain.read_bytes()
    cases = {
        "crc.mcap": (patched(data, records_at + 40, b"\xff"), "CRC mismatch"),
        "size.mcap": (
            patched(data, offset + 9 + 16, struct.pack("<Q", 7)),
            "holds .* bytes, not the declared 7",
        ),
        "huge.mcap": (
            patched(data, offset + 9 + 16, struct.pack("<Q", 1 << 50)),
            "declares 1125899906842624 uncompressed bytes",
        ),
    }
    for name, (bad, why) in cases.items():
        path = tmp_path / name
        path.write_bytes(bytes(bad))
        with pytest.raises(CorruptEvidenceError, match=rf"{name}: chunk at byte {offset} .*{why}"):
            open_evidence(path).steps()


def test_zstd_frame_larger_than_the_chunk_says_is_refused_before_decompressing(
    recorded: Path, tmp_path: Path
) -> None:
    ev = open_evidence(recorded)
    ref = ev._chunks[1]
    bad = patched(recorded.read_bytes(), ref.offset + 9 + 16, struct.pack("<Q", 100))
    path = tmp_path / "frame.mcap"
    path.write_bytes(bytes(bad))
    with pytest.raises(CorruptEvidenceError, match=r"zstd frame declares \d+ bytes, the chunk 100"):
        open_evidence(path).steps()


@pytest.mark.parametrize("arrow", [True, False])
def test_zstd_chunks_read_the_same_with_either_decompressor(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, arrow: bool
) -> None:
    """Arrow's zstd (into its memory pool) where pyarrow has it, else ``zstandard``."""
    expected = open_evidence(recorded).steps()
    monkeypatch.setattr(chunks, "_ARROW_ZSTD", arrow)
    assert open_evidence(recorded).steps().equals(expected)
    bad = patched(recorded.read_bytes(), open_evidence(recorded)._chunks[1].offset + 200, b"\x00")
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(bad))
    with pytest.raises(
        CorruptEvidenceError, match=r"flipped.mcap: chunk at byte \d+ .*(CRC|ZSTD|zstd|Zstd)"
    ):
        open_evidence(path).steps()


def test_split_raises_only_corruption_on_garbage(recorded: Path) -> None:
    path = recorded
    ev = open_evidence(path)
    with open(path, "rb") as f:
        ref = ev._chunks[0]
        data = chunks._decompress(chunks._read_chunk_record(f, ref, path), path, ref.offset)
    route = {cid: chunks._SLOTS.get(c.topic, -1) for cid, c in ev._channels.items()}
    rng = random.Random(0)
    outcomes = set()
    for case in range(400):
        mutated = bytearray(data[: rng.randrange(len(data) + 1)] if case % 2 else data)
        for _ in range(rng.randrange(1, 4)):
            at = rng.randrange(len(mutated)) if mutated else 0
            mutated[at : at + 1] = bytes([rng.randrange(256)])
        try:
            chunks._split(bytes(mutated), path, 7, dict(route), (True,) * 3, [], [])
            outcomes.add("ok")
        except CorruptEvidenceError as exc:
            assert "chunk at byte 7" in str(exc) and "run.mcap" in str(exc)
            outcomes.add("corrupt")
    assert outcomes == {"ok", "corrupt"}
    for garbage in (b"\x05", b"\x05\x00\x00", b"\x05" + struct.pack("<Q", 3) + b"abc"):
        with pytest.raises(CorruptEvidenceError, match="chunk at byte 7 is damaged"):
            chunks._split(garbage, path, 7, dict(route), (True,) * 3, [], [])


def test_flipped_byte_inside_a_chunk_is_corruption(recorded: Path, tmp_path: Path) -> None:
    ev = open_evidence(recorded)
    data = bytearray(recorded.read_bytes())
    ref = ev._chunks[1]
    data[ref.offset + 60] ^= 0xFF
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(EvidenceError, match=r"flipped\.mcap: chunk at byte"):
        open_evidence(bad).steps()
