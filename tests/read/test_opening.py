"""Opening files: what is not evidence, torn files (linear scan), damaged ends and metadata."""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import Any

import gymnasium as gym
import pyarrow.compute as pc
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from episode_audit import (
    CorruptEvidenceError,
    EvidenceError,
    NotEvidenceError,
    RecordEvidence,
    UnsupportedVersionError,
    check,
    open_evidence,
    recover,
)
from episode_audit.format import names as fmt
from tests.read.helpers import patched


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(NotEvidenceError, match=r"empty\.mcap: the file is empty"):
        open_evidence(path)


def test_a_directory_points_to_evidence_files(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    with pytest.raises(
        NotEvidenceError,
        match=r"runs: a directory, not an evidence file; its \*\.mcap files are "
        r"episode_audit\.read\.evidence_files\(\[directory\]\)",
    ):
        open_evidence(runs)


def test_garbage_file(tmp_path: Path) -> None:
    path = tmp_path / "garbage.mcap"
    path.write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(NotEvidenceError, match=r"garbage\.mcap: not an MCAP file"):
        open_evidence(path)


@pytest.mark.parametrize("cut", [100, 1000, 1400])
def test_a_file_torn_before_its_run_metadata_says_so(tmp_path: Path, cut: int) -> None:
    """Not "not an evidence file": its header names our profile; the recorder died starting."""
    path = tmp_path / "early.mcap"
    path.write_bytes((Path(__file__).parents[2] / "fixtures" / "clean.mcap").read_bytes()[:cut])
    with pytest.raises(
        CorruptEvidenceError,
        match=rf"early\.mcap: an evidence file torn before its run metadata was written "
        rf"\(torn at byte 57 of {cut}: .*\): it holds no evidence",
    ):
        open_evidence(path)


def test_mcap_that_is_not_evidence(tmp_path: Path) -> None:
    path = tmp_path / "other.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        writer.finish()
    with pytest.raises(NotEvidenceError, match="not evidence"):
        open_evidence(path)


def test_newer_major_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "future.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile=fmt.MCAP_PROFILE, library="future")
        writer.add_metadata(fmt.METADATA_RUN, {"format_version": "2.0"})
        writer.finish()
    with pytest.raises(UnsupportedVersionError, match=r"format 2\.0, newer than this reader"):
        open_evidence(path)


def test_metadata_with_missing_keys(tmp_path: Path) -> None:
    path = tmp_path / "partial.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile=fmt.MCAP_PROFILE, library="x")
        writer.add_metadata(fmt.METADATA_RUN, {"format_version": "1.0"})
        writer.finish()
    with pytest.raises(CorruptEvidenceError, match="run metadata lacks the key"):
        open_evidence(path)


def test_truncated_in_the_middle_of_a_block(recorded: Path, tmp_path: Path) -> None:
    data = recorded.read_bytes()
    ev = open_evidence(recorded)
    total = ev.steps().num_rows
    # cut inside the last chunk: every earlier chunk must survive
    cut = ev._chunks[-2].offset + 20
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[:cut])
    ev2 = open_evidence(torn)
    assert not ev2.finished
    assert ev2.torn is not None and "dropped" in ev2.torn
    kept = ev2.steps().num_rows
    assert 0 < kept < total
    episodes = ev2.episodes()
    ended = episodes.filter(pc.equal(episodes["ended"], True))
    assert ended.num_rows >= 1
    assert sum(episodes["length"].to_pylist()) == kept


@pytest.mark.parametrize("fraction", [0.001, 0.01, 0.3, 0.6, 0.95, 0.999])
def test_any_truncation_raises_only_evidence_errors(
    recorded: Path, tmp_path: Path, fraction: float
) -> None:
    data = recorded.read_bytes()
    torn = tmp_path / "cut.mcap"
    torn.write_bytes(data[: int(len(data) * fraction)])
    try:
        ev = open_evidence(torn)
        ev.episodes()
        ev.steps()
    except EvidenceError as exc:
        assert "cut.mcap" in str(exc)


def _summary_start(data: bytes) -> int:
    """The footer's summary_start (a finished file ends with footer + magic)."""
    _, _, start, _, _ = struct.unpack("<BQQQI", data[-8 - 29 : -8])
    return int(start)


