"""One metric compared between two sides: its difference, interval, test, plan and verdict.

:func:`rate_metric` compares a rate (success, failure, one label's failure, truncation,
error);
:func:`mean_metric` a mean (return, a reward term's episode total). Both are paired on matched
reset seeds when the pairs are usable (:func:`~.sides.pair`: enough of each task found a pair,
:data:`PAIRED_SHARE`), else unpaired over every ended episode. :func:`decide` gives the
verdict once the p-values are Holm-adjusted (:func:`settle` with an n needed that agrees with
the interval). The formulas: ``docs/compare.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from ..report.stats import Interval
from . import stats
from .sides import PAIRED_SHARE, Pairs

__all__ = [
    "PAIRED_SHARE",
    "VERDICTS",
    "MetricComparison",
    "Verdict",
    "decide",
    "interval_n_needed",
    "mean_metric",
    "not_computable",
    "rate_metric",
    "settle",
]

Verdict = Literal["regressed", "improved", "held", "inconclusive", "underpowered"]
VERDICTS: tuple[Verdict, ...] = ("regressed", "improved", "held", "inconclusive", "underpowered")

Array = np.ndarray[Any, Any]


@dataclass
class MetricComparison:
    """One metric of both sides: ``difference`` is the candidate's value minus the baseline's.

    ``better`` says which way is better (``"higher"``, ``"lower"``, or ``"none"`` for reward
    terms and the truncation rate, which get no verdict). ``n_needed`` counts pairs when
    ``paired``, else episodes a side; ``mde`` is the difference detectable now with the power
    of :data:`~.stats.POWER`.
    ``can_reject`` is false when its test gives p = 1 whatever the episodes hold in their
    order: a rate with no event on either side or one in every episode of both (unpaired),
    or fewer than two discordant pairs (paired); a mean with fewer than two values a side, a
    value not finite, or all values (paired: all differences 0) the same. ``same_test_as``
    names the group's metric whose test this one repeats. Neither is counted in Holm's family.
    """

    name: str
    kind: Literal["rate", "mean"]
    better: Literal["higher", "lower", "none"]
    baseline: float | None
    candidate: float | None
    baseline_n: int
    candidate_n: int
    difference: float
    interval: Interval
    paired: bool
    pairs: int
    test: str
    p_value: float
    margin: float
    mde: float
    n_needed: int
    p_adjusted: float | None = None
    verdict: Verdict | None = None
    baseline_iqm: float | None = None
    candidate_iqm: float | None = None
    can_reject: bool = True
    same_test_as: str | None = None
    not_comparable: str | None = None
    """Why the sides' values are not compared: not in the same units (returns of other reward
    wrappers or terms), or a side has no ended episode (:func:`not_computable`). Then the
    verdict is ``inconclusive``, the test cannot reject, and a gate cannot be verified."""

    @property
    def analysed(self) -> int:
        """The number of units the comparison rests on: pairs, or the smaller side's episodes."""
        return self.pairs if self.paired else min(self.baseline_n, self.candidate_n)

    def worse_bound(self) -> float:
        """The interval's end in the worse direction, as a loss (positive = worse)."""
        return -self.interval.low if self.better == "higher" else self.interval.high

    def to_dict(self) -> dict[str, Any]:
        """The metric as JSON-able values (``docs/compare.md``)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "better": self.better,
            "baseline": _finite(self.baseline),
            "candidate": _finite(self.candidate),
            "baseline_n": self.baseline_n,
            "candidate_n": self.candidate_n,
            "difference": _finite(self.difference),
            "interval": {"low": _finite(self.interval.low), "high": _finite(self.interval.high)},
            "paired": self.paired,
            "pairs": self.pairs,
            "test": self.test,
            "p_value": _finite(self.p_value),
            "p_adjusted": _finite(self.p_adjusted),
            "margin": _finite(self.margin),
            "mde": _finite(self.mde),
            "n_needed": None if self.n_needed >= stats.NEVER else self.n_needed,
            "verdict": self.verdict,
            "baseline_iqm": _finite(self.baseline_iqm),
            "candidate_iqm": _finite(self.candidate_iqm),
            "can_reject": self.can_reject,
            "same_test_as": self.same_test_as,
            "not_comparable": self.not_comparable,
        }


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def rate_metric(
    name: str,
    base: Array,
    cand: Array,
    pairs: Pairs,
    *,
    better: Literal["higher", "lower", "none"],
    margin: float,
) -> MetricComparison:
    """Compare the rate of ``True`` in two boolean arrays (one value per ended episode).

    ``better`` ``"none"``: a rate shown with its difference and interval, and no verdict
    (``truncation_rate``: reaching the time limit is a survival task's success, a goal task's
    timeout).
    """
    nb, nc = len(base), len(cand)
    if pairs.usable:
        x, y = base[pairs.base], cand[pairs.cand]
        n = len(x)
        a, b = int(np.sum(x & y)), int(np.sum(x & ~y))
        c, d = int(np.sum(~x & y)), int(np.sum(~x & ~y))
        diff = (c - b) / n
        psi = (b + c + 1) / (n + 2)  # discordant share, kept off 0 for planning
        variance = max(psi - diff * diff, psi / (n + 2))
        mde, needed = stats.planning(variance, math.sqrt(variance / n), margin)
        return MetricComparison(
            name, "rate", better, (a + b) / n, (a + c) / n, n, n, diff,
            stats.newcombe_paired(a, b, c, d), True, n, "McNemar exact",
            stats.mcnemar_exact(b, c), margin, mde, needed, can_reject=b + c >= 2,
        )  # fmt: skip
    xb, xc = int(np.sum(base)), int(np.sum(cand))
    vb, vc = _plan_variance(xb, nb), _plan_variance(xc, nc)
    mde, needed = stats.planning(vb + vc, math.sqrt(vb / nb + vc / nc), margin)
    return MetricComparison(
        name, "rate", better, xb / nb, xc / nc, nb, nc, xc / nc - xb / nb,
        stats.newcombe_unpaired(xb, nb, xc, nc), False, len(pairs), "Fisher exact",
        stats.fisher_p_value(xb, nb, xc, nc), margin, mde, needed,
        can_reject=0 < xb + xc < nb + nc,
    )  # fmt: skip


def _plan_variance(x: int, n: int) -> float:
    """A rate's Bernoulli variance for planning, from ``(x + 1) / (n + 2)`` (never 0)."""
    p = (x + 1) / (n + 2)
    return p * (1 - p)


