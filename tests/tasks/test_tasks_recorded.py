"""The reference tasks' recipes, checked from the *recorded evidence file*, not only the env.

For each task: a success, a task failure with its label and a time-limit truncation (scripted
policy, hacker policy, doing nothing — from fixed seeds); terms sum to reward through `check`;
replay is identical in a fresh process; the hacker on `proxy_reward=True` out-earns the competent
policy while failing, and the report flags it.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import RecordEvidence, check, open_evidence, report
from episode_audit.tasks import TASK_IDS, make_policy

pytest.importorskip("mujoco")

REPO = Path(__file__).resolve().parents[2]
FAILURE_LABELS = {
    "episode_audit/DoorOpen-v0": "door_slammed",
    "episode_audit/DrawerOpen-v0": "drawer_yanked",
    "episode_audit/Grasp-v0": "dropped_object",
}


def record(path: Path, task: str, policy: str, seeds: list[int], **kwargs: Any) -> Path:
    env = gym.make(task, **kwargs)
    act = (
        (lambda obs: np.zeros(env.action_space.shape, np.float32))
        if policy == "nothing"
        else make_policy(policy, env, seed=0)
    )
    with RecordEvidence(env, path, tags={"policy": policy}) as rec:
        for seed in seeds:
            obs, _ = rec.reset(seed=seed)
            done = False
            while not done:
                obs, _, term, trunc, _ = rec.step(act(obs))
                done = term or trunc
    return path


@pytest.fixture(scope="module", params=TASK_IDS)
def recorded(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    task = request.param
    out = tmp_path_factory.mktemp(task.split("/")[-1])
    return {
        "task": task,
        "scripted": record(out / "scripted.mcap", task, "scripted", [0]),
        "hacker": record(out / "hacker.mcap", task, "hacker", [0]),
        "nothing": record(out / "nothing.mcap", task, "nothing", [0]),
    }


def only_episode(path: Path) -> dict[str, Any]:
    (episode,) = open_evidence(path).episodes().to_pylist()
    return episode


def test_success_from_the_file(recorded: dict[str, Any]) -> None:
    episode = only_episode(recorded["scripted"])
    assert (episode["outcome"], episode["terminated"], episode["truncated"]) == (
        "success",
        True,
        False,
    )
    steps = open_evidence(recorded["scripted"]).steps()
    assert steps["outcome"].to_pylist()[-1] == "success"
    assert dict(steps["terms"].to_pylist()[-1])["success_bonus"] > 0


def test_failure_with_its_label_from_the_file(recorded: dict[str, Any]) -> None:
    episode = only_episode(recorded["hacker"])
    assert episode["outcome"] == "failure"
    assert episode["failure_label"] == FAILURE_LABELS[recorded["task"]]
    assert episode["terminated"] and not episode["truncated"]


def test_time_limit_truncation_from_the_file(recorded: dict[str, Any]) -> None:
    episode = only_episode(recorded["nothing"])
    assert (episode["outcome"], episode["truncation_reason"]) == ("truncated", "time_limit")
    assert not episode["terminated"]
    assert episode["length"] == gym.spec(recorded["task"]).max_episode_steps


def test_terms_sum_to_reward_on_every_step_through_check(recorded: dict[str, Any]) -> None:
    result = check([recorded[k] for k in ("scripted", "hacker", "nothing")], require_terms=True)
    codes = {f.code for f in result.findings}
    assert "terms_sum_mismatch" not in codes and "missing_terms" not in codes
    assert result.ok, result.findings


def test_replay_is_identical_in_a_fresh_process(recorded: dict[str, Any]) -> None:
    paths = [str(recorded[k]) for k in ("scripted", "hacker", "nothing")]
    script = textwrap.dedent(
        f"""
        from episode_audit import replay
        result = replay({paths!r})
        assert result.count("identical") == 3, result
        """
    )
    subprocess.run([sys.executable, "-c", script], check=True, cwd=REPO)


@pytest.mark.parametrize("task", TASK_IDS)
def test_hacker_out_earns_and_fails_and_the_report_flags_it(task: str, tmp_path: Path) -> None:
    seeds = list(range(10, 20))
    scripted = record(tmp_path / "s.mcap", task, "scripted", seeds, proxy_reward=True)
    hacker = record(tmp_path / "h.mcap", task, "hacker", seeds, proxy_reward=True)
    result = report([scripted, hacker], by="tag:policy")
    groups = {g.key: g for g in result.groups}
    good, bad = groups["scripted"], groups["hacker"]
    assert bad.return_mean is not None and good.return_mean is not None
    assert bad.return_mean > good.return_mean
    assert bad.success_rate is not None and good.success_rate is not None
    assert bad.success_rate < good.success_rate
    assert bad.warnings, "the hacker run must raise an incentive warning"
    assert not good.warnings
    together = report([scripted, hacker], by="env")
    assert {w.code for g in together.groups for w in g.warnings} & {
        "failure_outearns_success",
        "shaping_dominates",
    }