def _same_evidence(a: Any, b: Any) -> bool:
    return bool(
        a.steps().equals(b.steps())
        and a.episodes().equals(b.episodes())
        and a.resets().equals(b.resets())
    )


def test_a_damaged_summary_is_read_around(recorded: Path, tmp_path: Path) -> None:
    """A flipped byte anywhere from the summary to the closing magic changes nothing that is
    read: a summary whose CRC does not match is ignored and the data section is scanned."""
    data = recorded.read_bytes()
    intact = open_evidence(recorded)
    start = _summary_start(data)
    damaged = tmp_path / "damaged.mcap"
    flagged = 0
    for at in range(start, len(data), 13):
        damaged.write_bytes(patched(data, at, bytes([data[at] ^ 0xFF])))
        ev = open_evidence(damaged)
        assert ev.finished, at
        assert _same_evidence(ev, intact), at
        flagged += ev.summary_damage is not None
    assert flagged > (len(data) - start) // 13 // 2  # most flips are caught by the CRC


@pytest.mark.parametrize(
    ("where", "why"),
    [
        (-1, "the closing magic bytes are damaged"),
        (-8 - 29, "the footer record before the closing magic is damaged"),  # its opcode
        (-8 - 29 + 1, "the footer record before the closing magic is damaged"),  # its length
    ],
)
def test_a_damaged_footer_or_magic_is_named_and_the_file_still_reads(
    recorded: Path, tmp_path: Path, where: int, why: str
) -> None:
    data = recorded.read_bytes()
    damaged = tmp_path / "damaged.mcap"
    at = len(data) + where
    damaged.write_bytes(patched(data, at, bytes([data[at] ^ 0xFF])))
    ev = open_evidence(damaged)
    assert ev.summary_damage == why
    assert ev.finished and _same_evidence(ev, open_evidence(recorded))


def test_a_damaged_summary_schema_is_reported_and_recover_writes_a_new_one(
    recorded: Path, tmp_path: Path
) -> None:
    from episode_audit import check, recover

    data = recorded.read_bytes()
    start = _summary_start(data)
    at = data.index(b"episode_audit/steps", start)  # the summary's copy of a channel topic
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(patched(data, at + 3, b"X"))
    ev = open_evidence(damaged)
    assert ev.summary_damage is not None
    assert ev.summary_damage.startswith(f"the summary section at bytes {start}-")
    assert _same_evidence(ev, open_evidence(recorded))
    found = [f for f in check([damaged]).findings if f.code == "summary_damaged"]
    assert len(found) == 1 and found[0].severity == "warning"
    out = tmp_path / "out.mcap"
    result = recover(damaged, out)
    assert not result.already_finished and not result.lost
    assert "does not match the footer's CRC: a new summary was written" in result.summary()
    fixed = open_evidence(out)
    assert fixed.summary_damage is None and fixed.finished
    assert fixed.steps().equals(ev.steps())
    assert not [f for f in check([out]).findings if f.code == "summary_damaged"]


