"""The run-end record read back: typed values, and "not said" for anything a file could hold."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

from episode_audit import RecordEvidence, check, open_evidence
from episode_audit.format import EpisodeRanges
from episode_audit.format.run_end import RunEnd
from episode_audit.record import file as record_file

DEEP = "[" * 100_000  # (json.loads alone raises RecursionError on it)


def test_a_recorded_file_says_what_it_holds(tmp_path: Path) -> None:
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "run.mcap") as env:
        env.reset(seed=0)
        for _ in range(40):
            *_, terminated, truncated, _ = env.step(0)
            if terminated or truncated:
                env.reset()
    said = RunEnd.of(open_evidence(tmp_path / "run.mcap").run_end)
    assert said.status == "finished" and not said.recovered
    assert said.steps == 40 and said.episodes is not None and said.episodes >= 2
    assert said.troubles == 0 and said.first_trouble is None
    assert said.success_reported == 0
    assert said.cut_off_episodes == frozenset() and said.damaged_stretches == 0


def test_a_recovery_record_is_read() -> None:
    said = RunEnd.of(
        {
            "status": "recovered",
            "episodes": "7",
            "dropped": "a torn tail",
            "cut_off_episodes": "[6, true, 2.5, 5]",
            "damaged": '[{"offset": 1, "length": 2, "why": "crc"}]',
            "damaged_episodes": "[[1, 3]]",
        }
    )
    assert said.recovered and said.episodes == 7 and said.dropped == "a torn tail"
    assert said.cut_off_episodes == frozenset({5, 6})  # (not the bool, not the float)
    assert said.damaged_stretches == 1
    assert said.damaged_episodes == EpisodeRanges.of(spans=[(1, 3)])


# (a fullwidth 3, a superscript 2: str.isdigit takes both; a count is written in ASCII digits)
@pytest.mark.parametrize("value", ["", "-1", "1.5", " 3", "\uff13", "\u00b2", "12a"])
def test_a_count_that_is_not_digits_is_not_said(value: str) -> None:
    said = RunEnd.of({"steps": value, "episodes": value, "success_reported": value})
    assert said.steps is None and said.episodes is None and said.success_reported is None


def test_trouble_without_a_readable_count_happened_once_at_least() -> None:
    assert RunEnd.of({"recorder_trouble": "often"}).troubles == 1
    assert RunEnd.of({"recorder_trouble": "3"}).troubles == 3
    assert RunEnd.of({"recorder_trouble": ""}).troubles == 0


@pytest.mark.parametrize("key", ["damaged", "damaged_episodes", "cut_off_episodes"])
@pytest.mark.parametrize("value", [DEEP, "{not json", '"text"', "x" * (2 << 20)])
def test_json_values_that_do_not_parse_are_not_said(key: str, value: str) -> None:
    said = RunEnd.of({"status": "recovered", key: value})
    assert said.damaged_stretches == 0
    assert said.damaged_episodes == EpisodeRanges()
    assert said.cut_off_episodes == frozenset()


def test_no_record_says_nothing() -> None:
    assert RunEnd.of(None) == RunEnd.of({}) == RunEnd()
    assert not RunEnd().recovered


@pytest.fixture
def deeply_nested(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A file whose run-end record says it was recovered, with JSON nested 100 000 deep."""
    written = record_file.run_end_record

    def run_end(file: record_file.EvidenceFile) -> dict[str, str]:
        keys = ("damaged", "damaged_episodes", "cut_off_episodes")
        return {**written(file), "status": "recovered", **dict.fromkeys(keys, DEEP)}

    monkeypatch.setattr(record_file, "run_end_record", run_end)
    path = tmp_path / "deep.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(0)
    return path


def test_check_reads_a_file_whose_run_end_nests_too_deep(deeply_nested: Path) -> None:
    ev = open_evidence(deeply_nested)
    assert ev.damaged_stretches == 0 and ev.damaged_episodes == EpisodeRanges()
    codes = {f.code for f in check([deeply_nested]).findings}
    assert "file_recovered" in codes


def test_the_command_line_says_it_without_a_traceback(deeply_nested: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "episode_audit", "check", str(deeply_nested)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert "Traceback" not in run.stderr + run.stdout
    assert run.returncode in (0, 1) and "file_recovered" in run.stdout


def test_what_the_recorder_dropped_reads_as_counts_and_words() -> None:
    said = RunEnd.of(
        {
            "recorder_lost_steps": "600",
            "recorder_lost_resets": "12",
            "recorder_lost_episode_records": "13",
        }
    )
    assert (said.lost_steps, said.lost_resets, said.lost_episode_records) == (600, 12, 13)
    assert said.lost == "600 step rows, 12 reset rows and 13 episode records"
    assert RunEnd.of({"recorder_lost_steps": "0", "recorder_lost_resets": "1"}).lost == (
        "1 reset row"
    )
    # nothing dropped, or counts that do not parse: nothing said
    assert RunEnd.of({"recorder_lost_steps": "0"}).lost is None
    assert RunEnd.of({"recorder_lost_steps": "-3", "recorder_lost_resets": DEEP}).lost is None
