"""compare's n needed agrees with the interval the verdict was drawn from."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from episode_audit import compare
from episode_audit.compare.stats import NEVER
from episode_audit.rollout import record_episodes

BALANCE = "tests.support.cartpole:balance"


@pytest.fixture(scope="module")
def twins(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    out = tmp_path_factory.mktemp("twins")
    paths = [out / "a.mcap", out / "b.mcap"]
    for path in paths:  # the same 60 episodes twice: no failure, every one at the time limit
        record_episodes("CartPole-v1", path, policy=BALANCE, episodes=60, max_episode_steps=10)
    return paths


def test_an_interval_just_past_the_margin_asks_for_the_units_it_needs(twins: list[Path]) -> None:
    # 0 failures in 60 pairs on both sides: Newcombe's interval is +-6.0 %, past the 5 %
    # margin, while the planning formula asked for 51 pairs (fewer than the 60 there are):
    # `inconclusive, n needed 51` said 51 pairs would do what 60 did not
    result = compare([twins[0]], [twins[1]])
    failure = result.groups[0].metric("failure_rate")
    half = failure.interval.high
    assert half == pytest.approx(0.0602, abs=1e-4) and half > failure.margin
    assert failure.n_needed == math.ceil(60 * (half / 0.05) ** 2) == 87
    assert failure.verdict == "underpowered" and failure.to_dict()["n_needed"] == 87
    assert result.verdict == "underpowered"


def test_a_point_difference_past_the_margin_needs_no_n_it_could_hold_with() -> None:
    from episode_audit.compare.metrics import MetricComparison, interval_n_needed
    from episode_audit.report.stats import Interval

    metric = MetricComparison(
        "failure_rate", "rate", "lower", 0.1, 0.16, 50, 50, 0.06, Interval(-0.05, 0.17),
        True, 50, "McNemar exact", 0.3, 0.05, 0.1, 40,
    )  # fmt: skip
    assert interval_n_needed(metric) == NEVER
