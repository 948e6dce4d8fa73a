"""Incentive warnings: signs that a group's reward pays for something other than success.

:data:`INCENTIVE_WARNINGS` is the registry (code -> when it is raised), :func:`incentive_table`
the docs table generated from it (``docs/reporting.md``); :func:`incentive_warnings` finds the
warnings of one group, each an :class:`IncentiveWarning` whose message states its numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt

__all__ = [
    "FAILURE_OUTEARNS_SUCCESS",
    "INCENTIVE_WARNINGS",
    "NO_SUCCESS_POSITIVE_RETURN",
    "SHAPING_DOMINATES",
    "TRUNCATION_OUTEARNS_SUCCESS",
    "IncentiveWarning",
    "incentive_table",
    "incentive_warnings",
]

FAILURE_OUTEARNS_SUCCESS = "failure_outearns_success"
TRUNCATION_OUTEARNS_SUCCESS = "truncation_outearns_success"
NO_SUCCESS_POSITIVE_RETURN = "no_success_positive_return"
SHAPING_DOMINATES = "shaping_dominates"

_SHAPING_SHARE = 0.5
_SHAPING_SUCCESS_RATE = 0.5

INCENTIVE_WARNINGS: dict[str, str] = {
    FAILURE_OUTEARNS_SUCCESS: "failures with some label earn a higher mean return than successes "
    "(at least one of each)",
    TRUNCATION_OUTEARNS_SUCCESS: "truncated episodes earn a higher mean return than successes",
    NO_SUCCESS_POSITIVE_RETURN: "no episode succeeded, yet failures earn a positive mean return, "
    "at least as high as the truncated episodes' (if any); needs a task that reports success",
    SHAPING_DOMINATES: f"one reward term supplies >= {_SHAPING_SHARE:.0%} of the absolute term "
    "mass of the group's ended episodes, and pays (its total is positive: a dominating cost is "
    f"not shaping), while the success rate is < {_SHAPING_SUCCESS_RATE}; needs at least two "
    "terms (declared constants count), at least one episode the task ended (success or "
    "failure: a group only ever cut off by a time limit has no success signal), and a task that "
    "reports success",
}
"""Every incentive warning code and when it is raised."""


@dataclass
class IncentiveWarning:
    """A sign that the reward pays for something other than success (see the registry)."""

    group: str
    code: str
    message: str


class _Group(Protocol):
    """What the warnings read of a group: a :class:`~.groups.GroupReport` has it."""

    @property
    def key(self) -> str: ...
    @property
    def ended(self) -> int: ...
    @property
    def success(self) -> int: ...
    @property
    def failure(self) -> int: ...
    @property
    def success_rate(self) -> float | None: ...
    @property
    def success_signal(self) -> bool: ...


def incentive_table() -> str:
    """The Markdown table of :data:`INCENTIVE_WARNINGS`, as ``docs/reporting.md`` holds it."""
    rows = [f"| `{code}` | {when} |" for code, when in INCENTIVE_WARNINGS.items()]
    return "\n".join(["| code | when |", "| --- | --- |", *rows])


def incentive_warnings(
    group: _Group,
    outcome: np.ndarray[Any, Any],
    labels: np.ndarray[Any, Any],
    returns: np.ndarray[Any, Any] | None,
    terms: pa.Table,
) -> list[IncentiveWarning]:
    """The incentive warnings of ``group``.

    ``outcome``, ``labels`` (failure labels) and ``returns`` hold one value per episode of the
    group; ``terms`` one row per (ended episode, reward term) with its ``outcome`` and ``total``.
    An episode whose return is not finite (NaN, infinite) is left out of the returns' means:
    one would make every mean NaN and every comparison false (the report's notes count them).
    ``returns`` is ``None`` when they cannot be compared (different reward wrappers): then only
    the warnings on reward terms are given.
    """
    warnings: list[IncentiveWarning] = []
    if returns is not None:
        warnings += _on_returns(group, outcome, labels, returns)
    # success can only be rare where the task can end by itself: a group whose episodes were
    # all cut off (HalfCheetah, Reacher: time limit only) has no success signal to compare with
    rate = group.success_rate
    if (
        rate is not None
        and rate < _SHAPING_SUCCESS_RATE
        and group.success + group.failure
        and group.success_signal
        and terms.num_rows
    ):
        warnings += _shaping_dominates(group, rate, terms)
    return warnings


def _on_returns(
    group: _Group,
    outcome: np.ndarray[Any, Any],
    labels: np.ndarray[Any, Any],
    returns: np.ndarray[Any, Any],
) -> list[IncentiveWarning]:
    """The warnings that compare returns: failures or truncations out-earning successes."""
    finite = np.isfinite(returns)
    outcome, labels, returns = outcome[finite], labels[finite], returns[finite]
    failed = outcome == fmt.OUTCOME_FAILURE
    success = returns[outcome == fmt.OUTCOME_SUCCESS]
    truncated = returns[outcome == fmt.OUTCOME_TRUNCATED]
    if success.size:
        success_mean = float(np.mean(success))
        against = f"successes ({_num(success_mean)} over {success.size} episodes)"
        return [
            *_failures_outearning(group.key, failed, labels, returns, success_mean, against),
            *_truncations_outearning(group.key, truncated, success_mean, against),
        ]
    if failed.any() and group.success_signal:
        return _no_success_positive_return(group, returns[failed], truncated)
    return []


def _num(value: float) -> str:
    return f"{value:.4g}"


def _failures_outearning(
    key: str,
    failed: np.ndarray[Any, Any],
    labels: np.ndarray[Any, Any],
    returns: np.ndarray[Any, Any],
    success_mean: float,
    against: str,
) -> list[IncentiveWarning]:
    """``failure_outearns_success``: one warning per failure label that out-earns successes."""
    warnings: list[IncentiveWarning] = []
    named = np.array([str(x or fmt.UNLABELED) for x in labels], dtype=object)
    for label in sorted(set(named[failed].tolist())):
        chosen = failed & (named == label)
        mean = float(np.mean(returns[chosen]))
        if mean > success_mean:
            message = (
                f"failures labelled {label!r} earn a mean return of {_num(mean)} over "
                f"{int(chosen.sum())} episodes, more than {against}"
            )
            warnings.append(IncentiveWarning(key, FAILURE_OUTEARNS_SUCCESS, message))
    return warnings


def _truncations_outearning(
    key: str, truncated: np.ndarray[Any, Any], success_mean: float, against: str
) -> list[IncentiveWarning]:
    """``truncation_outearns_success``, from the returns of the truncated episodes."""
    if not truncated.size:
        return []
    mean = float(np.mean(truncated))
    if not mean > success_mean:
        return []
    message = (
        f"truncated episodes earn a mean return of {_num(mean)} over "
        f"{truncated.size} episodes, more than {against}"
    )
    return [IncentiveWarning(key, TRUNCATION_OUTEARNS_SUCCESS, message)]


def _no_success_positive_return(
    group: _Group, failures: np.ndarray[Any, Any], truncated: np.ndarray[Any, Any]
) -> list[IncentiveWarning]:
    """``no_success_positive_return``, from the returns of the failures and truncations."""
    mean = float(np.mean(failures))
    truncated_mean = float(np.mean(truncated)) if truncated.size else None
    if not (mean > 0 and (truncated_mean is None or mean >= truncated_mean)):
        return []
    beside = (
        ""
        if truncated_mean is None
        else f", at least the truncated episodes' {_num(truncated_mean)}"
    )
    message = (
        f"no episode succeeded (0 of {group.ended} ended), yet failures earn a positive "
        f"mean return of {_num(mean)} over {failures.size} episodes{beside}"
    )
    return [IncentiveWarning(group.key, NO_SUCCESS_POSITIVE_RETURN, message)]


def _shaping_dominates(group: _Group, rate: float, terms: pa.Table) -> list[IncentiveWarning]:
    """``shaping_dominates``: a paying term with most of the absolute term mass."""
    by_term = (
        pa.table(
            {
                "term": terms.column("term"),
                "mass": pc.abs(terms.column("total")),
                "total": terms.column("total"),
            }
        )
        .group_by("term")
        .aggregate([("mass", "sum"), ("total", "sum")])
    )
    names = by_term.column("term").to_pylist()
    masses = np.array(by_term.column("mass_sum").to_pylist(), dtype=np.float64)
    paid = np.array(by_term.column("total_sum").to_pylist(), dtype=np.float64)
    total = float(masses.sum())
    if not (len(names) >= 2 and total > 0 and math.isfinite(total)):
        return []
    top = int(np.argmax(masses))
    share = float(masses[top]) / total
    # a cost (a term that takes return, as a control cost) does not pay for anything
    if not (share >= _SHAPING_SHARE and paid[top] > 0):
        return []
    message = (
        f"term {names[top]!r} supplies {share:.0%} of the absolute term mass "
        f"({_num(float(masses[top]))} of {_num(total)}) while the success rate is "
        f"{rate:.2f} ({group.success} of {group.ended} ended episodes)"
    )
    return [IncentiveWarning(group.key, SHAPING_DOMINATES, message)]
