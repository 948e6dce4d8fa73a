"""The reference tasks' contracts, checked from the *recorded evidence file*, not only the env.

For each task, with the ``env_contract`` fixture of the pytest plugin: a success (scripted
policy), a task failure with its label (hacker policy) and a time-limit truncation (doing
nothing), from seed 0 -- each ending, its terms at the last step, terms summing to the reward
on every step, and an identical replay in a fresh env. Then: replay is identical in a fresh
process too, and the hacker on ``proxy_reward=True`` out-earns the competent policy while
failing, and the report flags it.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import RecordEvidence, report
from episode_audit.tasks import TASK_IDS, make_policy
from episode_audit.testing import ContractCase, ContractResult

pytest.importorskip("mujoco")

REPO = Path(__file__).resolve().parents[2]
FAILURE_LABELS = {
    "episode_audit/DoorOpen-v0": "door_slammed",
    "episode_audit/DrawerOpen-v0": "drawer_yanked",
    "episode_audit/Grasp-v0": "dropped_object",
}
Contract = Callable[[ContractCase], ContractResult]


def nothing(env: gym.Env[Any, Any]) -> Callable[[Any], Any]:
    zero = np.zeros(env.action_space.shape, np.float32)
    return lambda obs: zero


def cases(task: str) -> list[ContractCase]:
    """Success, the labelled failure and the time-limit truncation of ``task``, from seed 0."""
    common: dict[str, Any] = {"seed": 0, "require_terms": True}
    return [
        ContractCase(
            task,
            make_policy=lambda env: make_policy("scripted", env),
            expect="success",
            terms_present=["success_bonus"],
            terms_absent=["failure_penalty"],
            **common,
        ),
        ContractCase(
            task,
            make_policy=lambda env: make_policy("hacker", env),
            expect=f"failure:{FAILURE_LABELS[task]}",
            terms_present=["failure_penalty"],
            terms_absent=["success_bonus"],
            **common,
        ),
        ContractCase(task, make_policy=nothing, expect="truncated:time_limit", **common),
    ]


@pytest.mark.parametrize("case", [c for task in TASK_IDS for c in cases(task)], ids=str)
def test_the_contract_of_each_ending(case: ContractCase, env_contract: Contract) -> None:
    result = env_contract(case)
    if result.outcome == "truncated":
        assert result.steps == gym.spec(str(case.env)).max_episode_steps
    elif result.outcome == "success":
        assert result.last_terms["success_bonus"] > 0
    else:
        assert result.last_terms["failure_penalty"] < 0


@pytest.mark.parametrize("task", TASK_IDS)
def test_replay_is_identical_in_a_fresh_process(task: str, env_contract: Contract) -> None:
    paths = [str(env_contract(case).path) for case in cases(task)]
    script = textwrap.dedent(
        f"""
        from episode_audit import replay
        result = replay({paths!r})
        assert result.count("identical") == 3, result
        """
    )
    subprocess.run([sys.executable, "-c", script], check=True, cwd=REPO)


def record(path: Path, task: str, policy: str, seeds: list[int], **kwargs: Any) -> Path:
    env = gym.make(task, **kwargs)
    act = make_policy(policy, env, seed=0)
    with RecordEvidence(env, path, tags={"policy": policy}) as rec:
        for seed in seeds:
            obs, _ = rec.reset(seed=seed)
            done = False
            while not done:
                obs, _, term, trunc, _ = rec.step(act(obs))
                done = term or trunc
    return path


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
