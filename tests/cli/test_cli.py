from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.cli import app
from episode_audit.report.core import BY_LABEL_NOTE as REPORT_BY_LABEL_NOTE
from tests.support.rewards import record_cartpole

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures"
GOLDEN = Path(__file__).resolve().parent / "golden"
runner = CliRunner()


@pytest.fixture(autouse=True)
def _in_repo(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO)


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def cartpole(path: Path, episodes: int = 3, **kwargs: object) -> Path:
    with RecordEvidence(gym.make("CartPole-v1", **kwargs), path) as env:
        env.action_space.seed(0)
        for e in range(episodes):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    return path


def test_help_and_version() -> None:
    code, out, _ = run("--help")
    assert code == 0
    for command in ("check", "replay", "report", "show", "export", "record"):
        assert command in out
    code, out, _ = run("--version")
    assert code == 0 and out.startswith("episode-audit ")


@pytest.mark.parametrize(
    "command", ["check", "replay", "report", "show", "export", "record", "recover"]
)
def test_help_names_option_values_not_python_types(command: str) -> None:
    """Options read ``--episode <int>`` and ``--tag <key=value>``, not ``<list[int]>``."""
    code, out, _ = run(command, "--help")
    assert code == 0
    options = out[out.index("Options:") :]
    assert "<list[" not in options, options


def test_check_terms_that_do_not_sum_exit_1_and_name_the_step() -> None:
    code, out, _ = run("check", "fixtures/terms_mismatch.mcap", "--format", "json")
    assert code == 1
    data = json.loads(out)
    (finding,) = [f for f in data["findings"] if f["code"] == "terms_sum_mismatch"]
    assert (finding["episode"], finding["step"]) == (1, 3)
    code, out, _ = run("check", "fixtures/terms_mismatch.mcap")
    assert code == 1 and "terms_sum_mismatch" in out and "step 3" in out


def test_check_clean_file_exit_0() -> None:
    code, out, _ = run("check", "fixtures/clean.mcap")
    assert code == 0, out


def test_check_strict_fails_on_warnings() -> None:
    code, _, _ = run("check", "fixtures/torn.mcap")
    assert code == 0
    code, _, _ = run("check", "fixtures/torn.mcap", "--strict")
    assert code == 1
    # CartPole labels no failure and reports no terms: notes, which --strict lets pass
    code, out, _ = run("check", "fixtures/unlabeled_failure.mcap", "--strict")
    assert code == 0, out
    assert out.strip().endswith("0 error(s), 0 warning(s), 2 note(s)"), out


def test_check_ignore_leaves_findings_out_of_output_and_exit_code() -> None:
    code, out, _ = run("check", "fixtures/terms_mismatch.mcap", "--format", "json")
    assert code == 1
    before = json.loads(out)
    mismatches = [f for f in before["findings"] if f["code"] == "terms_sum_mismatch"]
    assert mismatches and before["ignored"] == 0
    code, out, _ = run(
        "check", "fixtures/terms_mismatch.mcap", "--ignore", "terms_sum_mismatch", "-f", "json"
    )
    assert code == 0
    data = json.loads(out)
    assert data["ok"] is True and data["ignored"] == len(mismatches)
    assert all(f["code"] != "terms_sum_mismatch" for f in data["findings"])
    assert data["counts"]["error"] == before["counts"]["error"] - len(mismatches)
    # --strict: the warnings left fail; ignored too, they do not
    args = ["check", "fixtures/torn.mcap", "--strict"]
    assert run(*args)[0] == 1
    code, out, _ = run(*args, "--ignore", "file_unfinished", "--ignore", "incomplete_episode")
    assert code == 0
    assert out.strip().endswith("0 error(s), 0 warning(s), 2 note(s), 2 ignored"), out
    for fmt in ("table", "markdown"):
        _, out, _ = run("check", "fixtures/clean.mcap", "-f", fmt)
        assert "ignored" not in out, fmt


def test_check_ignore_of_an_unknown_code_is_a_usage_error_listing_the_known_ones() -> None:
    from episode_audit.check import FINDING_CODES

    code, out, err = run("check", "fixtures/terms_mismatch.mcap", "--ignore", "terms_mismatch")
    assert code == 2 and out == ""
    one_error_line(
        err,
        "--ignore: unknown finding code 'terms_mismatch'; known codes: "
        + ", ".join(FINDING_CODES)
        + " (recorder_note for every recorder note, recorder_note:<code> for one)",
    )


def test_unreadable_file_exit_2_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    for command in ("check", "report", "replay", "show"):
        code, _, err = run(command, str(bad))
        assert code == 2, command
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "bad.mcap" in lines[0] and "Traceback" not in err
    code, _, err = run("check", str(tmp_path / "missing.mcap"))
    assert code == 2 and "no such file" in err