def mean_metric(
    name: str,
    base: Array,
    cand: Array,
    pairs: Pairs,
    *,
    better: Literal["higher", "none"],
    margin: float | None,
) -> MetricComparison:
    """Compare the means of two float arrays (one value per ended episode).

    ``margin`` ``None`` takes half the baseline's standard deviation (Cohen's d = 0.5). The n
    needed is at least :func:`~.stats.fewest`: below it there is no interval
    (:func:`~.stats.too_few`).
    """
    nb, nc = len(base), len(cand)
    paired = pairs.usable
    if paired:
        x, y = base[pairs.base], cand[pairs.cand]
        variance = float(np.var(y - x, ddof=1))
        se = math.sqrt(variance / len(x))
    else:
        x, y = base, cand
        vb = float(np.var(x, ddof=1)) if nb > 1 else math.inf
        vc = float(np.var(y, ddof=1)) if nc > 1 else math.inf
        variance, se = vb + vc, math.sqrt(vb / nb + vc / nc)
    if margin is None:
        spread = base if nb > 1 else cand
        margin = 0.5 * float(np.std(spread, ddof=1)) if len(spread) > 1 else 0.0
    mde, needed = stats.planning(variance, se, margin)
    if needed < stats.NEVER:  # (fewer cannot reach p < ALPHA in the exact test: no interval)
        needed = max(needed, stats.fewest(paired=paired))
    return MetricComparison(
        name, "mean", better, float(np.mean(x)), float(np.mean(y)), len(x), len(y),
        float(np.mean(y) - np.mean(x)), stats.mean_difference_interval(x, y, paired=paired),
        paired, len(pairs), "paired t" if paired else "Welch t",
        stats.mean_p_value(x, y, paired=paired), margin, mde, needed,
        baseline_iqm=stats.iqm(x), candidate_iqm=stats.iqm(y),
        can_reject=_can_reject(x, y, paired),
    )  # fmt: skip


def not_compared(metric: MetricComparison, why: str) -> MetricComparison:
    """``metric`` with its sides' values in different units (``why``): no difference, no test.

    Each side's mean stays (in its own units); the difference, its interval, the p-value and
    the planning figures go (``nan``: ``null`` in JSON), the test is ``none``, and the
    verdict will be ``inconclusive`` (:func:`decide`).
    """
    nan = math.nan
    return replace(
        metric, difference=nan, interval=Interval(nan, nan), test="none", p_value=nan, mde=nan,
        n_needed=stats.NEVER, can_reject=False,
        not_comparable=why,
    )  # fmt: skip


