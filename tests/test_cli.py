from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import pandas as pd
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, open_evidence
from episode_audit.cli import app

REPO = Path(__file__).resolve().parents[1]
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
    code, _, _ = run("check", "fixtures/unlabeled_failure.mcap")
    assert code == 0
    code, _, _ = run("check", "fixtures/unlabeled_failure.mcap", "--strict")
    assert code == 1


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
    code, out, _ = run("replay", str(path), "--env-factory", "tests.factories:heavy_cartpole")
    assert code == 1
    assert "step 0: observation expected" in out
    assert "0 identical, 3 diverged" in out


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


def test_report_never_folds_flags_into_done() -> None:
    for fmt in ("table", "markdown", "json"):
        _, out, _ = run("report", "fixtures/clean.mcap", "--format", fmt)
        assert "done" not in out.lower()


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

    from tests.envs import ScriptedEnv

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