def _metadata_offset(path: Path, name: str) -> tuple[int, int]:
    """(offset, length) of the metadata record ``name`` the file's summary locates."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (index,) = [m for m in summary.metadata_indexes if m.name == name]
    return index.offset, index.length


def test_a_garbled_run_end_record_is_named_and_the_file_is_still_finished(
    recorded: Path, tmp_path: Path
) -> None:
    """Before: "the writer did not finish the file", and recover said the recorder was killed
    before close(). The summary and footer behind the record say the writer finished."""
    data = recorded.read_bytes()
    offset, length = _metadata_offset(recorded, "episode_audit.run_end")
    intact = open_evidence(recorded)
    damaged = tmp_path / "damaged.mcap"
    # the opcode, the length field, the name, a key and a value of the record
    for at in (offset, offset + 1, offset + 9 + 4 + 3, offset + length - 3):
        damaged.write_bytes(patched(data, at, bytes([data[at] ^ 0xFF])))
        ev = open_evidence(damaged)
        assert ev.finished and ev.torn is None and ev.run_end is None, at
        assert ev.run_end_damage is not None
        assert ev.run_end_damage.startswith(
            f"the episode_audit.run_end metadata record at byte {offset} "
        ), at
        assert _same_evidence(ev, intact), at


def test_a_garbled_run_end_record_is_reported_and_recover_writes_a_new_one(
    recorded: Path, tmp_path: Path
) -> None:
    from episode_audit import check, recover

    data = recorded.read_bytes()
    offset, _ = _metadata_offset(recorded, "episode_audit.run_end")
    at = data.index(b"status", offset)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(patched(data, at, b"\xff"))  # not UTF-8 any more
    codes = [f.code for f in check([damaged]).findings]
    assert "run_end_damaged" in codes and "file_unfinished" not in codes
    out = tmp_path / "out.mcap"
    result = recover(damaged, out)
    assert not result.already_finished and not result.lost and result.closing
    assert result.summary().endswith(
        f"; no evidence lost (the episode_audit.run_end metadata record at byte {offset} is "
        "garbled: its status and counts were lost, a new run-end record was written)"
    )
    fixed = open_evidence(out)
    assert fixed.finished and fixed.run_end_damage is None
    assert fixed.run_end is not None and fixed.run_end["status"] == "recovered"
    assert _same_evidence(fixed, open_evidence(recorded))
    assert "run_end_damaged" not in [f.code for f in check([out]).findings]


def test_a_garbled_run_metadata_record_is_named(recorded: Path, tmp_path: Path) -> None:
    """Without the run record (spaces, env, settings) nothing can be read as evidence."""
    data = recorded.read_bytes()
    offset, _ = _metadata_offset(recorded, "episode_audit.run")
    at = data.index(b"format_version", offset)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(patched(data, at, b"\xff"))
    with pytest.raises(
        CorruptEvidenceError,
        match=rf"the episode_audit.run metadata record at byte {offset} is garbled: the "
        "spaces, env and settings of the run it held are lost",
    ):
        open_evidence(damaged)


@pytest.mark.parametrize("byte", [2, 4])  # its length grows past the end, or past the cap
def test_a_garbled_run_metadata_length_in_a_torn_file_is_named(
    recorded: Path, tmp_path: Path, byte: int
) -> None:
    """Not "torn before its run metadata", nor "no complete chunk": intact chunks follow it."""
    data = recorded.read_bytes()
    offset, _ = _metadata_offset(recorded, "episode_audit.run")
    torn = data[: len(data) // 2]  # no summary: read by a scan
    damaged = tmp_path / "damaged.mcap"
    at = offset + 1 + byte  # (a byte of the record's length)
    damaged.write_bytes(patched(torn, at, bytes([torn[at] ^ 0x40])))
    garbled = (
        rf"^{re.escape(str(damaged))}: the episode_audit.run metadata record at byte {offset} "
        "is garbled: the spaces, env and settings of the run it held are lost, so the file "
        "cannot be read as evidence$"
    )
    with pytest.raises(CorruptEvidenceError, match=garbled):
        open_evidence(damaged)
    with pytest.raises(CorruptEvidenceError, match=garbled):
        recover(damaged, tmp_path / "fixed.mcap")
    assert not (tmp_path / "fixed.mcap").exists()
    with pytest.raises(CorruptEvidenceError, match=garbled):
        check([damaged])  # (the command line: a file_unreadable finding saying so)


def test_recovery_reads_its_own_unfinished_output_as_torn_not_as_a_live_recorders(
    tmp_path: Path,
) -> None:
    from episode_audit.read.opening import open_own_output

    path = tmp_path / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        env.step(0)
        env.flush()
        assert open_evidence(path).torn.startswith("still being written by this process")
        own = open_own_output(path)
        assert own.torn is not None and own.torn.startswith("ends at byte")
        assert own.writer is None


def test_one_assignment_lowers_the_record_cap_everywhere(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The fuzz harness lowers ``chunks.MAX_RECORD_BYTES``: opening and the walk obey it too."""
    from mcap.records import Header

    from episode_audit.read import FileEnd, chunks, iter_records

    assert open_evidence(recorded).finished
    monkeypatch.setattr(chunks, "MAX_RECORD_BYTES", 64)  # less than the Schema records
    with pytest.raises(CorruptEvidenceError, match="torn before its run metadata was written"):
        open_evidence(recorded)  # neither the summary nor the scan gets past the first Schema
    items = list(iter_records(recorded))
    assert [type(item) for item in items] == [Header, FileEnd]
    assert items[-1].offset < items[-1].size
