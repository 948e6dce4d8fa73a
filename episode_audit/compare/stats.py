"""The statistics of a comparison, each cited in ``docs/compare.md``.

- rates: :func:`newcombe_unpaired` (Newcombe 1998a, method 10) with Fisher's exact test;
  :func:`newcombe_paired` (Newcombe 1998b, method 10) with :func:`mcnemar_exact`;
- means: :func:`mean_difference_interval` (the paired or Welch t interval) with its t-test
  (:func:`mean_p_value`; without spread, the exact permutation test, :func:`no_spread_p_value`);
  no interval where that test could not reach p < :data:`ALPHA` (:func:`too_few`); :func:`iqm`;
- :func:`holm` (Holm 1979); :func:`planning` (minimum detectable effect, n needed).

The tests and intervals are scipy's (``scipy.stats``); Newcombe's intervals are sums of squares of
Wilson limits (:func:`~episode_audit.report.stats.wilson_interval`) scipy has no function for.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..report.stats import Interval, wilson_interval

__all__ = [
    "ALPHA",
    "POWER",
    "fewest",
    "fisher_p_value",
    "holm",
    "iqm",
    "mean_difference_interval",
    "mcnemar_exact",
    "mean_p_value",
    "newcombe_paired",
    "newcombe_unpaired",
    "no_spread_p_value",
    "planning",
    "smallest_p",
    "too_few",
]

ALPHA = 0.05
"""Two-sided level of the tests; the intervals are ``1 - ALPHA``."""
POWER = 0.8
"""The power the minimum detectable effect and the n needed are stated for."""
NEVER = 2**31 - 1
"""The n needed when no n is enough (a margin of 0 with spread, or no spread known)."""

Array = np.ndarray[Any, Any]


def _stats() -> Any:
    """``scipy.stats``, imported on first use (it takes a while; most commands never need it)."""
    import scipy.stats

    return scipy.stats


def newcombe_unpaired(x1: int, n1: int, x2: int, n2: int) -> Interval:
    """Newcombe's hybrid score interval (1998a, method 10) for ``x2/n2 - x1/n1``.

    >>> ci = newcombe_unpaired(48, 80, 56, 70)  # Newcombe 1998a, example (a)
    >>> round(ci.low, 4), round(ci.high, 4)
    (0.0524, 0.3339)
    """
    p1, p2 = x1 / n1, x2 / n2
    w1, w2 = wilson_interval(x1, n1), wilson_interval(x2, n2)
    d = p2 - p1
    low = d - math.sqrt((p2 - w2.low) ** 2 + (w1.high - p1) ** 2)
    high = d + math.sqrt((w2.high - p2) ** 2 + (p1 - w1.low) ** 2)
    return Interval(max(-1.0, low), min(1.0, high))


def newcombe_paired(a: int, b: int, c: int, d: int) -> Interval:
    """Newcombe's score interval (1998b, method 10) for a paired difference of proportions.

    The pairs: ``a`` both sides succeed, ``b`` only the baseline, ``c`` only the candidate,
    ``d`` neither; the difference is the candidate's rate minus the baseline's, ``(c - b) / n``.

    >>> ci = newcombe_paired(59, 16, 6, 80)  # Fagerland et al. 2017, ch. 8 (Cavo et al.)
    >>> round(ci.low, 4), round(ci.high, 4)
    (-0.1186, -0.0046)
    """
    n = a + b + c + d
    base, cand = a + b, a + c  # successes of each side
    p1, p2 = base / n, cand / n
    w1, w2 = wilson_interval(base, n), wilson_interval(cand, n)
    phi = 0.0
    margins = base * (n - base) * cand * (n - cand)
    if margins > 0:
        cross = a * d - b * c
        if cross > n / 2:  # Newcombe's correction of phi for a positive association
            phi = (cross - n / 2) / math.sqrt(margins)
        elif cross < 0:
            phi = cross / math.sqrt(margins)
    diff = p2 - p1
    lo2, hi1 = p2 - w2.low, w1.high - p1
    hi2, lo1 = w2.high - p2, p1 - w1.low
    low = diff - math.sqrt(max(0.0, lo2**2 - 2 * phi * lo2 * hi1 + hi1**2))
    high = diff + math.sqrt(max(0.0, hi2**2 - 2 * phi * hi2 * lo1 + lo1**2))
    return Interval(max(-1.0, low), min(1.0, high))


def mcnemar_exact(b: int, c: int) -> float:
    """The exact McNemar p-value (``scipy.stats.binomtest``).

    A two-sided binomial test of ``c`` of the ``b + c`` discordant pairs at 1/2; 1.0 without
    discordant pairs.

    >>> round(mcnemar_exact(16, 6), 4)
    0.0525
    """
    if b + c == 0:
        return 1.0
    return float(_stats().binomtest(c, b + c, 0.5).pvalue)


def fisher_p_value(x1: int, n1: int, x2: int, n2: int) -> float:
    """Fisher's exact two-sided p-value for ``x1/n1`` against ``x2/n2``."""
    table = [[x1, n1 - x1], [x2, n2 - x2]]
    return float(_stats().fisher_exact(table).pvalue)