def not_computable(
    name: str,
    kind: Literal["rate", "mean"],
    better: Literal["higher", "lower", "none"],
    base: Array,
    cand: Array,
    margin: float | None,
    why: str,
) -> MetricComparison:
    """A metric over ended episodes of which a side has none (``why``): no difference, no test.

    The side that has some keeps its value; the other's is ``None``. As :func:`not_compared`
    otherwise: the verdict will be ``inconclusive`` and a gate cannot be verified.
    """
    nan = math.nan

    def value(values: Array) -> float | None:
        return float(np.mean(values)) if len(values) else None

    return MetricComparison(
        name, kind, better, value(base), value(cand), len(base), len(cand), nan,
        Interval(nan, nan), False, 0, "none", nan, nan if margin is None else margin, nan,
        stats.NEVER, can_reject=False, not_comparable=why,
    )  # fmt: skip


def _can_reject(x: Array, y: Array, paired: bool) -> bool:
    """Whether a test of the means of ``x`` and ``y`` can give a p below 1 at all."""
    if min(len(x), len(y)) < 2 or not (np.isfinite(x).all() and np.isfinite(y).all()):
        return False
    values = y - x if paired else np.concatenate([x, y])
    return bool(np.ptp(values) > 0 or (paired and values[0] != 0))


def settle(metric: MetricComparison) -> None:
    """Set the verdict of a metric whose ``p_adjusted`` is set, and an n needed that agrees.

    The planning n (:func:`~.stats.planning`) is the normal approximation's; a metric it
    calls enough for that is still ``inconclusive`` when its interval, as computed, reaches
    past the margin. Its n needed is then the interval's (:func:`interval_n_needed`): more units
    than it has (it is ``underpowered``), or none enough (``inconclusive``, n needed never).
    """
    metric.verdict = decide(metric)
    if metric.verdict != "inconclusive" or metric.not_comparable is not None:
        return
    if not math.isfinite(metric.difference):
        return
    metric.n_needed = interval_n_needed(metric)
    if metric.n_needed < stats.NEVER:
        metric.verdict = decide(metric)


def interval_n_needed(metric: MetricComparison) -> int:
    """The units an interval like this one needs for its worse end to come within the margin.

    The worse side's half-width ``h`` shrinks as ``1 / sqrt(n)``: with ``loss`` the point
    difference's distance in the worse direction, ``n' = ceil(n * (h / (margin - loss))**2)``,
    at least ``n + 1`` and the planning n; :data:`~.stats.NEVER` when the point difference
    itself is at or beyond the margin (no n makes that interval's worse end fall within it).

    >>> m = MetricComparison("failure_rate", "rate", "lower", 0.0, 0.0, 72, 72, 0.0,
    ...     Interval(-0.0507, 0.0507), True, 72, "McNemar exact", 1.0, 0.05, 0.038, 43)
    >>> interval_n_needed(m)
    75
    """
    loss = -metric.difference if metric.better == "higher" else metric.difference
    half, room = metric.worse_bound() - loss, metric.margin - loss
    if room <= 0:
        return stats.NEVER
    n = metric.analysed
    if not math.isfinite(half):
        return metric.n_needed
    return max(metric.n_needed, n + 1, math.ceil(n * (half / room) ** 2))


def decide(metric: MetricComparison, alpha: float = stats.ALPHA) -> Verdict:
    """The verdict of a metric whose ``p_adjusted`` is set.

    ``regressed`` / ``improved``: the adjusted p-value is below ``alpha``, the difference worse /
    better; ``held``: the interval's worse end is within the margin; ``underpowered``: neither,
    and fewer units than ``n_needed``; ``inconclusive``: neither, with enough units, or the
    difference is not finite (a return that is not: no number of episodes would tell). A mean
    of too few episodes to bound its difference (:func:`~.stats.too_few`) is ``underpowered``
    whatever its t-test says: no exact test could reject there, and its interval is unbounded.
    A mean whose sides are in different units (``not_comparable``) is ``inconclusive``.
    """
    if metric.not_comparable is not None or not math.isfinite(metric.difference):
        return "inconclusive"
    if metric.kind == "mean" and stats.too_few(
        metric.baseline_n, metric.candidate_n, paired=metric.paired
    ):
        return "underpowered"
    p = metric.p_value if metric.p_adjusted is None else metric.p_adjusted
    gain = metric.difference if metric.better == "higher" else -metric.difference
    if p < alpha and gain != 0:
        return "improved" if gain > 0 else "regressed"
    if metric.worse_bound() <= metric.margin:
        return "held"
    if metric.analysed < metric.n_needed:
        return "underpowered"
    return "inconclusive"
