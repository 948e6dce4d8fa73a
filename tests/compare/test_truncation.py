"""compare's truncation rate: shown, not judged (the time limit is a success or a timeout)."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import compare
from episode_audit.rollout import record_episodes


@pytest.fixture(scope="module")
def cartpole(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("cartpole")
    made = {}
    for name, policy in (("random", "random"), ("balance", "tests.support.cartpole:balance")):
        made[name] = out / f"{name}.mcap"
        record_episodes(
            "CartPole-v1", made[name], policy=policy, episodes=20, max_episode_steps=100
        )
    return made


def test_a_better_survival_policy_reaching_the_time_limit_is_not_a_regression(
    cartpole: dict[str, Path],
) -> None:
    # random CartPole falls; the balancing policy reaches the time limit every episode:
    # truncation_rate was `regressed` (lower is better) and so was the comparison, exit 1
    result = compare([cartpole["random"]], [cartpole["balance"]])
    (group,) = result.groups
    truncation = group.metric("truncation_rate")
    assert truncation.candidate == 1.0 and truncation.baseline < 0.5
    assert truncation.better == "none" and truncation.verdict is None
    assert truncation.p_adjusted is None and truncation.difference > 0.5
    assert truncation.interval.low > 0  # (shown with its interval all the same)
    assert group.metric("failure_rate").verdict == "improved"
    assert group.metric("return").verdict == "improved"
    assert result.verdict == "improved" and result.passed
    assert "all/truncation_rate" not in {c.name for c in result.cases()}
    data = result.to_dict()["groups"][0]["metrics"]
    (shown,) = [m for m in data if m["name"] == "truncation_rate"]
    assert shown["verdict"] is None and shown["better"] == "none"