def mean_difference_interval(base: Array, cand: Array, *, paired: bool) -> Interval:
    """The 95 % t interval of ``mean(cand) - mean(base)``: paired t, or Welch's (unpaired).

    The interval of the test :func:`mean_p_value` gives the p-value of (``scipy.stats``'s
    ``ttest_rel`` / ``ttest_ind(equal_var=False)``, ``confidence_interval``): it excludes a
    difference exactly when that test rejects it. Too few values to bound the difference
    (:func:`too_few`: a side of one, or fewer than the exact permutation test needs to reach
    p < :data:`ALPHA`) give ``(-inf, inf)``. Data without spread and enough values give the
    point difference: the exact permutation test then rejects every other shift (the interval
    is that test's, inverted).

    >>> mean_difference_interval(np.array([21.0]), np.array([0.0]), paired=False)
    Interval(low=-inf, high=inf)
    >>> mean_difference_interval(np.array([1.0, 1.0]), np.array([3.0, 3.0]), paired=False)
    Interval(low=-inf, high=inf)
    >>> mean_difference_interval(np.ones(4), np.full(4, 3.0), paired=False)
    Interval(low=2.0, high=2.0)
    >>> ci = mean_difference_interval(np.arange(4.0), np.arange(4.0) + 5, paired=False)
    >>> round(ci.low, 3), round(ci.high, 3)
    (2.766, 7.234)
    """
    diff = float(np.mean(cand) - np.mean(base))
    if too_few(len(base), len(cand), paired=paired) is not None:
        return Interval(-math.inf, math.inf)
    if (np.ptp(cand - base) == 0) if paired else (np.ptp(base) == np.ptp(cand) == 0):
        return Interval(diff, diff)
    with warnings.catch_warnings():  # (scipy's precision-loss warning: data nearly constant)
        warnings.simplefilter("ignore", RuntimeWarning)
        if paired:
            result = _stats().ttest_rel(cand, base)
        else:
            result = _stats().ttest_ind(cand, base, equal_var=False)
        ci = result.confidence_interval(confidence_level=1 - ALPHA)
    low, high = float(ci.low), float(ci.high)
    if not (math.isfinite(low) and math.isfinite(high)):
        return Interval(-math.inf, math.inf)
    return Interval(low, high)


def smallest_p(n1: int, n2: int, *, paired: bool) -> float:
    """The smallest two-sided p-value the exact permutation test of a difference of means gives.

    Paired (``n1`` pairs): ``2 / 2**n1``, all signs alike; unpaired: ``2 / comb(n1 + n2, n1)``
    (the split seen and its mirror image) when ``n1 == n2``, else ``1 / comb(n1 + n2, n1)``.

    >>> smallest_p(5, 5, paired=True), smallest_p(3, 3, paired=False)
    (0.0625, 0.1)
    >>> smallest_p(5000, 5000, paired=True), smallest_p(50000, 50000, paired=False)
    (0.0, 0.0)
    """
    if paired:
        return min(1.0, math.ldexp(1.0, 1 - n1))  # (2 / 2**n1, as 0.0 past a float's range)
    splits = 2 if n1 == n2 else 1
    if n1 + n2 <= _EXACT_COMB:
        return min(1.0, splits / math.comb(n1 + n2, n1))
    log_comb = math.lgamma(n1 + n2 + 1) - math.lgamma(n1 + 1) - math.lgamma(n2 + 1)
    return math.exp(math.log(splits) - log_comb)  # (0.0 long before this many episodes)


_EXACT_COMB = 1000
"""Above this many episodes in all, :func:`smallest_p`'s count of splits is taken by its
logarithm: the exact count's digits take time (0.3 s at 100 000 a side) for a p-value that
is 0.0 as a float anyway."""


def fewest(*, paired: bool) -> int:
    """The fewest pairs, or episodes a side, whose exact permutation test can reach p < ALPHA.

    >>> fewest(paired=True), fewest(paired=False)
    (6, 4)
    """
    n = 2
    while smallest_p(n, n, paired=paired) >= ALPHA:
        n += 1
    return n