def test_output_not_to_a_terminal_is_200_columns_unless_columns_says(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    args = ("check", "fixtures/torn.mcap")  # (a finding whose message is long)
    _, wide, _ = run(*args)  # (no COLUMNS: tests/conftest.py)
    assert max(map(len, wide.splitlines())) == 200
    monkeypatch.setenv("COLUMNS", "80")
    code, out, _ = run(*args)
    assert code == 0 and max(map(len, out.splitlines())) <= 80
    assert "file_unfinished" in out


def test_torn_file_check_reports_unfinished_and_report_counts_episodes() -> None:
    code, out, _ = run("check", "fixtures/torn.mcap", "--format", "json")
    assert code == 0
    codes = {f["code"] for f in json.loads(out)["findings"]}
    assert "file_unfinished" in codes
    code, out, _ = run("report", "fixtures/torn.mcap", "--format", "json")
    assert code == 0
    (group,) = json.loads(out)["groups"]
    assert group["episodes"] >= 2 and group["incomplete"] == 1
    assert group["ended"] == group["episodes"] - 1


def test_a_torn_file_that_holds_nothing_fails_check_and_report_says_so(tmp_path: Path) -> None:
    """The first 1500 bytes of a finished file: run metadata, no chunk. check exited 0 with a
    warning and report printed only "No episodes"."""
    path = tmp_path / "early.mcap"
    path.write_bytes((FIXTURES / "clean.mcap").read_bytes()[:1500])
    code, out, _ = run("check", str(path), "--format", "json")
    (finding,) = json.loads(out)["findings"]
    assert code == 1 and (finding["severity"], finding["code"]) == ("error", "file_unfinished")
    code, out, _ = run("report", str(path))
    assert code == 0 and out.startswith("No episodes")
    assert "Unfinished files (still being written, or torn)" in out
    assert "no episode survives" in " ".join(out.split())
    code, out, _ = run("report", str(path), "--format", "json")
    (unfinished,) = json.loads(out)["unfinished"]
    assert unfinished["why"].endswith(
        "; no recorder is writing it and it holds no complete chunk: no episode survives"
    )


def test_directories_are_searched(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    shutil.copy(FIXTURES / "clean.mcap", tmp_path / "sub" / "a.mcap")
    shutil.copy(FIXTURES / "unlabeled_failure.mcap", tmp_path / "b.mcap")
    code, out, _ = run("report", str(tmp_path), "--format", "json")
    assert code == 0
    assert len(json.loads(out)["groups"]) == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = run("check", str(empty))
    assert code == 2 and "no *.mcap files" in err


def test_replay_identical_exit_0(tmp_path: Path) -> None:
    path = cartpole(tmp_path / "cp.mcap")
    code, out, _ = run("replay", str(path))
    assert code == 0, out
    assert "3 identical, 0 diverged, 0 not replayable" in out


def test_replay_of_a_changed_env_exit_1_names_step_and_field(tmp_path: Path) -> None:
    path = cartpole(tmp_path / "cp.mcap")
    code, out, _ = run(
        "replay", str(path), "--env-factory", "tests.support.factories:heavy_cartpole"
    )
    assert code == 1
    assert "step 0: observation expected" in out
    assert "0 identical, 3 diverged" in out


def test_replay_lists_not_replayable_episodes_sharing_a_reason_in_one_row(
    tmp_path: Path,
) -> None:
    gym.register("NotRegistered-v0", entry_point="gymnasium.envs.classic_control:CartPoleEnv")
    try:
        with RecordEvidence(gym.make("NotRegistered-v0"), tmp_path / "u.mcap") as env:
            for e in range(7):
                env.reset(seed=e)
                env.step(0)
    finally:
        del gym.registry["NotRegistered-v0"]
    code, out, err = run("replay", str(tmp_path / "u.mcap"), "--format", "markdown")
    assert code == 1 and "replay verified no episode" in err
    rows = [line for line in out.splitlines() if "not_replayable" in line]
    assert len(rows) == 1 and "| 0, 1, 2, 3, 4 and 2 more |" in rows[0], out
    assert "'NotRegistered-v0' is not registered in this process" in rows[0]


def test_replay_bad_factory_is_a_usage_error(tmp_path: Path) -> None:
    path = cartpole(tmp_path / "cp.mcap", episodes=1)
    code, _, err = run("replay", str(path), "--env-factory", "nocolon")
    assert code == 2 and "MODULE:CALLABLE" in err
    code, _, err = run("replay", str(path), "--import", "no_such_module_for_test")
    assert code == 2 and "no_such_module_for_test" in err


def test_report_gates_missed_and_held() -> None:
    code, out, _ = run("report", "fixtures/clean.mcap", "--min-success-rate", "0.95")
    assert code == 1 and "FAIL" in out
    code, out, _ = run(
        "report", "fixtures/clean.mcap", "--min-success-rate", "0.5", "--max-truncation-rate", "0.5"
    )
    assert code == 0, out
    code, out, _ = run(
        "report", "fixtures/unlabeled_failure.mcap", "--max-failure-rate", "unlabeled=0.1"
    )
    assert code == 1
    code, _, err = run("report", "fixtures/clean.mcap", "--max-failure-rate", "x=2")
    assert code == 2 and "between 0 and 1" in err
    code, _, err = run("report", "fixtures/clean.mcap", "--by", "colour")
    assert code == 2 and "--by" in err


def test_report_by_label_takes_no_gates_and_says_why_it_has_no_rates() -> None:
    # a failure label's group had a success rate of 0 by construction, so this exited 1
    args = ("report", "fixtures/unlabeled_failure.mcap", "--by", "label")
    for gate in (["--min-success-rate", "0.5"], ["--fail-on-incentive-warning"]):
        code, out, err = run(*args, *gate)
        assert (code, out) == (2, "")
        one_error_line(err, "gates: expected a grouping whose groups can hold several")
    code, out, err = run(*args, "--format", "json")
    assert code == 0, err
    data = json.loads(out)
    assert all(g["success_rate"] is None and g["warnings"] == [] for g in data["groups"])
    assert data["notes"] == [REPORT_BY_LABEL_NOTE]
    assert f"episode-audit: warning: {REPORT_BY_LABEL_NOTE}" in err


def test_report_of_files_with_no_stepped_episode_says_so_in_one_line(tmp_path: Path) -> None:
    # (a reset, then close: the terminal showed an empty table under a wrapped title)
    path = tmp_path / "unstarted.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    env.reset(seed=0)
    env.close()
    line = "No episodes: none in these files took a step (only those are counted).\n"
    code, out, _ = run("report", str(path))
    assert (code, out) == (0, line)
    code, out, _ = run("report", str(path), "--format", "markdown")
    assert code == 0 and out.endswith("\n" + line + "\n")
    code, out, _ = run("report", str(path), "--min-success-rate", "0.5")
    assert code == 1 and out.startswith(line) and "no gate could be checked" in out


def test_report_says_once_in_each_format_when_returns_are_a_reward_wrappers(
    tmp_path: Path,
) -> None:
    plain = str(record_cartpole(tmp_path / "plain.mcap"))
    scaled = str(record_cartpole(tmp_path / "scaled.mcap", "scaled"))
    note = "1/2 files' returns are not the env's: TransformReward"
    code, out, err = run("report", plain, scaled, "--by", "all", "--no-step-summary")
    assert code == 0 and note not in err
    assert [line.rstrip() for line in out.splitlines()].count(note) == 1
    assert out.index("Outcomes") < out.index(note) < out.index("Failure labels")
    code, out, _ = run("report", plain, scaled, "-f", "markdown", "--no-step-summary")
    assert out.count(note) == 1
    code, out, _ = run("report", plain, scaled, "-f", "json")
    assert json.loads(out)["reward_wrappers"] == [{"wrappers": ["TransformReward"], "files": 1}]
    gate = ("--by", "all", "--max-truncation-rate", "1")
    code, out, _ = run("report", plain, scaled, *gate, "-f", "junit", "--no-step-summary")
    assert code == 0 and out.count(note) == 1  # (in the gate case's details)


def test_report_never_folds_flags_into_done() -> None:
    for fmt in ("table", "markdown", "json"):
        _, out, _ = run("report", "fixtures/clean.mcap", "--format", fmt)
        assert "done" not in out.lower()


@pytest.mark.parametrize("fmt", ["table", "markdown", "junit"])
def test_report_intervals_are_in_the_rates_unit(fmt: str) -> None:
    # a rate printed as "83.3% [0.44, 0.97]" mixed a percent and fractions
    code, out, _ = run(
        "report", "fixtures/clean.mcap", "--min-success-rate", "0.5", "--format", fmt
    )
    assert code == 0, out
    assert "83.3% [43.6, 97.0]" in out and "16.7% [3.0, 56.4]" in out
    assert not re.search(r"\[[01]\.\d\d, ", out)  # no fraction left
    code, out, _ = run("report", "fixtures/clean.mcap", "--format", "json")
    ci = json.loads(out)["groups"][0]["success_ci"]  # JSON keeps fractions
    assert (round(ci["low"], 3), round(ci["high"], 3)) == (0.436, 0.970)


@pytest.mark.parametrize("fmt", ["markdown", "json"])
def test_report_golden_output(fmt: str) -> None:
    code, out, _ = run("report", "fixtures/clean.mcap", "--by", "tag:policy", "--format", fmt)
    assert code == 0
    golden = GOLDEN / f"report_clean.{'md' if fmt == 'markdown' else 'json'}"
    assert out == golden.read_text(), f"regenerate {golden} if the change is intended"


def test_show_summary_and_episode() -> None:
    code, out, _ = run("show", "fixtures/clean.mcap", "--format", "json")
    assert code == 0
    data = json.loads(out)
    assert data["finished"] is True and data["episodes"] == 6
    code, out, _ = run(
        "show", "fixtures/clean.mcap", "--episode", "4", "--steps", "115:", "--format", "json"
    )
    assert code == 0
    data = json.loads(out)
    assert [row[0] for row in data["rows"]] == list(range(115, 120))
    assert data["rows"][-1][data["columns"].index("outcome")] == "truncated (time_limit)"
    # JSON holds the values themselves, as the file does (not the table's display text)
    steps = open_evidence("fixtures/clean.mcap").episode(4).steps.slice(115).to_pylist()
    for row, step in zip(data["rows"], steps, strict=True):
        cells = dict(zip(data["columns"], row, strict=True))
        assert cells["reward"] == step["reward"] and isinstance(cells["reward"], float)
        assert {k: cells[k] for k in dict(step["terms"])} == dict(step["terms"])
        assert cells["notes"] == [] and cells["terminated"] is step["terminated"]
    record = open_evidence("fixtures/clean.mcap").episode(4).record
    assert data["episode"]["term_totals"] == dict(record["term_totals"])
    code, out, _ = run("show", "fixtures/clean.mcap", "--episode", "0", "--steps", "0:3")
    assert code == 0 and "shaping" in out
    code, _, err = run("show", "fixtures/clean.mcap", "--steps", "0:3")
    assert code == 2 and "--episode" in err
    code, _, err = run("show", "fixtures/clean.mcap", "--episode", "99")
    assert code == 2 and "no episode 99" in err


SHOW_JSON_KEYS = [  # the summary's keys before the episode list and the spaces' shapes
    "file", "finished", "torn", "recovered", "format_version", "writer", "env_id", "start_time",
    "tags", "episodes", "steps", "outcomes", "observation_space", "action_space", "reward_terms",
    "versions", "platform", "command_line", "env_spec", "layout",
]  # fmt: skip


def test_show_and_check_count_the_episodes_report_counts(tmp_path: Path) -> None:
    """One CartPole episode, then a reset never stepped: show said ``episodes 2`` (``incomplete
    1``) and check ``2 episodes`` where report counts 1 (docs/reporting.md: unstarted)."""
    path = tmp_path / "unstarted.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        while not any(env.step(0)[2:4]):
            pass
        env.reset(seed=1)
    code, out, _ = run("report", str(path), "-f", "json")
    (group,) = json.loads(out)["groups"]
    assert code == 0 and (group["episodes"], group["incomplete"]) == (1, 0)
    code, out, _ = run("show", str(path), "-f", "json")
    data = json.loads(out)
    assert (data["episodes"], data["outcomes"]["incomplete"], data["unstarted"]) == (1, 0, 1)
    assert [e["episode"] for e in data["episode_list"]] == [0]
    code, out, _ = run("show", str(path))
    lines = [" ".join(line.split()) for line in out.splitlines()]
    assert "episodes 1" in lines
    assert "unstarted 1 (reset and never stepped: not counted, as in report)" in lines
    assert "outcomes success 0, failure 1, truncated 0, incomplete 0, error 0" in lines
    code, out, _ = run("check", str(path), "-f", "json", "--no-step-summary")
    data = json.loads(out)
    assert data["episodes"] == 1 and "incomplete_episode" not in out
    code, out, _ = run("check", str(path), "--no-step-summary")
    assert out.splitlines()[-1].startswith("1 file(s), 1 episode, ")
    show_clean = json.loads(run("show", "fixtures/clean.mcap", "-f", "json")[1])
    assert show_clean["unstarted"] == 0  # (the key is always there)


def test_show_summary_lists_episodes_and_spaces_with_shape_and_dtype() -> None:
    code, out, _ = run("show", "fixtures/clean.mcap")
    assert code == 0
    lines = [" ".join(line.split()) for line in out.splitlines()]
    assert "observation space Box(shape=(11,), dtype=float64)" in lines
    assert "action space Box(shape=(3,), dtype=float32)" in lines
    start = lines.index("episode outcome label / reason length return")
    assert lines[start + 2 : start + 8] == [
        "0 success - 65 11.5",
        "1 success - 66 11.5",
        "2 success - 65 11.5",
        "3 success - 67 11.6",
        "4 truncated time_limit 120 1.3",
        "5 success - 64 11.4",
    ]
    code, out, _ = run("show", "fixtures/torn.mcap", "--format", "markdown")
    assert code == 0
    assert "| action space | Discrete(n=2, shape=(), dtype=int64) |" in out
    assert "| 11 | incomplete | - | 14 | 14 |" in out  # 12 episodes: every one listed
    # JSON: the keys it had, in their order, then the new ones
    code, out, _ = run("show", "fixtures/torn.mcap", "--format", "json")
    data = json.loads(out)
    assert list(data)[: len(SHOW_JSON_KEYS)] == SHOW_JSON_KEYS
    assert data["observation_space"] == "Box" and data["action_space"] == "Discrete"
    assert (data["observation_shape"], data["observation_dtype"]) == ([4], "float32")
    assert (data["action_shape"], data["action_dtype"]) == ([], "int64")
    assert data["episode_list_omitted"] == 0 and len(data["episode_list"]) == 12
    assert data["episode_list"][0] == {
        "episode": 0,
        "env_index": 0,
        "agent": None,
        "outcome": "failure",
        "label": "unlabeled",
        "length": 18,
        "return": 18.0,
    }
    assert data["observation_digest_min_bytes"] is None


def test_show_says_which_observations_are_stored_as_digests(tmp_path: Path) -> None:
    path = tmp_path / "digests.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path, digest_min_bytes=16) as env:
        env.reset(seed=0)
        env.step(0)
    code, out, _ = run("show", str(path), "--format", "markdown")
    assert code == 0
    assert (
        "| observation space | Box(shape=(4,), dtype=float32); arrays of 16 bytes or more stored "
        "as 16-byte BLAKE2b digests (replay compares them, show and export cannot give their "
        "values) |"
    ) in out
    code, out, _ = run("show", str(path), "--format", "json")
    assert json.loads(out)["observation_digest_min_bytes"] == 16


class _SequenceActions(gym.Env[Any, Any]):
    """Actions of a space stored as JSON text (a Sequence)."""

    observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    action_space = gym.spaces.Sequence(gym.spaces.Discrete(3))

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        return np.zeros(2, np.float32), {}

    def step(self, action: Any) -> Any:
        return np.zeros(2, np.float32), 0.0, False, False, {}


def test_show_gives_actions_their_space_cannot_rebuild_as_stored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "sequence.mcap"
    with RecordEvidence(_SequenceActions(), path) as env:
        env.reset(seed=0)
        env.step((1, 2))
    code, out, _ = run("show", str(path), "--episode", "0", "--format", "json")
    assert code == 0 and json.loads(out)["rows"][0][1] == [1, 2]

    def refuse(self: Any, sample_n: Any) -> Any:
        raise KeyError("not a value of this space")

    monkeypatch.setattr(gym.spaces.Sequence, "from_jsonable", refuse)
    code, out, err = run("show", str(path), "--episode", "0", "--format", "json")
    assert code == 0 and "Traceback" not in err
    assert json.loads(out)["rows"][0][1] == "[1, 2]"  # (the stored JSON text)


def test_show_summary_of_a_long_file_lists_the_first_and_last_episodes(tmp_path: Path) -> None:
    path = cartpole(tmp_path / "long.mcap", episodes=20, max_episode_steps=3)
    code, out, _ = run("show", str(path))
    assert code == 0
    lines = [" ".join(line.split()) for line in out.splitlines()]
    title = lines.index("Episodes (first 5 and last 5 of 20)")
    episodes = lines[title + 4 : lines.index("", title + 4)]
    assert [row.split()[0] for row in episodes] == [*"01234", "…", *map(str, range(15, 20))]
    assert episodes[5] == "… 10 more (--all-episodes)"
    assert episodes[0] == "0 truncated time_limit 3 3"
    code, out, _ = run("show", str(path), "--format", "json")
    data = json.loads(out)
    assert data["episode_list_omitted"] == 10
    assert [e["episode"] for e in data["episode_list"]] == [0, 1, 2, 3, 4, *range(15, 20)]
    code, out, _ = run("show", str(path), "--all-episodes", "--format", "json")
    data = json.loads(out)
    assert data["episode_list_omitted"] == 0
    assert [e["episode"] for e in data["episode_list"]] == list(range(20))
    code, out, _ = run("show", str(path), "--all-episodes", "--format", "markdown")
    assert code == 0 and "more |" not in out and "| 10 | truncated | time_limit | 3 | 3 |" in out
    code, _, err = run("show", str(path), "--all-episodes", "--episode", "0")
    assert code == 2
    one_error_line(
        err, "--all-episodes lists the episodes of the file summary; not with --episode N"
    )


class LongKwargs(gym.Env[np.ndarray, np.int64]):
    """A registered env whose spec holds a long kwarg (a path, a config string)."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, config: str = "") -> None:
        self.config = config

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action: Any) -> Any:
        return np.zeros(1, np.float32), 0.0, True, False, {}


gym.register("EpisodeAuditLongKwargs-v0", entry_point=LongKwargs)


def test_show_prints_the_env_spec_within_the_width_and_whole_in_json(tmp_path: Path) -> None:
    """The spec was one JSON text printed unbroken: CartPole's ``vector_entry_point`` line was
    83 columns wide at 80. Now a table, each value as JSON, a long one broken after a ``/``,
    ``:`` or ``.``; ``--format json`` gives the spec whole."""
    config = "/data/" + "very-long-folder-name/" * 8 + "config.yaml"
    path = tmp_path / "long.mcap"
    with RecordEvidence(gym.make("EpisodeAuditLongKwargs-v0", config=config), path) as env:
        env.reset(seed=0)
        env.step(0)
    cartpole_file = cartpole(tmp_path / "cartpole.mcap", episodes=1)
    for file, value in ((path, json.dumps({"config": config})), (cartpole_file, None)):
        result = runner.invoke(app, ["show", str(file)], env={"COLUMNS": "80"})
        assert result.exit_code == 0
        lines = result.stdout.splitlines()
        assert max(len(line) for line in lines) <= 80, result.stdout
        if value is not None:  # the kwargs row and the lines it continues on, read in order
            start = next(i for i, line in enumerate(lines) if line.split()[:1] == ["kwargs"])
            pieces = [lines[start].split(maxsplit=1)[1].strip()]
            for line in lines[start + 1 :]:
                if not line.strip() or line[1:2] != " ":
                    break
                pieces.append(line.strip())
            assert "".join(pieces) == value.replace(" ", ""), pieces  # (wrapped at its space)
            assert all(p.endswith(("/", ":")) for p in pieces[:-1]), pieces
    (row,) = [line for line in lines if "vector_entry_point" in line]
    assert row.split()[1:] == ['"gymnasium.envs.classic_control.cartpole:']
    code, out, _ = run("show", str(path), "-f", "json")
    assert code == 0 and json.loads(out)["env_spec"]["kwargs"] == {"config": config}


@pytest.mark.parametrize(
    ("description", "text"),
    [
        ({"type": "MultiDiscrete", "nvec": [[2, 3]], "start": [[0, 0]], "dtype": "int64"},
         "MultiDiscrete(shape=(1, 2), dtype=int64)"),
        ({"type": "MultiBinary", "n": 4}, "MultiBinary(shape=(4,), dtype=int8)"),
        ({"type": "Text", "min_length": 1, "max_length": 8, "charset": "ab"},
         "Text(1, 8, charset=ab)"),
        ({"type": "Tuple", "spaces": [{"type": "Discrete", "n": 2, "start": 0, "dtype": "int64"}]},
         "Tuple(Discrete(n=2, shape=(), dtype=int64))"),
        ({"type": "Custom", "class": "a.B", "repr": "B()"}, "Custom(a.B)"),
        ({"type": "Box", "shape": "x", "dtype": 3}, "Box(?)"),  # from a bad file
        ({"type": "Dict", "spaces": [["a"], 7]}, "Dict(?)"),
        ({}, "?"),
    ],
)  # fmt: skip
def test_space_text_of_every_kind_of_space(description: dict[str, object], text: str) -> None:
    from episode_audit.cli.render.show import space_text

    assert space_text(description) == text


def test_export_reads_back_with_pyarrow_and_pandas(tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    code, out, _ = run(
        "export", "fixtures/clean.mcap", "fixtures/unlabeled_failure.mcap", "--out", str(out_dir)
    )
    assert code == 0, out
    steps = pq.read_table(out_dir / "clean.steps.parquet")
    assert set(steps.column("file").to_pylist()) == {"fixtures/clean.mcap"}
    episodes = pd.read_parquet(out_dir / "episodes.parquet")
    assert len(episodes) == 9
    assert set(episodes["file"]) == {"fixtures/clean.mcap", "fixtures/unlabeled_failure.mcap"}
    frame = pd.read_parquet(out_dir / "unlabeled_failure.steps.parquet")
    assert len(frame) == int(
        episodes[episodes["file"] == "fixtures/unlabeled_failure.mcap"]["length"].sum()
    )
    code, _, err = run("export", "fixtures/clean.mcap", "--out", str(out_dir))
    assert code == 2 and "--overwrite" in err


def test_record_any_registered_env(tmp_path: Path) -> None:
    out = tmp_path / "rec.mcap"
    code, stdout, _ = run(
        "record",
        "CartPole-v1",
        "--episodes",
        "3",
        "--seed",
        "7",
        "--out",
        str(out),
        "--max-episode-steps",
        "10",
        "--tag",
        "checkpoint=42",
    )
    assert code == 0, stdout
    assert "recorded 3 episodes" in stdout
    code, out_json, _ = run("show", str(out), "--format", "json")
    data = json.loads(out_json)
    assert data["tags"] == {"policy": "random", "checkpoint": "42"}
    code, _, err = run("record", "NoSuchEnv-v9", "--out", str(tmp_path / "x.mcap"))
    assert code == 2 and "NoSuchEnv-v9" in err
    code, _, err = run("record", "CartPole-v1", "--out", str(out))
    assert code == 2 and "never overwritten" in err
    code, _, err = run(
        "record", "CartPole-v1", "--out", str(tmp_path / "y.mcap"), "--env-kwargs", "{"
    )
    assert code == 2 and "--env-kwargs" in err


def test_hostile_strings_print_literally(tmp_path: Path) -> None:
    import numpy as np

    from tests.support.envs import ScriptedEnv

    env = ScriptedEnv(
        step_fn=lambda e, a: (
            np.zeros(2, np.float32),
            1.0,
            True,
            False,
            {"failure": "[red]x[/red]\x1b[31m"},
        )
    )
    path = tmp_path / "hostile.mcap"
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        rec.step(0)
    _, out, _ = run("report", str(path), "--by", "label")
    assert "[red]x[/red]\\x1b[31m" in out
    assert "\x1b" not in out


# ------------------------------------------------------------------- bad arguments (a CLI audit)


def test_record_counts_one_episode_in_the_singular(tmp_path: Path) -> None:
    """It said ``recorded 1 episodes (1 steps)``."""
    out = tmp_path / "one.mcap"
    code, stdout, _ = run(
        "record", "CartPole-v1", "--out", str(out), "--episodes", "1", "--max-episode-steps", "1"
    )
    assert code == 0 and stdout.startswith(f"recorded 1 episode (1 step) to {out}: "), stdout


def test_links_in_a_folder_that_lead_nowhere_are_unreadable_inputs(tmp_path: Path) -> None:
    # they were skipped without a word (exit 0), and the linked folder was not searched
    (tmp_path / "real").mkdir()
    (tmp_path / "top").mkdir()
    shutil.copy(FIXTURES / "clean.mcap", tmp_path / "real" / "a.mcap")
    shutil.copy(FIXTURES / "clean.mcap", tmp_path / "top" / "b.mcap")
    os.symlink("../real", tmp_path / "top" / "linked")
    os.symlink("../real/gone.mcap", tmp_path / "top" / "dangling.mcap")
    os.symlink("loop.mcap", tmp_path / "top" / "loop.mcap")
    top = tmp_path / "top"
    code, out, err = run("check", str(top), "-f", "json")
    assert code == 2
    assert err.splitlines() == [
        f"episode-audit: error: {top}/dangling.mcap: cannot open: broken symbolic link (to "
        "../real/gone.mcap, which does not exist)",
        f"episode-audit: error: {top}/loop.mcap: cannot open: symbolic link loop",
    ]
    data = json.loads(out)
    assert data["files"] == [str(top / n) for n in ("b.mcap", "dangling.mcap", "linked/a.mcap",
                                                    "loop.mcap")]  # fmt: skip
    assert [u["file"] for u in data["unreadable"]] == [str(top / "dangling.mcap"),
                                                       str(top / "loop.mcap")]  # fmt: skip
    code, _, err = run("show", str(top / "loop.mcap"))  # (it said "no such file or directory")
    assert code == 2
    one_error_line(err, f"{top}/loop.mcap: symbolic link loop")


def one_error_line(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("episode-audit: error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--policy", "nonsense"], "--policy: expected random, scripted, hacker"),
        (["--policy", "scripted"], "--policy scripted: policy 'scripted' plays only the"),
        (
            ["--policy", "tests.support.factories:no_such"],
            "cannot load 'tests.support.factories:no_such'",
        ),
        (["--seed", "-1"], "--seed: expected 0 <= seed"),
        (["--seed", str(2**64 - 1)], "--seed: expected 0 <= seed"),
        (["--max-episode-steps", "0"], "--max-episode-steps: expected at least 1, got 0"),
        (["--import", ""], "--import '': ValueError: Empty module name"),
        (["--env-kwargs", '{"render_mode": 3}'], "cannot make 'CartPole-v1' with"),
    ],
)
def test_a_record_usage_error_touches_no_file(
    tmp_path: Path, args: list[str], message: str
) -> None:
    """Found before the file is opened: no file left behind, none replaced (--overwrite)."""
    fresh = tmp_path / "fresh.mcap"
    code, _, err = run("record", "CartPole-v1", "--out", str(fresh), "--episodes", "1", *args)
    assert code == 2 and not fresh.exists()
    one_error_line(err, message)
    kept = shutil.copy(FIXTURES / "clean.mcap", tmp_path / "kept.mcap")
    before = Path(kept).read_bytes()
    code, _, _ = run("record", "CartPole-v1", "--out", str(kept), "--overwrite", *args)
    assert code == 2 and Path(kept).read_bytes() == before


def test_argument_values_outside_their_range_are_usage_errors(tmp_path: Path) -> None:
    clean = "fixtures/clean.mcap"
    huge = str(2**80)
    for args, message in [
        (["replay", clean, "--atol", "nan"], "--atol: expected a finite number >= 0, got nan"),
        (["replay", clean, "--atol", "inf"], "--atol: expected a finite number >= 0, got inf"),
        (
            ["replay", clean, "-e", huge],
            f"--episode: expected an episode index from 0 to 2**63 - 1, got {huge}",
        ),
        (
            ["show", clean, "-e", huge],
            f"--episode: expected an episode index from 0 to 2**63 - 1, got {huge}",
        ),
        (["check", clean, clean, "--atol", "-1"], "atol: expected a finite number >= 0"),
        (["report", clean, "--max-failure-rate", "=0.1"], "got '=0.1' (no label)"),
        (["report", clean, "--games"], "fixtures/clean.mcap is a single-env file (drop --games)"),
        (["export", clean, "--out", clean], "clean.mcap: not a directory; --out names"),
    ]:
        code, out, err = run(*args)
        assert code == 2, args
        one_error_line(err, message)
    # an episode index no file has: the (empty) result, then the error
    code, out, err = run("replay", clean, "-e", "99")
    assert code == 2 and "0 identical" in out
    one_error_line(err, "--episode: no episode 99 in the file(s) given")


def test_a_file_given_twice_counts_once(tmp_path: Path) -> None:
    clean = FIXTURES / "clean.mcap"
    (tmp_path / "d").mkdir()
    shutil.copy(clean, tmp_path / "d" / "clean.mcap")
    copy = tmp_path / "d" / "clean.mcap"
    code, out, _ = run("report", str(copy), str(tmp_path / "d"), "--by", "all", "-f", "json")
    assert code == 0
    (group,) = json.loads(out)["groups"]
    assert group["episodes"] == open_evidence(clean).episodes().num_rows
    code, out, _ = run("check", str(copy), str(copy), "-f", "json")
    assert json.loads(out)["files"] == [str(copy)]


def test_check_json_names_an_unreadable_file_and_is_not_ok(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    code, out, err = run("check", "fixtures/clean.mcap", str(bad), "-f", "json")
    assert code == 2
    one_error_line(err, str(bad))
    data = json.loads(out)
    assert data["ok"] is False and data["files"] == ["fixtures/clean.mcap", str(bad)]
    (finding,) = [f for f in data["findings"] if f["code"] == "file_unreadable"]
    assert finding["severity"] == "error" and finding["file"] == str(bad)


def test_report_json_never_says_passed_when_an_input_was_not_read(tmp_path: Path) -> None:
    """Before: ``"passed": true`` beside an unreadable input, and exit 2."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    gate = ("--min-success-rate", "0.1")  # that the clean file passes
    for inputs, code, passed in [
        (["fixtures/clean.mcap"], 0, True),
        (["fixtures/clean.mcap", str(bad)], 2, False),
        ([str(bad)], 2, False),
    ]:
        got, out, err = run("report", *inputs, *gate, "-f", "json")
        assert (got, json.loads(out)["passed"]) == (code, passed), err


@pytest.mark.parametrize("command", ["check", "replay", "report"])
def test_json_names_the_unreadable_inputs_as_stderr_does(tmp_path: Path, command: str) -> None:
    """Before: one stderr line per unreadable input and exit 2, but the JSON did not name them."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    torn = tmp_path / "early.mcap"  # torn before its run metadata
    torn.write_bytes((FIXTURES / "clean.mcap").read_bytes()[:200])
    # (replay: a CartPole file, whose steps no library version changes; MuJoCo's may differ)
    good = "fixtures/unlabeled_failure.mcap" if command == "replay" else "fixtures/clean.mcap"
    code, out, err = run(command, good, str(bad), str(torn), "-f", "json")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith("episode-audit: error: ") for line in lines)
    unreadable = json.loads(out)["unreadable"]
    assert [u["file"] for u in unreadable] == [str(bad), str(torn)]
    for entry, line in zip(unreadable, lines, strict=True):
        assert line == f"episode-audit: error: {entry['file']}: {entry['why']}"
    assert unreadable[0]["why"].startswith("not an MCAP file"), unreadable
    code, out, err = run(command, good, "-f", "json")
    assert code == 0 and err == "" and json.loads(out)["unreadable"] == []
    # nothing readable at all: still one JSON document, naming them (exit 2)
    code, out, err = run(command, str(bad), "-f", "json")
    assert code == 2 and [u["file"] for u in json.loads(out)["unreadable"]] == [str(bad)]
    # (a table has nothing to show: only the error line)
    code, out, err = run(command, str(bad))
    assert code == 2 and len(err.strip().splitlines()) == 1
    if command == "report":
        assert out == ""


def test_export_says_an_input_is_unfinished(tmp_path: Path) -> None:
    code, out, err = run("export", "fixtures/torn.mcap", "--out", str(tmp_path / "out"))
    assert code == 0 and "wrote" in out
    assert err.startswith("episode-audit: note: fixtures/torn.mcap is unfinished (")
    assert "exported what it holds" in err


SPECIAL = {
    "fifo": "a FIFO (named pipe)",
    "device": "a character device",
    "socket": "a socket",
    "directory": "a directory",
}


@contextmanager
def special_file(tmp_path: Path, kind: str) -> Iterator[Path]:
    """A path that exists and is not a regular file. A FIFO has a reader while the block runs:
    a command that (wrongly) opened it to write would not wait forever."""
    path = tmp_path / kind
    if kind == "device":
        path = Path(os.devnull)
    elif kind == "directory":
        path.mkdir()
    elif kind == "socket":
        with socket.socket(socket.AF_UNIX) as sock:
            sock.bind(str(path))
    elif kind == "fifo":
        os.mkfifo(path)
        reader = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        try:
            yield path
        finally:
            os.close(reader)
        return
    yield path


def _same_kind(path: Path, kind: str) -> bool:
    checks = {"fifo": path.is_fifo, "device": path.is_char_device, "socket": path.is_socket}
    return path.is_dir() and not any(path.iterdir()) if kind == "directory" else checks[kind]()


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["", "overwrite"])
@pytest.mark.parametrize("kind", SPECIAL)
def test_record_refuses_an_out_that_is_not_a_regular_file(
    tmp_path: Path, kind: str, overwrite: list[str]
) -> None:
    """Before the env is built (its bad --env-kwargs is not what the error says), one line."""
    with special_file(tmp_path, kind) as out:
        args = ["record", "CartPole-v1", "--out", str(out), "--episodes", "1", *overwrite]
        code, _, err = run(*args, "--env-kwargs", '{"render_mode": 3}')
        assert code == 2 and _same_kind(out, kind)
        refused = f"{out}: is {SPECIAL[kind]}" + (", not a regular file" * (kind != "directory"))
        one_error_line(err, refused)
        code, out_text, err = run(*args)  # and with nothing else wrong: nothing recorded
        assert code == 2 and out_text == "" and _same_kind(out, kind)
        one_error_line(err, refused)


@pytest.mark.parametrize("name", ["episodes.parquet", "clean.steps.parquet"])
@pytest.mark.parametrize("kind", ["fifo", "socket", "directory"])
def test_export_refuses_an_output_file_that_is_not_a_regular_file(
    tmp_path: Path, kind: str, name: str
) -> None:
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    with special_file(out_dir, kind) as special:
        target = special.rename(out_dir / name)
        code, out, err = run("export", "fixtures/clean.mcap", "--out", str(out_dir), "--overwrite")
        assert code == 2 and out == "" and _same_kind(target, kind)
        one_error_line(err, f"{target}: is {SPECIAL[kind]}, not a regular file")
        assert sorted(p.name for p in out_dir.iterdir()) == [name]  # nothing written
    code, _, err = run("export", "fixtures/clean.mcap", "--out", os.devnull, "--overwrite")
    assert code == 2
    one_error_line(err, f"{os.devnull}: not a directory")


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["", "overwrite"])
@pytest.mark.parametrize("kind", SPECIAL)
def test_recover_refuses_an_out_that_is_not_a_regular_file(
    tmp_path: Path, kind: str, overwrite: list[str]
) -> None:
    with special_file(tmp_path, kind) as out:
        code, _, err = run("recover", "fixtures/torn.mcap", "--out", str(out), *overwrite)
        assert code == 2 and _same_kind(out, kind)
        message = "is a directory" if kind == "directory" else "not a regular file"
        one_error_line(err, f"{out}: {message}")


def test_an_os_error_no_command_names_is_one_line_and_exit_2(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from episode_audit.cli import _app as cli

    def disk_full() -> None:
        raise OSError(28, "No space left on device", "/data/out.mcap")

    monkeypatch.setattr(cli, "app", disk_full)
    with pytest.raises(SystemExit) as exited:
        cli.main()
    assert exited.value.code == 2
    err = capsys.readouterr().err
    one_error_line(err, "/data/out.mcap: No space left on device")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--env-factory", "tests.support.factories:raises"],
            "--env-factory tests.support.factories:raises: "
            "it raised RuntimeError: boom from factory",
        ),
        (
            ["--env-factory", "tests.support.factories:not_an_env"],
            "--env-factory tests.support.factories:not_an_env: "
            "it returned str, not a gymnasium.Env",
        ),
        (["--import", ""], "--import '': ValueError: Empty module name"),
        (
            ["--import", "tests.no_such_module"],
            "--import 'tests.no_such_module': ModuleNotFoundError",
        ),
    ],
)
def test_a_replay_factory_or_import_that_fails_is_one_line(args: list[str], message: str) -> None:
    code, _, err = run("replay", "fixtures/clean.mcap", *args)
    assert code == 2
    one_error_line(err, message)


def test_record_out_naming_a_directory_says_so(tmp_path: Path) -> None:
    code, _, err = run("record", "CartPole-v1", "--out", str(tmp_path), "--episodes", "1")
    assert code == 2
    one_error_line(err, f"{tmp_path}: is a directory; give the evidence file's path")


def test_a_gate_on_a_label_no_failure_has_warns_and_still_passes() -> None:
    """A misspelt label (``colision``) would pass every time; the report says so."""
    code, out, err = run(
        "report",
        "fixtures/unlabeled_failure.mcap",
        "--max-failure-rate",
        "colision=0.1",
        "--format",
        "json",
    )
    assert code == 0
    assert json.loads(out)["unmatched_labels"] == ["colision"]
    assert err.strip() == (
        "episode-audit: warning: gate max_failure_rate:colision: no failure in these files is "
        "labelled 'colision': is the label spelt as recorded? (labels seen: 'unlabeled')"
    )


def _without_read_override() -> list[str] | None:
    """A command prefix under which a mode-000 file cannot be read: none for a normal user;
    for root, ``setpriv`` dropping the capabilities that bypass file permissions."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return None
    caps = "-dac_override,-dac_read_search"
    return [setpriv, "--bounding-set", caps, "--inh-caps", caps]


@pytest.mark.parametrize("command", ["check", "report", "show", "replay", "export", "recover"])
def test_a_file_without_read_permission_is_one_line_and_the_others_go_on(
    tmp_path: Path, command: str
) -> None:
    """Click's own readability check was a three-line usage error that stopped every input."""
    prefix = _without_read_override()
    if prefix is None:
        pytest.skip("running as root without setpriv: a mode-000 file stays readable")
    locked = tmp_path / "locked.mcap"
    shutil.copy(FIXTURES / "clean.mcap", locked)
    locked.chmod(0)
    several = command in ("check", "report", "replay", "export")
    # (replay: a CartPole file, whose steps no library version changes; MuJoCo's may differ)
    good = FIXTURES / ("unlabeled_failure.mcap" if command == "replay" else "clean.mcap")
    args = [str(locked), *([str(good)] if several else [])]
    if command in ("export", "recover"):
        args += ["--out", str(tmp_path / "out")]
    done = subprocess.run(
        [*prefix, sys.executable, "-m", "episode_audit", command, *args, "--format", "json"]
        if command in ("check", "report", "replay")
        else [*prefix, sys.executable, "-m", "episode_audit", command, *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert done.returncode == 2, done
    if command == "check":  # an unreadable input is a finding there, and the exit says so
        findings = json.loads(done.stdout)["findings"]
        assert [f["code"] for f in findings] == ["file_unreadable"], findings
        assert "cannot open: Permission denied" in findings[0]["message"]
    else:
        one_error_line(done.stderr, f"{locked}: cannot open: Permission denied")
    if command == "report":
        assert json.loads(done.stdout)["groups"][0]["episodes"] == 6
    if command == "replay":
        assert json.loads(done.stdout)["summary"]["identical"] == 3
    if command == "export":
        assert (tmp_path / "out" / "episodes.parquet").exists()


def test_record_of_an_ale_game_without_its_import_says_which_to_import(tmp_path: Path) -> None:
    """Gymnasium registers no ALE env until ``ale_py`` is imported (a process of its own: this
    one may have imported it); the command says ``--import ale_py``, the library ``imports=``."""
    out = tmp_path / "pong.mcap"
    record = [sys.executable, "-m", "episode_audit", "record", "ALE/Pong-v5", "--out", str(out)]
    library = (
        "from episode_audit.rollout import record_episodes\n"
        f"record_episodes('ALE/Pong-v5', {str(out)!r})"
    )
    done = [
        subprocess.run(args, capture_output=True, text=True, cwd=REPO, timeout=120)
        for args in (record, [sys.executable, "-c", library])
    ]
    said = "cannot make 'ALE/Pong-v5': no env is registered in namespace 'ALE'; pass "
    assert done[0].returncode == 2, done[0]
    assert " ".join(done[0].stderr.split()) == (  # (wrapped at 80 columns)
        f"episode-audit: error: {said}--import ale_py, which registers it"
    )
    assert done[1].returncode == 1 and done[1].stderr.splitlines()[-1] == (
        f"episode_audit.errors.ConfigurationError: {said}imports=['ale_py'], which registers it"
    )
    assert not out.exists()
    code, _, err = run("record", "Unknown/Game-v0", "--out", str(out))
    assert code == 2
    one_error_line(
        err,
        "cannot make 'Unknown/Game-v0': no env is registered in namespace 'Unknown'; pass "
        "--import MODULE naming the package that registers it",
    )


def test_record_says_when_the_policy_raised(tmp_path: Path) -> None:
    """Not "recorded as error" (that is the env raising): the env's episode is left open."""
    out = tmp_path / "pol.mcap"
    code, _, err = run(
        "record",
        "CartPole-v1",
        "--out",
        str(out),
        "--policy",
        "tests.support.factories:crashing_policy",
    )
    assert code == 2
    one_error_line(
        err,
        "episode 0: the policy raised ValueError: policy bug (the episode is recorded as "
        f"incomplete in {out})",
    )
    (episode,) = open_evidence(out).episodes().to_pylist()
    assert (episode["outcome"], episode["length"]) == ("incomplete", 2)


def test_check_ignore_of_a_code_no_finding_has_warns_once_and_keeps_the_exit_code() -> None:
    """``recorder_note:<code>`` is open-ended (newer recorders write new notes): a misspelt one
    is not refused, but said."""
    args = ["check", "fixtures/terms_mismatch.mcap", "--ignore", "terms_sum_mismatch"]
    code, _, err = run(*args, "--ignore", "recorder_note:observaton_cast")
    assert code == 0
    assert err.strip() == (
        "episode-audit: warning: --ignore recorder_note:observaton_cast: no finding has this "
        "code (misspelt?); nothing left out"
    )
    assert run(*args)[2] == ""  # the code that left findings out: no word


def test_show_episode_titles_say_the_error_the_agent_and_the_sub_env(tmp_path: Path) -> None:
    from episode_audit import RecordVectorEvidence
    from tests.replay.test_pettingzoo_replay import _rps
    from tests.support.flaky import record_flaky

    flaky = record_flaky(tmp_path / "flaky.mcap")
    code, out, _ = run("show", str(flaky), "--episode", "1", "--format", "markdown")
    assert code == 0
    assert out.startswith("### episode 1: error (RuntimeError in step), 2 steps"), out
    code, out, _ = run("show", str(_rps(tmp_path / "rps.mcap")), "-e", "1", "-f", "markdown")
    assert code == 0 and out.startswith("### episode 1 (agent player_1): "), out
    path = tmp_path / "vec.mcap"
    venv = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with RecordVectorEvidence(venv, path) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(2, np.int64))
    code, out, _ = run("show", str(path), "-e", "1", "-f", "markdown")
    assert code == 0 and out.startswith("### episode 1 (sub-env 1): incomplete"), out


def test_show_prints_a_game_s_env_kwargs_as_recorded_within_80_columns(tmp_path: Path) -> None:
    """A PettingZoo file has no env spec: its env kwargs (what replay builds the game with) were
    in no line of the table or Markdown; ``inf`` is held exactly in ``env_kwargs_typed``."""
    import math

    from episode_audit import RecordParallelEvidence
    from tests.replay.test_pettingzoo_replay import rps_v2

    kwargs = {"num_actions": 3, "max_cycles": math.inf}
    path = tmp_path / "rps.mcap"
    with RecordParallelEvidence(rps_v2.parallel_env(**kwargs), path, env_kwargs=kwargs) as env:
        env.reset(seed=0)
        env.step(dict.fromkeys(env.agents, 1))
    result = runner.invoke(app, ["show", str(path)], env={"COLUMNS": "80"})
    assert result.exit_code == 0
    assert max(len(line) for line in result.stdout.splitlines()) <= 80
    (row,) = [line for line in result.stdout.splitlines() if "env kwargs" in line]
    assert re.fullmatch(r" env kwargs +num_actions=3, max_cycles=inf *", row), row
    code, out, _ = run("show", str(path), "--format", "markdown")
    assert code == 0 and "| env kwargs | num_actions=3, max_cycles=inf |" in out
    code, out, _ = run("show", str(_plain_game(tmp_path / "plain.mcap")))
    assert code == 0 and re.search(
        r" env kwargs +not recorded: replay builds the env with its defaults", out
    ), out


def _plain_game(path: Path) -> Path:
    from episode_audit import RecordParallelEvidence
    from tests.replay.test_pettingzoo_replay import rps_v2

    with RecordParallelEvidence(rps_v2.parallel_env(), path) as env:
        env.reset(seed=0)
        env.step(dict.fromkeys(env.agents, 1))
    return path


def test_show_episode_prints_tuple_actions_item_by_item() -> None:
    from episode_audit.cli.render.show import _cell

    action = (2, np.array([0.078, -0.485], np.float32))
    assert _cell(action) == "(2, [ 0.078 -0.485])"
    assert _cell({"mode": np.int64(1), "x": np.zeros(2)}) == "{mode: 1, x: [0. 0.]}"


def test_show_counts_one_sub_env_in_the_singular(tmp_path: Path) -> None:
    path = tmp_path / "one.mcap"
    envs = gym.make_vec("CartPole-v1", 1, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(5):
            rec.step(rec.action_space.sample())
    code, out, _ = run("show", str(path))
    assert code == 0 and "vector: 1 sub-env (" in out, out
