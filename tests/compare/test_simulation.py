"""Seeded simulations: the 95 % intervals cover 93-97 % of the time, and a candidate that is
the baseline (same policy, other seeds) is called ``regressed`` at most 5 % of the time.

Slow (``make test-long``); the figures are printed (``-s``).
"""

from __future__ import annotations

import numpy as np
import pytest

from episode_audit.compare import stats
from episode_audit.compare.core import _decide
from episode_audit.compare.groups import CompareGates, compare_group
from episode_audit.compare.sides import Side

pytestmark = pytest.mark.slow
RUNS = 2000
LOW, HIGH = 0.93, 0.97


def _covered(intervals: list[stats.Interval], truth: float) -> float:
    return float(np.mean([ci.low <= truth <= ci.high for ci in intervals]))


def test_unpaired_rate_interval_coverage() -> None:
    rng = np.random.default_rng(1)
    n, pb, pc = 100, 0.7, 0.6
    xb, xc = rng.binomial(n, pb, RUNS), rng.binomial(n, pc, RUNS)
    cis = [stats.newcombe_unpaired(int(b), n, int(c), n) for b, c in zip(xb, xc, strict=True)]
    coverage = _covered(cis, pc - pb)
    print(f"\nNewcombe unpaired (n={n} a side, {pb} -> {pc}, {RUNS} runs): {coverage:.2%}")
    assert LOW <= coverage <= HIGH


def test_paired_rate_interval_coverage() -> None:
    rng = np.random.default_rng(2)
    n = 100
    cells = [0.55, 0.15, 0.05, 0.25]  # both, baseline only, candidate only, neither
    truth = cells[2] - cells[1]
    tables = rng.multinomial(n, cells, RUNS)
    cis = [stats.newcombe_paired(*map(int, t)) for t in tables]
    coverage = _covered(cis, truth)
    print(f"\nNewcombe paired ({n} pairs, difference {truth:+.2f}, {RUNS} runs): {coverage:.2%}")
    assert LOW <= coverage <= HIGH


@pytest.mark.parametrize("paired", [False, True])
def test_mean_interval_coverage(paired: bool) -> None:
    rng = np.random.default_rng(3 + paired)
    n, shift = 100, 1.0
    cis = []
    for _ in range(RUNS):
        base = rng.gamma(2.0, 2.0, n)  # skewed, as returns often are
        if paired:
            cand = base + shift + rng.normal(0, 1.0, n)
        else:
            cand = rng.gamma(2.0, 2.0, n) + shift
        cis.append(stats.mean_difference_interval(base, cand, paired=paired))
    coverage = _covered(cis, shift)
    kind = "paired" if paired else "unpaired"
    print(f"\nt interval, {kind} (n={n}, {RUNS} runs): {coverage:.2%}")
    assert LOW <= coverage <= HIGH


@pytest.mark.parametrize(("n", "paired"), [(4, False), (6, False), (6, True), (10, True)])
def test_mean_interval_coverage_with_the_fewest_episodes_it_bounds(n: int, paired: bool) -> None:
    # (the BCa bootstrap covered 83-90 % of such normal samples at 4-6 a side)
    rng = np.random.default_rng(10 + n + paired)
    shift = 5.0
    cis = []
    for _ in range(RUNS):
        base = rng.normal(100.0, 20.0, n)
        cand = (base if paired else rng.normal(100.0, 20.0, n)) + shift
        if paired:
            cand = cand + rng.normal(0.0, 10.0, n)
        cis.append(stats.mean_difference_interval(base, cand, paired=paired))
    coverage = _covered(cis, shift)
    kind = "pairs" if paired else "a side"
    print(f"\nt interval, {n} {kind} (normal, {RUNS} runs): {coverage:.2%}")
    assert LOW <= coverage <= HIGH


def _episodes(rng: np.random.Generator, n: int) -> Side:
    outcome = rng.choice(
        ["success", "failure", "failure", "truncated"], n, p=[0.7, 0.1, 0.05, 0.15]
    )
    label = [None] * n
    kinds = rng.random(n) < 2 / 3
    label = ["slipped" if k else "dropped" for k in kinds]
    failure = [lab if o == "failure" else None for o, lab in zip(outcome, label, strict=True)]
    returns = np.where(outcome == "success", 10.0, 2.0) + rng.normal(0, 3.0, n)
    return Side.of(list(outcome), list(returns), failure_label=failure)


def test_false_regression_rate_when_the_candidate_is_the_baseline() -> None:
    rng = np.random.default_rng(5)
    n = 100
    verdicts = []
    for _ in range(RUNS):
        group = compare_group("all", _episodes(rng, n), _episodes(rng, n), CompareGates(), [])
        _decide([group])
        verdicts.append(group.verdict)
    rate = verdicts.count("regressed") / RUNS
    counts = {v: verdicts.count(v) for v in sorted(set(verdicts))}
    print(f"\nsame policy, other seeds ({n} a side, {RUNS} runs): regressed {rate:.2%}; {counts}")
    assert rate <= 0.05