def too_few(n1: int, n2: int, *, paired: bool) -> str | None:
    """Why ``n1`` and ``n2`` values (paired: ``n1`` pairs) cannot bound a difference of means.

    ``None`` when they can. A side of one value has no spread to tell from none. Below
    :func:`fewest`, no exact test can reach p < :data:`ALPHA` whatever the values, so no 95 %
    interval excludes any difference without assuming how returns are distributed
    (``docs/compare.md``).

    >>> too_few(2, 2, paired=False).split(":")[0]
    '2 episodes a side are too few'
    >>> too_few(10, 10, paired=True) is None
    True
    """
    unit = "pair" if paired else "episode"
    if min(n1, n2) < 2:
        side = "" if paired else " a side"
        return f"one {unit}{side} has no spread to resample (at least 2 needed)"
    p = smallest_p(n1, n2, paired=paired)
    if p < ALPHA:
        return None
    least = fewest(paired=paired)
    have = f"{n1} pairs are" if paired else (
        f"{n1} episodes a side are" if n1 == n2 else f"{n1} and {n2} episodes are"
    )  # fmt: skip
    need = f"{least} pairs" if paired else f"{least} a side"
    return f"{have} too few: an exact test's p is at least {p:.3g} ({need} can reach p < {ALPHA})"


def mean_p_value(base: Array, cand: Array, *, paired: bool) -> float:
    """The two-sided p-value of a difference of means: paired t-test or Welch's t-test.

    1.0 with fewer than two values a side. Without spread (every pair's difference the same,
    or each side constant) the t statistic is undefined, and a tiny sample without spread is
    no evidence: p is then the exact permutation test's (:func:`no_spread_p_value`).

    >>> mean_p_value(np.array([1.0, 1.0]), np.array([0.0, 0.0]), paired=False)
    0.3333333333333333
    """
    if min(len(base), len(cand)) < 2:
        return 1.0
    flat = np.ptp(cand - base) == 0 if paired else np.ptp(base) == np.ptp(cand) == 0
    if flat:
        return no_spread_p_value(base, cand, paired=paired)
    with warnings.catch_warnings():  # (scipy's precision-loss warning: data nearly constant)
        warnings.simplefilter("ignore", RuntimeWarning)
        if paired:
            p = _stats().ttest_rel(cand, base).pvalue
        else:
            p = _stats().ttest_ind(cand, base, equal_var=False).pvalue
    return 1.0 if math.isnan(float(p)) else float(p)


def no_spread_p_value(base: Array, cand: Array, *, paired: bool) -> float:
    """The exact permutation p-value (Pitman 1937) of a difference of means without spread.

    Paired, every difference ``d`` the same: of the ``2**n`` sign flips of the differences, the
    two with all signs alike are as extreme, so ``p = min(1, 2 / 2**n)`` (the sign test); 1.0
    when ``d`` is 0. Unpaired, each side constant: of the ``comb(n1 + n2, n1)`` ways to split
    the values, the one seen (every baseline value apart from every candidate value) is as
    extreme as any, and so is its mirror image when ``n1 == n2``; 1.0 when the sides are equal.

    >>> no_spread_p_value(np.ones(2), np.zeros(2), paired=True)  # 2 pairs: 1 in 2
    0.5
    >>> no_spread_p_value(np.ones(6), np.zeros(6), paired=True)
    0.03125
    >>> round(no_spread_p_value(np.ones(4), np.zeros(4), paired=False), 4)  # 2 in 70
    0.0286
    """
    if float(np.mean(cand)) == float(np.mean(base)):
        return 1.0
    return smallest_p(len(base), len(cand), paired=paired)


def iqm(values: Array) -> float | None:
    """The interquartile mean (mean of the middle 50 %, ``scipy.stats.trim_mean(x, 0.25)``).

    >>> iqm(np.array([0.0, 1.0, 2.0, 3.0, 100.0]))
    2.0
    """
    return float(_stats().trim_mean(values, 0.25)) if len(values) else None


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values (Holm 1979), in the order given.

    scipy has no Holm adjustment (``false_discovery_control`` is Benjamini-Hochberg).

    >>> [round(p, 6) for p in holm([0.01, 0.04, 0.03])]
    [0.03, 0.06, 0.06]
    """
    order = sorted(range(len(p_values)), key=lambda i: p_values[i])
    adjusted = [1.0] * len(p_values)
    running = 0.0
    m = len(p_values)
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


def planning(variance: float, se: float, margin: float) -> tuple[float, int]:
    """The minimum detectable effect now and the n (a side, or pairs) needed to detect ``margin``.

    ``variance`` is the difference's variance per unit (the sum of one episode's variance on each
    side, or one pair's), ``se`` the difference's standard error now. With
    ``z = z(1 - ALPHA/2) + z(POWER)``: ``MDE = z * se`` and
    ``n_needed = ceil(z**2 * variance / margin**2)`` (at least 2).

    >>> mde, needed = planning(0.5, 0.05, 0.2)
    >>> round(mde, 4), needed
    (0.1401, 99)
    """
    norm = _stats().norm
    z = float(norm.ppf(1 - ALPHA / 2) + norm.ppf(POWER))
    if not math.isfinite(variance):  # a side of one episode: no spread to plan with
        return math.inf, NEVER
    if margin <= 0:
        return z * se, 2 if variance == 0 else NEVER
    return z * se, max(2, math.ceil(z * z * variance / (margin * margin)))
