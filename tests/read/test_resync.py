"""read/resync.py: finding the next intact record after damage."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader

from episode_audit.format import names as fmt
from episode_audit.read import resync


def _records(path: Path) -> tuple[bytes, bytes]:
    """A whole chunk record of ``path`` and its run metadata record, as bytes."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    index = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    run = next(m for m in summary.metadata_indexes if m.name == fmt.METADATA_RUN)
    data = path.read_bytes()
    start = index.chunk_start_offset
    return data[start : start + index.chunk_length], data[run.offset : run.offset + run.length]


def _find(tmp_path: Path, data: bytes, start: int = 0) -> int | None:
    path = tmp_path / "scan.bin"
    path.write_bytes(data)
    with open(path, "rb") as f:
        return resync.next_intact(f, path, start, len(data))


def _fake_chunk(records: int) -> bytes:
    """A chunk record's framing with zstd named in place, around bytes that are no zstd."""
    body = struct.pack("<QQQII", 0, 0, 100, 1, 4) + b"zstd" + struct.pack("<Q", records)
    body += b"\x28\xb5\x2f\xfd" + bytes(records - 4)
    return struct.pack("<BQ", 0x06, len(body)) + body


@pytest.mark.parametrize("garbage", [0, 1, 200, 255, 256, 257, 300, 700])
def test_the_next_intact_chunk_is_found_wherever_it_starts(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, garbage: int
) -> None:
    """Also across the scan's window ends (a small window: the same code, more of them)."""
    monkeypatch.setattr(resync, "_WINDOW", 256)
    chunk, _ = _records(recorded)
    noise = bytes((i * 7 + 3) % 256 for i in range(garbage))
    assert _find(tmp_path, noise + chunk + noise) == garbage


def test_a_record_that_only_looks_like_one_is_passed_over(recorded: Path, tmp_path: Path) -> None:
    """Framing alone is not enough: a chunk must decompress and match its CRC, a metadata
    record must be filled exactly by its name and entries."""
    chunk, run = _records(recorded)
    fake = _fake_chunk(64)
    bad_crc = bytearray(chunk)
    bad_crc[-10] ^= 0xFF
    (name,) = struct.unpack_from("<I", run, 9)
    misnamed = run[:9] + struct.pack("<I", name + 1) + run[13:]
    long_metadata = struct.pack("<BQ", 0x0C, len(run) - 8) + run[9:] + b"\x00"
    for decoy in (fake, bytes(bad_crc), misnamed, long_metadata):
        assert _find(tmp_path, decoy) is None
        assert _find(tmp_path, decoy + chunk) == len(decoy)
    assert _find(tmp_path, b"\x00" * 50 + run + chunk) == 50  # a metadata record counts
    assert _find(tmp_path, chunk + chunk, start=1) == len(chunk)
    assert _find(tmp_path, b"") is None and _find(tmp_path, chunk[:-1]) is None


def test_where_nothing_intact_is_left_is_scanned_once(recorded: Path, tmp_path: Path) -> None:
    """After a scan found nothing, a later damage asks again without reading the file."""
    chunk, _ = _records(recorded)
    path = tmp_path / "scan.bin"
    path.write_bytes(bytes(300) + chunk + bytes(300))
    with open(path, "rb") as f:
        scan = resync.Resync(f, path, path.stat().st_size)
        assert scan.after(-1) == 300 and scan.after(300) is None
        f.close()  # a second scan from further on would now fail to read
        assert scan.after(301) is None and scan.after(5000) is None
