from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import struct
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from typer.testing import CliRunner

from episode_audit import (
    ConfigurationError,
    CorruptEvidenceError,
    EpisodeRanges,
    EvidenceError,
    NotEvidenceError,
    RecordEvidence,
    RecordVectorEvidence,
    ReplayResult,
    export,
    open_evidence,
    recover,
)
from episode_audit.cli import app
from episode_audit.read import iter_records
from episode_audit.recover.files import temporary
from episode_audit.replay import replay as replay_files
from tests import kill_harness
from tests.support.disk import fill_disk
from tests.support.hostile import replace_column, rewrite
from tests.support.killing import how_long, killed_midway
from tests.support.rewards import record_cartpole
from tests.support.viewer_files import random_cartpole_file

runner = CliRunner()


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished CartPole file: 6 seeded episodes, a chunk every 32 steps."""
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=32, flush_every_s=3600) as env:
        env.action_space.seed(0)
        for seed in range(6):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
    return path


def layout(path: Path) -> tuple[list[tuple[int, int]], int]:
    """(chunk offset, chunk length) of every chunk, and where the summary starts (mcap's view)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        chunks = sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)
    data = path.read_bytes()  # the footer: opcode, length, summary start, ...; then the magic
    opcode, _, summary_start = struct.unpack_from("<BQQ", data, len(data) - 8 - 29)
    assert opcode == 0x02
    return chunks, summary_start


def torn_copy(recorded: Path, directory: Path, cut: int) -> Path:
    torn = directory / f"torn-{cut}.mcap"
    torn.write_bytes(recorded.read_bytes()[:cut])
    return torn


def assert_recovered_like(torn: Path, out: Path, messages: int) -> None:
    """The output is a finished, indexed MCAP holding what a reader of the torn file sees."""
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == messages
        run_end = {m.name: m.metadata for m in reader.iter_metadata()}["episode_audit.run_end"]
        blocks = [m.data for _, _, m in reader.iter_messages(topics=["episode_audit/steps"])]
    assert run_end["status"] == "recovered" and int(run_end["blocks"]) == len(blocks)
    assert sum(pa.ipc.open_stream(b).read_all().num_rows for b in blocks) == int(run_end["steps"])
    before, after = open_evidence(torn), open_evidence(out)
    assert not before.finished and after.finished and after.torn is None
    assert after.run_end is not None and after.run_end["status"] == "recovered"
    assert after.run.to_metadata() == before.run.to_metadata()
    assert after.episodes().equals(before.episodes())
    assert after.steps().equals(before.steps())
    assert after.resets().equals(before.resets())
    assert int(run_end["steps"]) == before.steps().num_rows
    assert int(run_end["episodes"]) == before.episodes().num_rows


def test_cut_inside_a_chunk_drops_it_and_says_so(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[-3]
    torn = torn_copy(recorded, tmp_path, offset + length // 2)
    source = torn.read_bytes()
    result = recover(torn, tmp_path / "out.mcap")
    assert torn.read_bytes() == source  # the input is never changed
    assert result.data_dropped and result.lost and not result.already_finished
    assert result.dropped_record == "chunk" and result.dropped_at == offset
    assert result.dropped_bytes == length // 2
    assert result.chunks == len(chunks) - 3
    cut = open_evidence(torn).episodes()
    assert result.cut_off_episodes == tuple(
        cut.filter(pc.invert(cut["ended"]))["episode"].to_pylist()
    )
    assert len(result.cut_off_episodes) == 1
    assert f"the last {result.dropped_bytes} bytes (a partial chunk record" in result.summary()
    assert_recovered_like(torn, tmp_path / "out.mcap", result.messages)


@pytest.mark.parametrize("where", ["header", "first chunk", "message index", "summary"])
def test_cuts_at_other_offsets(recorded: Path, tmp_path: Path, where: str) -> None:
    chunks, summary_start = layout(recorded)
    first, (last, last_length) = chunks[0], chunks[-1]
    cut = {
        "header": first[0],  # header and run metadata only: no chunk yet
        "first chunk": first[0] + first[1] - 1,
        "message index": last + last_length + 5,  # after close()'s last chunk
        "summary": summary_start + 7,
    }[where]
    torn = torn_copy(recorded, tmp_path, cut)
    if where in ("header", "first chunk"):  # no complete chunk: nothing to recover, no output
        if where == "header":  # torn before the first block: no step schema in the file
            assert open_evidence(torn).steps(columns=["episode", "reward"]).num_rows == 0
        with pytest.raises(EvidenceError, match="nothing to recover: the file holds its run"):
            recover(torn, tmp_path / "out.mcap")
        assert not (tmp_path / "out.mcap").exists()
        return
    result = recover(torn, tmp_path / "out.mcap")
    assert_recovered_like(torn, tmp_path / "out.mcap", result.messages)
    expected = {
        "message index": ("message index", False, len(chunks)),
        "summary": ("schema", False, len(chunks)),
    }[where]
    assert (result.dropped_record, result.data_dropped, result.chunks) == expected
    # only a cut after close() wrote the run-end record (before the summary) loses nothing
    assert result.lost == (where != "summary")
    assert result.closing == (where == "summary")


def test_killed_during_close_loses_nothing(recorded: Path, tmp_path: Path) -> None:
    _, summary_start = layout(recorded)
    torn = torn_copy(recorded, tmp_path, summary_start)  # run-end record and data end written
    code, out, _ = run("recover", str(torn), "-o", str(tmp_path / "out.mcap"))
    assert code == 0, out
    assert (
        "nothing lost (close() had written the run-end record; the summary after it was cut)" in out
    )
    fixed = open_evidence(tmp_path / "out.mcap")
    assert fixed.run_end is not None
    assert fixed.run_end["dropped"] == "nothing" and fixed.run_end["cut_off_episodes"] == "[]"
    assert fixed.run_end["end_time"] == open_evidence(recorded).run_end["end_time"]  # type: ignore[index]
    # whether the task reports success is the original's (report's warnings read it)
    assert fixed.run_end["success_reported"] == open_evidence(recorded).run_end["success_reported"]  # type: ignore[index]
    assert fixed.reports_success is open_evidence(recorded).reports_success is not None


def test_a_file_without_its_closing_magic_is_unfinished(recorded: Path, tmp_path: Path) -> None:
    torn = torn_copy(recorded, tmp_path, recorded.stat().st_size - 8)  # killed before the magic
    ev = open_evidence(torn)
    assert not ev.finished and ev.torn is not None and "closing magic" in ev.torn
    result = recover(torn, tmp_path / "out.mcap")
    assert not result.lost and not result.already_finished and result.dropped_bytes == 0
    assert_recovered_like(torn, tmp_path / "out.mcap", result.messages)


def test_a_damaged_footer_before_an_intact_closing_magic_loses_nothing(
    recorded: Path, tmp_path: Path
) -> None:
    data = bytearray(recorded.read_bytes())
    data[-8 - 29] = 0x7F  # the footer's opcode, the closing magic after it intact
    damaged = tmp_path / "footer.mcap"
    damaged.write_bytes(bytes(data))
    code, out, _ = run("recover", str(damaged), "-o", str(tmp_path / "out.mcap"))
    assert code == 0, out
    assert "nothing lost (the last 8 bytes (the closing magic at byte" in out
    fixed = open_evidence(tmp_path / "out.mcap")
    assert fixed.finished and fixed.steps().equals(open_evidence(recorded).steps())


def test_cli_exit_1_says_what_was_dropped(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    torn = torn_copy(recorded, tmp_path, chunks[2][0] + 40)
    code, out, err = run("recover", str(torn), "--out", str(tmp_path / "out.mcap"))
    assert code == 1 and err == ""
    assert "dropped: the last" in out and "(a partial chunk record at byte" in out
    assert "had no end record: recorded as incomplete" in out


def test_cli_refuses_to_overwrite_and_never_writes_in_place(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    torn = torn_copy(recorded, tmp_path, chunks[2][0] + 40)
    digest = hashlib.sha256(torn.read_bytes()).hexdigest()
    code, _, err = run("recover", str(torn), "-o", str(torn), "--overwrite")
    assert code == 2 and "the output is the input" in err
    existing = tmp_path / "existing.mcap"
    existing.write_bytes(b"keep me")
    code, _, err = run("recover", str(torn), "-o", str(existing))
    assert code == 2 and "file exists" in err and "--overwrite" in err
    assert existing.read_bytes() == b"keep me"
    code, _, _ = run("recover", str(torn), "-o", str(existing), "--overwrite")
    assert code == 1 and open_evidence(existing).finished
    assert hashlib.sha256(torn.read_bytes()).hexdigest() == digest
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.mcap", torn.name]


def test_cli_exit_2_for_what_is_not_evidence(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    text = tmp_path / "notes.mcap"
    text.write_text("not mcap")
    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        writer.finish()
    for path, why in [
        (empty, "the file is empty"),
        (text, "not an MCAP file"),
        (other, "not evidence"),
        (tmp_path / "missing.mcap", "no such file"),
    ]:
        code, out, err = run("recover", str(path), "-o", str(tmp_path / "out.mcap"))
        assert code == 2 and why in err and out == "", (path, err)
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out.mcap").exists()
    with pytest.raises(NotEvidenceError, match="not an MCAP file"):
        recover(text, tmp_path / "out.mcap")
    with pytest.raises(ConfigurationError, match="is a directory"):
        recover(text, tmp_path)


def evidence_in_chunk(path: Path, offset: int) -> set[int]:
    """The episodes with a reset row, step rows or an end record in the chunk at ``offset``."""
    for chunk in open_evidence(path).scan():
        if chunk.offset == offset:
            found: set[int] = set()
            for batch in chunk.steps + chunk.resets:
                found.update(batch.column("episode").to_pylist())
            for raw in chunk.episode_records:
                found.update(pa.ipc.open_stream(raw).read_all()["episode"].to_pylist())
            return found
    raise AssertionError(f"no chunk at {offset}")


def replay_file(path: Path) -> ReplayResult:
    return replay_files([path])


def damaged_copy(source: Path, directory: Path, at: int, cut: int | None = None) -> Path:
    """``source`` (up to ``cut``) with the byte at ``at`` flipped."""
    data = bytearray(source.read_bytes()[:cut])
    data[at] ^= 0xFF
    out = directory / f"damaged-{at}-{cut}.mcap"
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize("which", ["first", "second", "middle", "last"])
def test_a_damaged_chunk_is_skipped_and_its_episodes_named(
    recorded: Path, tmp_path: Path, which: str
) -> None:
    chunks, _ = layout(recorded)
    k = {"first": 0, "second": 1, "middle": len(chunks) // 2, "last": len(chunks) - 1}[which]
    offset, length = chunks[k]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20)  # in the compressed records
    with pytest.raises(CorruptEvidenceError, match=f"chunk at byte {offset} is damaged.*recover"):
        open_evidence(damaged).episodes()
    result = recover(damaged, tmp_path / "out.mcap")
    assert [(d.offset, d.length) for d in result.damaged] == [(offset, length)]
    assert "CRC mismatch" in result.damaged[0].why or "damaged" in result.damaged[0].why
    truth = evidence_in_chunk(recorded, offset)
    assert truth and set(result.damaged_episodes.first(1000)) == truth
    assert result.lost and result.chunks == len(chunks) - 1 and not result.cut_off_episodes
    out = open_evidence(tmp_path / "out.mcap")
    assert out.finished and out.run_end is not None and out.run_end["status"] == "recovered"
    assert out.damaged_episodes == result.damaged_episodes and out.damaged_stretches == 1
    # every step of every intact chunk is kept, untouched
    original = open_evidence(recorded).steps()
    kept = original.filter(pc.invert(pc.is_in(original["episode"], pa.array(sorted(truth)))))
    survivors = out.steps()
    survivors = survivors.filter(pc.invert(pc.is_in(survivors["episode"], pa.array(sorted(truth)))))
    assert survivors.equals(kept)
    # the audit commands say what was lost; replay skips the damaged episodes
    code, report, _ = run("check", str(tmp_path / "out.mcap"), "--format", "json")
    findings = json.loads(report)["findings"]
    damage = [f for f in findings if f["code"] == "evidence_damaged"]
    assert code == 1 and len(damage) == 1 and damage[0]["severity"] == "error"
    assert f"{len(truth)} episode(s) lost part or all" in damage[0]["message"]
    assert not any("cut off by the torn end" in f["message"] for f in findings)
    replayed = replay_file(tmp_path / "out.mcap")
    skipped = {e.episode for e in replayed.episodes if e.status == "not_replayable"}
    assert skipped == truth & {e.episode for e in replayed.episodes}
    assert replayed.count("identical") == len(replayed.episodes) - len(skipped)


def test_recover_cli_names_the_damage_and_exits_1(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[1]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20)
    for command in ("check", "report", "show", "replay"):
        code, _, err = run(command, str(damaged))
        assert code == 2 and "`episode-audit recover` copies the intact chunks" in err, command
    code, out, err = run("recover", str(damaged), "-o", str(tmp_path / "out.mcap"))
    assert code == 1 and err == ""
    assert f"1 damaged stretch(es) skipped (chunk at byte {offset} is damaged" in out
    assert "lost evidence in them" in out and len(out.strip().splitlines()) == 1


def test_a_damaged_file_among_good_ones_costs_them_nothing(recorded: Path, tmp_path: Path) -> None:
    """The damage is found after the file opened; the others are still checked, replayed,
    reported and exported, and the command exits 2 naming the damaged file."""
    chunks, _ = layout(recorded)
    offset, length = chunks[1]
    inputs = tmp_path / "in"
    inputs.mkdir()
    shutil.copy(recorded, inputs / "a.mcap")
    damaged_copy(recorded, tmp_path, offset + length - 20).rename(inputs / "b.mcap")
    record_cartpole(inputs / "c.mcap", episodes=6)  # (another run: a copy is the same run)
    good = [str(inputs / "a.mcap"), str(inputs / "c.mcap")]
    for command in ("check", "replay", "report", "export"):
        if command == "export":
            code, out, err = run(command, str(inputs), "-o", str(tmp_path / "out"))
        else:
            code, out, err = run(command, str(inputs), "--format", "json")
        assert code == 2, command
        assert err.count("episode-audit: error:") == 1, command
        assert f"{inputs / 'b.mcap'}: chunk at byte {offset} is damaged" in err, command
        if command == "check":  # the damaged file is there as a file_unreadable error
            data = json.loads(out)
            assert data["files"] == [good[0], str(inputs / "b.mcap"), good[1]]
            assert [f["file"] for f in data["findings"] if f["code"] == "file_unreadable"] == [
                str(inputs / "b.mcap")
            ]
        elif command == "replay":
            assert sorted({e["file"] for e in json.loads(out)["episodes"]}) == good
        elif command == "report":
            assert [g["key"] for g in json.loads(out)["groups"]] == good
    exported = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert exported == ["a.steps.parquet", "c.steps.parquet", "episodes.parquet"]
    episodes = pq.read_table(tmp_path / "out" / "episodes.parquet")
    assert sorted(set(episodes.column("file").to_pylist())) == good
    assert episodes.num_rows == 2 * open_evidence(recorded).episodes().num_rows


def test_export_raises_on_a_damaged_file_unless_given_on_error(
    recorded: Path, tmp_path: Path
) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[1]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20)
    with pytest.raises(CorruptEvidenceError, match=f"chunk at byte {offset} is damaged"):
        export([recorded, damaged], tmp_path / "raised")
    assert not (tmp_path / "raised" / f"{damaged.stem}.steps.parquet").exists()
    errors: list[EvidenceError] = []
    result = export([recorded, damaged], tmp_path / "kept", on_error=errors.append)
    assert result.failed == [damaged] and len(errors) == 1
    assert result.steps_files == [tmp_path / "kept" / "run.steps.parquet"]
    assert result.episodes == open_evidence(recorded).episodes().num_rows


def test_garbled_framing_in_a_finished_file_is_skipped_up_to_the_next_chunk(
    recorded: Path, tmp_path: Path
) -> None:
    chunks, _ = layout(recorded)
    (offset, _), (following, _) = chunks[2], chunks[3]
    damaged = damaged_copy(recorded, tmp_path, offset + 8)  # the top byte of its record length
    result = recover(damaged, tmp_path / "out.mcap")
    assert [(d.offset, d.length) for d in result.damaged] == [(offset, following - offset)]
    assert "past the end of the file" in result.damaged[0].why
    assert set(result.damaged_episodes.first(1000)) == evidence_in_chunk(recorded, offset)
    assert result.chunks == len(chunks) - 1


def test_damage_and_a_torn_tail_together(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[1]
    cut = chunks[-2][0] + 40  # torn inside the second-to-last chunk
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20, cut)
    result = recover(damaged, tmp_path / "out.mcap")
    assert [d.offset for d in result.damaged] == [offset]
    assert set(result.damaged_episodes.first(1000)) == evidence_in_chunk(recorded, offset)
    assert result.dropped_record == "chunk" and result.dropped_at == chunks[-2][0]
    assert result.cut_off_episodes  # the episode in flight at the torn end
    assert not set(result.cut_off_episodes) & set(result.damaged_episodes.first(1000))
    text = result.summary()
    assert "damaged stretch(es) skipped" in text and "had no end record" in text


def test_damage_in_the_last_intact_chunk_of_a_torn_file_marks_the_open_episodes(
    recorded: Path, tmp_path: Path
) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[-3]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20, chunks[-2][0] + 40)
    result = recover(damaged, tmp_path / "out.mcap")
    # whether an episode lost its end record to the damage or to the kill cannot be told:
    # none is called cut off, every one without an end record is named as damaged; one that
    # began in the damaged chunk left nothing behind, and the result says it cannot be counted
    assert not result.cut_off_episodes and result.damaged_tail
    present = {
        int(e) for e in open_evidence(tmp_path / "out.mcap").episodes()["episode"].to_pylist()
    }
    truth = evidence_in_chunk(recorded, offset)
    assert truth & present and set(result.damaged_episodes.first(1000)) == truth & present
    assert "episodes begun there cannot be counted" in result.summary()


def test_a_damaged_first_chunk_of_a_torn_file_cannot_be_recovered(
    recorded: Path, tmp_path: Path
) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[0]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20, chunks[-2][0] + 40)
    with pytest.raises(CorruptEvidenceError, match="holds the channel definitions") as caught:
        recover(damaged, tmp_path / "out.mcap")
    assert "copies the intact chunks" not in str(caught.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == [damaged.name]  # no temp file left
    code, _, err = run("recover", str(damaged), "-o", str(tmp_path / "out.mcap"))
    assert code == 2 and "no chunk can be decoded" in err and len(err.strip().splitlines()) == 1


def test_iter_records_raises_on_damage_unless_asked_to_skip(recorded: Path, tmp_path: Path) -> None:
    chunks, _ = layout(recorded)
    offset, length = chunks[1]
    damaged = damaged_copy(recorded, tmp_path, offset + length - 20)
    with pytest.raises(CorruptEvidenceError, match=f"chunk at byte {offset} is damaged"):
        list(iter_records(damaged))
    walked = list(iter_records(damaged, skip_damaged=True))
    assert [type(item).__name__ for item in walked].count("DamagedRegion") == 1
    assert [type(item).__name__ for item in walked].count("ChunkRecords") == len(chunks) - 1


def test_finished_file_is_copied_unchanged(recorded: Path, tmp_path: Path) -> None:
    code, out, _ = run("recover", str(recorded), "-o", str(tmp_path / "copy.mcap"))
    assert code == 0 and "already finished: copied unchanged" in out
    assert (tmp_path / "copy.mcap").read_bytes() == recorded.read_bytes()
    copied = recover(recorded, tmp_path / "copy2.mcap")
    assert copied.already_finished and copied.steps == open_evidence(recorded).steps().num_rows
    # a recovered file is finished too
    chunks, _ = layout(recorded)
    torn = torn_copy(recorded, tmp_path, chunks[2][0] + 40)
    recover(torn, tmp_path / "once.mcap")
    again = recover(tmp_path / "once.mcap", tmp_path / "twice.mcap")
    assert again.already_finished and not again.lost


def test_audit_commands_agree_on_a_torn_file_and_its_recovery(
    recorded: Path, tmp_path: Path
) -> None:
    chunks, _ = layout(recorded)
    torn = torn_copy(recorded, tmp_path, chunks[4][0] + 40)
    fixed = tmp_path / "fixed.mcap"
    assert recover(torn, fixed).lost

    def output(command: str, path: Path, *extra: str) -> tuple[int, object]:
        code, out, _ = run(command, str(path), "--format", "json", *extra)
        return code, json.loads(out.replace(str(path), "FILE"))

    code, torn_check = output("check", torn)
    assert code == 0
    code, fixed_check = output("check", fixed)
    assert code == 0
    swapped = {"file_unfinished": "file_recovered"}
    assert [
        (f["severity"], swapped.get(f["code"], f["code"]), f["episode"], f["step"])
        for f in torn_check["findings"]  # type: ignore[index]
    ] == [
        (f["severity"], f["code"], f["episode"], f["step"])
        for f in fixed_check["findings"]  # type: ignore[index]
    ]
    assert "incomplete_episode" in {f["code"] for f in fixed_check["findings"]}  # type: ignore[index]
    code, torn_report = output("report", torn)
    assert code == 0
    assert [u["file"] for u in torn_report.pop("unfinished")] == ["FILE"]  # type: ignore[attr-defined]
    code, fixed_report = output("report", fixed)
    assert fixed_report.pop("unfinished") == []  # type: ignore[attr-defined]
    assert torn_report == fixed_report
    assert output("replay", torn) == output("replay", fixed)
    code, replayed = output("replay", fixed)
    assert code == 0 and replayed["summary"]["identical"] >= 3  # type: ignore[index]
    code, torn_show = output("show", torn)
    assert code == 0
    code, fixed_show = output("show", fixed)
    assert code == 0
    for data in (torn_show, fixed_show):
        for key in ("finished", "torn", "recovered"):
            data.pop(key)  # type: ignore[attr-defined]
    assert torn_show == fixed_show
    episode = str(open_evidence(torn).episodes()["episode"][-1].as_py())
    assert output("show", torn, "-e", episode) == output("show", fixed, "-e", episode)
    code, text, _ = run("show", str(fixed))
    assert "recovered from a torn or damaged file (dropped: the last" in text


def test_kill_sample(tmp_path: Path) -> None:
    """A few kills of the crash harness (make test-long runs over a hundred)."""
    verdicts = kill_harness.run(8, tmp_path, seed=11, scale=0.3)
    assert {v.plan.mode for v in verdicts} == set(kill_harness.MODES)
    assert [(v.plan, v.problems) for v in verdicts if v.problems] == []
    assert all(v.in_file >= v.flushed for v in verdicts)


def test_a_damaged_chunk_of_a_vector_file(tmp_path: Path) -> None:
    """Several streams: episodes of every sub-env that had evidence in the chunk are named."""
    path = tmp_path / "vector.mcap"
    envs = gym.vector.SyncVectorEnv([lambda: gym.make("CartPole-v1") for _ in range(3)])
    with RecordVectorEvidence(envs, path, block_steps=64) as env:
        env.action_space.seed(0)
        env.reset(seed=0)
        for _ in range(300):
            env.step(env.action_space.sample())
    chunks, _ = layout(path)
    offset, length = chunks[len(chunks) // 2]
    damaged = damaged_copy(path, tmp_path, offset + length - 20)
    result = recover(damaged, tmp_path / "out.mcap")
    truth = evidence_in_chunk(path, offset)
    assert len(truth) > 3 and set(result.damaged_episodes.first(1000)) == truth
    replayed = replay_file(tmp_path / "out.mcap")
    assert replayed.count("diverged") == 0
    assert {e.episode for e in replayed.episodes if e.status == "not_replayable"} == truth & {
        e.episode for e in replayed.episodes
    }


def test_a_damaged_chunk_of_a_pettingzoo_file(tmp_path: Path) -> None:
    """Agent-episodes are named like any other; replay skips every game one of them is in."""
    rps_v2 = pytest.importorskip("pettingzoo.classic.rps_v2")
    from episode_audit import RecordParallelEvidence, check

    path = tmp_path / "rps.mcap"
    kwargs = {"max_cycles": 5}
    with RecordParallelEvidence(
        rps_v2.parallel_env(**kwargs), path, env_kwargs=kwargs, block_steps=8
    ) as env:
        for game in range(30):
            env.reset(seed=game)
            while env.agents:
                env.step({a: (game + i) % 3 for i, a in enumerate(env.agents)})
    chunks, _ = layout(path)
    assert len(chunks) >= 3
    offset, length = chunks[len(chunks) // 2]
    damaged = damaged_copy(path, tmp_path, offset + length - 20)
    out = tmp_path / "out.mcap"
    result = recover(damaged, out)
    truth = evidence_in_chunk(path, offset)
    assert truth and set(result.damaged_episodes.first(1000)) == truth
    assert [f.code for f in check([out]).findings].count("evidence_damaged") == 1
    replayed = replay_file(out)
    assert replayed.count("diverged") == 0 and replayed.count("identical") > 0
    skipped = {e.episode for e in replayed.episodes if e.status == "not_replayable"}
    present = {e.episode for e in replayed.episodes}
    assert truth & present <= skipped  # and the other agent-episodes of those games
    assert all(
        e.reason is not None and "damaged chunk" in e.reason
        for e in replayed.episodes
        if e.status == "not_replayable"
    )


def test_a_finished_file_never_calls_an_episode_cut_off(tmp_path: Path) -> None:
    """An agent that left early had its end record in a damaged chunk that later chunks
    follow: after close() no episode was in flight, so its episode lost evidence; it was
    not cut off by a killed writer."""
    pytest.importorskip("pettingzoo")
    from gymnasium.spaces import Box, Discrete
    from pettingzoo.utils.env import ParallelEnv

    from episode_audit import RecordParallelEvidence

    class OneLeavesEarly(ParallelEnv):  # type: ignore[misc]
        metadata = {"name": "one_leaves_early_v0"}
        possible_agents = ["early", "late"]

        def observation_space(self, agent: str) -> Any:
            return Box(0.0, 100.0, (1,), np.float32)

        def action_space(self, agent: str) -> Any:
            return Discrete(2)

        def reset(self, seed: int | None = None, options: Any = None) -> Any:
            self.agents, self.t = list(self.possible_agents), 0
            return {a: np.zeros(1, np.float32) for a in self.agents}, {a: {} for a in self.agents}

        def step(self, actions: Any) -> Any:
            self.t += 1
            ends = {a: self.t == (20 if a == "early" else 60) for a in self.agents}
            obs = {a: np.array([self.t], np.float32) for a in self.agents}
            nothing: dict[str, Any] = {a: {} for a in self.agents}
            rewards = dict.fromkeys(self.agents, 1.0)
            out = obs, rewards, ends, dict.fromkeys(self.agents, False), nothing
            self.agents = [a for a in self.agents if not ends[a]]
            return out

    path = tmp_path / "early.mcap"
    with RecordParallelEvidence(OneLeavesEarly(), path, block_steps=8) as env:
        env.reset(seed=0)
        while env.agents:
            env.step(dict.fromkeys(env.agents, 0))
    chunks, _ = layout(path)
    # the last chunk with evidence of the early agent's episode (0) holds its end record
    k = max(i for i, (offset, _) in enumerate(chunks) if 0 in evidence_in_chunk(path, offset))
    assert 0 < k < len(chunks) - 1
    offset, length = chunks[k]
    result = recover(damaged_copy(path, tmp_path, offset + length - 20), tmp_path / "out.mcap")
    assert result.closing and result.lost
    assert not result.cut_off_episodes
    assert set(result.damaged_episodes.first(10)) == evidence_in_chunk(path, offset) == {0, 1}


@pytest.mark.parametrize(
    "raw",
    [None, "", "not json", "{}", "[1, 2]", "[[3, 1]]", '[["a", 2]]', "[[-1, 4]]", "[[1, 2, 3]]"],
)
def test_damaged_episodes_that_do_not_parse_read_as_none(raw: str | None) -> None:
    assert EpisodeRanges.from_json(raw) == EpisodeRanges()


def test_damaged_episodes_stay_compact_and_exact() -> None:
    lost = EpisodeRanges.of([2, 3, 9], spans=[(4, 5), (10, 10**12)])
    assert lost.spans == ((2, 5), (9, 10**12)) and lost.count == 10**12 - 4
    assert 10**11 in lost and 6 not in lost and "3" not in lost and np.int64(3) in lost
    assert EpisodeRanges.from_json(lost.to_json()) == lost and lost.first(3) == [2, 3, 4]


def test_recovering_a_recovered_file_again_keeps_its_cut_off_episodes(
    recorded: Path, tmp_path: Path
) -> None:
    # A recovered file has a run-end record, so close() "ran" — but its cut-off episodes were
    # cut off by the torn original, and a second recovery (the copy was damaged in turn) must
    # not call them damaged.
    chunks, _ = layout(recorded)
    offset, length = chunks[len(chunks) // 2]
    once = tmp_path / "once.mcap"
    first = recover(torn_copy(recorded, tmp_path, offset + length), once)
    assert first.cut_off_episodes
    cut_off = set(first.cut_off_episodes)
    intact, _ = layout(once)
    damaged_at = next(
        (o, n) for o, n in intact[1:] if evidence_in_chunk(once, o).isdisjoint(cut_off)
    )
    twice = tmp_path / "twice.mcap"
    second = recover(damaged_copy(once, tmp_path, damaged_at[0] + damaged_at[1] - 20), twice)
    assert set(second.cut_off_episodes) == cut_off
    assert set(second.damaged_episodes.first(100)) == evidence_in_chunk(once, damaged_at[0])
    out = open_evidence(twice)
    assert json.loads(out.run_end["cut_off_episodes"]) == sorted(cut_off)  # type: ignore[index]


def chunk_steps(path: Path) -> dict[int, pa.Table]:
    """The step rows of each chunk of ``path``, by the chunk's offset."""
    return {
        chunk.offset: pa.Table.from_batches(chunk.steps).select(["episode", "step", "reward"])
        for chunk in open_evidence(path).scan()
        if chunk.steps
    }


def disk_full_copy(recorded: Path, directory: Path, k: int, written: int) -> Path:
    """``recorded`` as a brief disk-full leaves it: of chunk ``k`` (and its message indexes)
    only the first ``written`` bytes reached the file; the writer went on appending the later
    chunks after them, flushed, and was killed before writing its last chunk."""
    chunks, _ = layout(recorded)
    data = recorded.read_bytes()
    (offset, _), (following, _) = chunks[k], chunks[k + 1]
    spliced = data[: offset + written] + data[following : chunks[-1][0]]
    out = directory / f"disk-full-{k}-{written}.mcap"
    out.write_bytes(spliced)
    return out


@pytest.mark.parametrize("written", [1, 5, 40, "half", "index"])
def test_recover_resynchronises_after_a_partial_chunk_and_keeps_every_later_step(
    recorded: Path, tmp_path: Path, written: int | str
) -> None:
    """Found by the issue's disk-full run: recover kept the chunks before a partial one and
    dropped every intact chunk after it as "a partial unknown record"."""
    chunks, _ = layout(recorded)
    k = 1  # the first chunk holds the channel definitions
    offset, length = chunks[k]
    # cut inside the chunk's record head, its header, its records; or after the whole chunk,
    # inside the message index records that follow it
    cut = {"half": length // 2, "index": length + 10}.get(str(written), written)
    assert isinstance(cut, int)
    spliced = disk_full_copy(recorded, tmp_path, k, cut)
    result = recover(spliced, tmp_path / "out.mcap")
    # the partial record is one damaged stretch, up to the next intact chunk (where the
    # writer went on); nothing is dropped at the end (the kill came after a flush)
    lost = offset if written != "index" else None
    start = offset if lost is not None else offset + length
    assert [(d.offset, d.length) for d in result.damaged] == [(start, offset + cut - start)]
    assert result.dropped_bytes == 0
    assert result.chunks == len(chunks) - 1 - (lost is not None)
    # every step of every later chunk comes back, untouched
    by_chunk = chunk_steps(recorded)
    expected = pa.concat_tables(
        table for at, table in by_chunk.items() if at not in (lost, chunks[-1][0])
    )
    out = open_evidence(tmp_path / "out.mcap")
    assert out.steps(columns=["episode", "step", "reward"]).equals(expected)
    later = sum(t.num_rows for at, t in by_chunk.items() if offset < at < chunks[-1][0])
    assert later >= 2 * 32 and result.steps == expected.num_rows
    # the episodes with evidence in the lost chunk are named as damaged, no others
    truth = evidence_in_chunk(recorded, offset) if lost is not None else set()
    assert set(result.damaged_episodes.first(1000)) == truth
    text = result.summary()
    assert "1 damaged stretch(es) skipped (" in text and f" at byte {start} " in text


def _nulls_in(column: str) -> Any:
    def edit(batch: pa.RecordBatch) -> pa.RecordBatch:
        values = batch.column(column).to_pylist()
        values[0] = None
        return replace_column(batch, column, values)

    return edit


def _unknown_outcome(batch: pa.RecordBatch) -> pa.RecordBatch:
    return replace_column(batch, "outcome", ["won"] * batch.num_rows)


def _reward_as_text(batch: pa.RecordBatch) -> pa.RecordBatch:
    i = batch.schema.get_field_index("reward")
    return batch.set_column(i, "reward", pa.array([str(v) for v in batch.column(i).to_pylist()]))


@pytest.mark.parametrize(
    "edit",
    [
        {"steps": _nulls_in("terminated")},
        {"steps": _reward_as_text},
        {"resets": _nulls_in("env_index")},
        {"episodes": _unknown_outcome},
    ],
    ids=["null flags", "wrong type", "null reset key", "unknown outcome"],
)
def test_a_finished_file_the_reader_refuses_is_refused_not_copied(
    recorded: Path, tmp_path: Path, edit: dict[str, Any]
) -> None:
    """Found by the issue's fuzzing: recover said "already finished: copied unchanged
    (nothing to recover)" and exited 0 on files every other command refused."""
    bad = rewrite(recorded, tmp_path / "bad.mcap", **edit)
    code, _, refused = run("check", str(bad))
    assert code == 2 and str(bad) in refused
    code, out, err = run("recover", str(bad), "-o", str(tmp_path / "out.mcap"))
    assert (code, out, err) == (2, "", refused)  # the same one line as the other commands
    with pytest.raises(CorruptEvidenceError):
        recover(bad, tmp_path / "out.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]  # nothing written


_RECOVER_CHILD = """
import sys, time
from episode_audit import recover
print("go", flush=True)
start = time.perf_counter()
recover(sys.argv[1], sys.argv[2])
print(time.perf_counter() - start, flush=True)
"""


def test_a_killed_recover_leaves_nothing_behind(tmp_path: Path) -> None:
    """Found by the issue's kills: 11 of 20 SIGKILLs left a hidden ``.NAME.XXXX.recovering``.
    The output is written to an unnamed file (O_TMPFILE) linked into place when finished."""
    if not hasattr(os, "O_TMPFILE"):
        pytest.skip("no unnamed files (O_TMPFILE) on this OS: the named temporary remains")
    source = tmp_path / "src"
    source.mkdir()
    path = random_cartpole_file(source / "run.mcap", 2_000, block_steps=4, flush_every_s=3600)
    torn = torn_copy(path, source, path.stat().st_size * 9 // 10)
    out = tmp_path / "out"
    out.mkdir()
    took = how_long(_RECOVER_CHILD, str(torn), str(out / "calibrate.mcap"))
    assert (out / "calibrate.mcap").exists()
    runs = [(str(torn), str(out / f"killed-{n}.mcap")) for n in range(5)]
    assert killed_midway(_RECOVER_CHILD, runs, took / 2) >= 3  # most kills landed mid-recovery
    left = sorted(p.name for p in out.iterdir())
    assert all(name == "calibrate.mcap" or name.startswith("killed-") for name in left), left
    for name in left:  # an output there is whole (published only once finished)
        assert open_evidence(out / name).finished


@pytest.mark.parametrize("overwrite", [False, True])
def test_the_output_has_no_name_until_it_is_published(tmp_path: Path, overwrite: bool) -> None:
    """Where the OS has unnamed files, nothing of a recovery shows in the output's directory
    until the finished file is linked into place (and then only the output)."""
    dst = tmp_path / "out.mcap"
    if overwrite:
        dst.write_bytes(b"old")
    tmp = temporary(dst)
    try:
        assert tmp.unnamed == hasattr(os, "O_TMPFILE")
        tmp.path.write_bytes(b"recovered")
        listing = sorted(p.name for p in tmp_path.iterdir())
        assert listing == (["out.mcap"] if overwrite else []) or not tmp.unnamed
        tmp.publish(overwrite)
    finally:
        tmp.discard()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]
    assert dst.read_bytes() == b"recovered"
    assert dst.stat().st_mode & 0o777 == 0o666 & ~_umask()
    if not overwrite:  # never over an existing file unless asked
        again = temporary(dst)
        try:
            again.path.write_bytes(b"again")
            with pytest.raises(ConfigurationError, match="file exists"):
                again.publish(False)
        finally:
            again.discard()
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_KILLED_BEFORE_ITS_FIRST_FLUSH = """
import os, signal, sys
import gymnasium as gym
from episode_audit import RecordEvidence

env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], flush_every_s=3600)
env.reset(seed=0)
for _ in range(3):
    env.step(0)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_torn_file_with_nothing_to_recover_writes_no_output(tmp_path: Path) -> None:
    """Killed before its first flush: the file holds its run metadata only. No empty copy is
    written (with --overwrite, an existing output is left as it was); one line, exit 2."""
    import signal
    import subprocess
    import sys

    torn = tmp_path / "torn.mcap"
    done = subprocess.run(
        [sys.executable, "-c", _KILLED_BEFORE_ITS_FIRST_FLUSH, str(torn)], timeout=120
    )
    assert done.returncode == -signal.SIGKILL and torn.stat().st_size > 0
    nothing = (
        r"torn\.mcap: nothing to recover: the file holds its run metadata but no episode, "
        r"reset or step \(its recorder was killed before its first flush\); no output was written"
    )
    with pytest.raises(EvidenceError, match=nothing):
        recover(torn, tmp_path / "out.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == [torn.name]  # nothing, no temp file
    code, out, err = run("recover", str(torn), "-o", str(tmp_path / "out.mcap"))
    assert (code, out) == (2, "") and len(err.strip().splitlines()) == 1, err
    assert re.search(nothing, err), err
    kept = tmp_path / "kept.mcap"
    kept.write_bytes(b"an earlier output")
    code, _, err = run("recover", str(torn), "-o", str(kept), "--overwrite")
    assert code == 2 and kept.read_bytes() == b"an earlier output", err
    assert sorted(p.name for p in tmp_path.iterdir()) == [kept.name, torn.name]


def test_a_full_disk_is_one_error_naming_the_output(small_disk: Path, tmp_path: Path) -> None:
    finished = random_cartpole_file(tmp_path / "run.mcap", 2000, block_steps=64)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(finished.read_bytes()[:-100])  # (no footer, no summary: rewritten)
    filler = fill_disk(small_disk)
    for src in (finished, torn):  # copied unchanged; rewritten
        for out in (small_disk / "fixed.mcap", small_disk / "new" / "fixed.mcap"):
            with pytest.raises(
                ConfigurationError,
                match=rf"^{re.escape(str(out))}: cannot write it: No space left on device; "
                "free some space there or choose another output path$",
            ):
                recover(src, out)
            assert sorted(small_disk.iterdir()) == [filler]  # no output, no folder it made
    result = CliRunner().invoke(app, ["recover", str(torn), "-o", str(out)])
    assert result.exit_code == 2 and "Traceback" not in result.output


def test_an_out_a_slash_short_of_a_url_is_one_line_and_writes_nothing(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (it made a local folder "s3:" and wrote the file there)
    monkeypatch.chdir(tmp_path)
    code, out, err = run("recover", str(recorded), "--out", "s3:/bucket/fixed.mcap")
    assert code == 2 and not out
    assert err.strip().splitlines() == [
        "episode-audit: error: --out s3:/bucket/fixed.mcap: a URL takes two slashes: "
        "s3://bucket/fixed.mcap; a local path: ./s3:/bucket/fixed.mcap"
    ]
    assert list(tmp_path.iterdir()) == []


def test_paths_with_spaces_stay_whole_in_the_result(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    torn = torn_copy(recorded, tmp_path, len(recorded.read_bytes()) - 10)
    source = tmp_path / "a run of a longer name.mcap"
    torn.rename(source)
    out = "recovered runs/the run of a longer name, recovered.mcap"
    Path("recovered runs").mkdir()
    result = CliRunner().invoke(app, ["recover", source.name, "-o", out], env={"COLUMNS": "80"})
    assert out in result.output and source.name in result.output, result.output
