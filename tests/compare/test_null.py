"""Fast seeded null simulations: the candidate is the baseline's policy, and nothing may be
called ``regressed`` more than 5 % of the time (the slow ones: ``test_simulation.py``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from episode_audit.compare.core import _decide
from episode_audit.compare.groups import (
    CompareGates,
    GroupComparison,
    check_gates,
    compare_group,
)
from episode_audit.compare.sides import Side
from episode_audit.report.incentives import IncentiveWarning, incentive_warnings

NO_TERMS = pa.table({"term": pa.array([], pa.string()), "total": pa.array([], pa.float64())})


@dataclass
class _Group:
    """What the incentive warnings read of a group."""

    key: str
    ended: int
    success: int
    failure: int
    success_rate: float | None
    success_signal: bool = True


def _side(rng: np.random.Generator, n: int) -> tuple[Side, list[IncentiveWarning]]:
    """``n`` episodes of a policy whose return does not depend on how the episode ended, so
    ``failure_outearns_success`` is a coin toss; and the side's incentive warnings."""
    outcome = rng.choice(["success", "failure", "truncated"], n, p=[0.6, 0.25, 0.15])
    labels = np.array(["slipped" if o == "failure" else None for o in outcome], dtype=object)
    returns = rng.normal(5.0, 3.0, n)
    success, failure = int((outcome == "success").sum()), int((outcome == "failure").sum())
    group = _Group("all", n, success, failure, success / n)
    warnings = incentive_warnings(group, outcome.astype(object), labels, returns, NO_TERMS)
    side = Side.of(list(outcome), list(returns), failure_label=list(labels), seed=list(range(n)))
    return side, warnings


def _null_groups(runs: int = 100, n: int = 30) -> list[GroupComparison]:
    """``runs`` comparisons of two samples of the same policy, ``n`` episodes a side."""
    rng = np.random.default_rng(7)
    groups = []
    for _ in range(runs):
        (base, warned_b), (cand, warned_c) = _side(rng, n), _side(rng, n)
        codes = {w.code for w in warned_b}
        new = [w for w in warned_c if w.code not in codes]
        group = compare_group("all", base, cand, CompareGates(), new)
        _decide([group])
        groups.append(group)
    return groups


def test_incentive_warnings_new_by_chance_do_not_make_the_verdict() -> None:
    groups = _null_groups()
    warned = sum(bool(g.new_warnings) for g in groups)
    assert warned >= 20  # (the warning does appear on the candidate's side alone by chance)
    regressed = [g.verdict for g in groups].count("regressed")
    assert regressed / len(groups) <= 0.05, (regressed, warned)


def test_the_new_warnings_gate_fails_on_them_only_when_asked() -> None:
    gate = CompareGates(fail_on_new_incentive_warning=True)
    for group in _null_groups(20):
        (result,) = check_gates(group, gate)
        assert result.gate == "new_incentive_warnings"
        assert result.passed == (not group.new_warnings), result.message
        assert check_gates(group, CompareGates()) == []


def _crashing_side(rng: np.random.Generator, n: int) -> Side:
    """``n`` episodes begun, seeded ``0..n-1``, each an ``error`` with chance 0.1; the side of
    those that ended, with all of them as its ``started``."""
    outcome = rng.choice(["success", "failure", "truncated", "error"], n, p=[0.5, 0.2, 0.2, 0.1])
    everything = Side.of(list(outcome), list(rng.normal(5.0, 3.0, n)), seed=list(range(n)))
    ended = everything.take(np.flatnonzero(outcome != "error"))
    ended.started = everything
    return ended


def test_error_rates_of_the_same_env_are_not_called_a_regression() -> None:
    """Errors come and go by chance on both sides: the error rate joins Holm's family, and the
    family still calls at most 5 % of comparisons ``regressed``."""
    rng = np.random.default_rng(11)
    groups = []
    for _ in range(100):
        group = compare_group(
            "all", _crashing_side(rng, 30), _crashing_side(rng, 30), CompareGates(), []
        )
        _decide([group])
        groups.append(group)
    assert all(g.metric("error_rate").can_reject for g in groups[:5])
    verdicts = [g.verdict for g in groups]
    errors = [g.metric("error_rate").verdict for g in groups]
    assert verdicts.count("regressed") / len(groups) <= 0.05, verdicts.count("regressed")
    assert errors.count("regressed") <= 2, errors
