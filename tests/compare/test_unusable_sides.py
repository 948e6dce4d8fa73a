"""Sides a metric cannot use: returns that are not finite, a group one side lacks, a side whose
every episode raised. Real recorded files, the library and the command line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from typer.testing import CliRunner

from episode_audit import CompareGates, RecordEvidence, compare
from episode_audit.cli import app
from episode_audit.rollout import record_episodes
from tests.support.crashing import crashing_cartpole

runner = CliRunner()
REPO = Path(__file__).resolve().parents[2]


class NanReward(gym.Env[Any, Any]):
    """Four steps an episode; the second step's reward is NaN, so every return is NaN."""

    observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        reward = float("nan") if self.t == 2 else 1.0
        return np.zeros(2, np.float32), reward, False, self.t >= 4, {}


def _nan_returns(path: Path, episodes: int) -> Path:
    with RecordEvidence(NanReward(), path) as env:
        for seed in range(episodes):
            env.reset(seed=seed)
            for _ in range(4):
                env.step(0)
    return path


@pytest.mark.parametrize("episodes", [2, 10])
def test_a_return_gate_on_nan_returns_says_more_episodes_would_not_help(
    tmp_path: Path, episodes: int
) -> None:
    base = _nan_returns(tmp_path / "a.mcap", episodes)
    cand = _nan_returns(tmp_path / "b.mcap", episodes)
    result = compare([base], [cand], gates=CompareGates(max_return_drop=1.0))
    (gate,) = result.groups[0].gates
    assert not gate.passed and not result.passed
    assert gate.message == (
        "return: cannot be verified, a return is not finite (NaN or infinite), so the mean "
        "return is undefined and more episodes would not help (group all)"
    )
    assert result.groups[0].metric("return").verdict == "inconclusive"
    assert not any("record more" in note for note in result.notes), result.notes


def test_the_one_side_table_title_is_one_line_when_it_fits(tmp_path: Path) -> None:
    files = {}
    for name, config in [("b_short", "short"), ("b_long", "long"), ("c_short", "short")]:
        files[name] = str(tmp_path / f"{name}.mcap")
        record_episodes("CartPole-v1", files[name], episodes=4, max_episode_steps=10,
                        tags={"config": config})  # fmt: skip
    args = ["compare", files["b_short"], files["b_long"], "--candidate", files["c_short"]]
    for columns in ("200", "80"):
        result = runner.invoke(app, [*args, "--by", "tag:config"], env={"COLUMNS": columns})
        assert result.exit_code == 0, result.output
        lines = [line.rstrip() for line in result.stdout.splitlines()]
        assert "Groups on one side only (not compared)" in lines, result.stdout
        assert max(len(line) for line in lines) <= int(columns)


def test_every_candidate_episode_raised_exits_1_in_every_output(tmp_path: Path) -> None:
    import jsonschema
    import junitparser

    base = str(crashing_cartpole(tmp_path / "clean.mcap", 30))
    crashed = str(crashing_cartpole(tmp_path / "crashed.mcap", 30, lambda seed: True))
    args = ["compare", base, "--candidate", crashed, "--max-error-increase", "0.05"]
    result = runner.invoke(app, [*args, "-f", "json"])
    assert result.exit_code == 1, result.output
    data = json.loads(result.stdout)
    schema = json.loads((REPO / "docs" / "schemas" / "compare.json").read_text())
    jsonschema.validate(data, schema, jsonschema.Draft202012Validator)
    assert data["verdict"] == "regressed" and data["passed"] is False
    (gate,) = data["groups"][0]["gates"]
    assert (gate["gate"], gate["passed"]) == ("max_error_increase", False)
    result = runner.invoke(app, [*args, "-f", "junit"])
    xml = tmp_path / "compare.xml"
    xml.write_text(result.stdout)
    outcomes = {
        case.name: type(case.result[0]).__name__ if case.result else "passed"
        for suite in junitparser.JUnitXml.fromfile(str(xml))
        for case in suite
    }
    assert result.exit_code == 1
    assert outcomes["error_rate"] == "Failure" and outcomes["gate:max_error_increase"] == "Failure"
    assert outcomes["failure_rate"] == "Skipped" and "Error" not in outcomes.values()
    result = runner.invoke(app, args, env={"COLUMNS": "200"})
    assert result.exit_code == 1
    row = next(line for line in result.stdout.splitlines() if " failure_rate " in line)
    assert row.split()[4:8] == ["30)", "-", "(n", "0)"] and row.split()[8] == "-", row
    assert "other units" not in row and "not compared" in row
