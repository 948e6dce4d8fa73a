"""The statistics against published worked examples and scipy's own results."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from episode_audit.compare import stats


@pytest.mark.parametrize(
    ("x2", "n2", "x1", "n1", "low", "high"),
    [  # Newcombe (1998a) Table II, method 10: x2/n2 - x1/n1; statsmodels 0.15.0's
        # confint_proportions_2indep(x2, n2, x1, n1, method="newcomb") gives the same 8 rows
        (56, 70, 48, 80, 0.0524, 0.3339),
        (9, 10, 3, 10, 0.1705, 0.8090),
        (6, 7, 2, 7, 0.0582, 0.8062),
        (5, 56, 0, 29, -0.0381, 0.1926),
        (0, 10, 0, 20, -0.1611, 0.2775),
        (0, 10, 0, 10, -0.2775, 0.2775),
        (10, 10, 0, 20, 0.6791, 1.0),
        (10, 10, 0, 10, 0.6075, 1.0),
        # Fagerland, Lydersen & Laake (2017), ch. 4: Perondi et al. 2004, 7/34 - 1/34
        (7, 34, 1, 34, 0.0189, 0.3404),
    ],
)
def test_newcombe_unpaired_matches_the_published_examples(
    x2: int, n2: int, x1: int, n1: int, low: float, high: float
) -> None:
    ci = stats.newcombe_unpaired(x1, n1, x2, n2)
    assert (round(ci.low, 4), round(ci.high, 4)) == (low, high)


def test_newcombe_paired_matches_the_published_example() -> None:
    # Fagerland, Lydersen & Laake (2017), ch. 8: Cavo et al. 2012, table [[59, 6], [16, 80]]:
    # p1 - p2 = (6 - 16) / 161 = -0.0621, 95 % CI -0.1186 to -0.0046. Ours is candidate minus
    # baseline, so the baseline is the table's second margin: a=59, b=16, c=6, d=80.
    ci = stats.newcombe_paired(59, 16, 6, 80)
    assert (round(ci.low, 4), round(ci.high, 4)) == (-0.1186, -0.0046)
    mirrored = stats.newcombe_paired(59, 6, 16, 80)
    assert (round(mirrored.low, 4), round(mirrored.high, 4)) == (0.0046, 0.1186)


def test_newcombe_paired_phi_correction_only_past_n_over_2() -> None:
    # ad - bc = 1 <= n/2: phi is 0, so the interval is the unpaired square-and-add of the margins
    ci = stats.newcombe_paired(1, 1, 7, 12)
    n = 21
    w1, w2 = stats.wilson_interval(2, n), stats.wilson_interval(8, n)
    d = 8 / n - 2 / n
    assert ci.low == pytest.approx(d - math.hypot(8 / n - w2.low, w1.high - 2 / n))


@pytest.mark.parametrize(
    ("b", "c", "p"), [(16, 6, 0.0525), (3, 3, 1.0), (0, 0, 1.0), (0, 7, 0.0156)]
)
def test_mcnemar_exact_is_the_binomial_test_of_discordant_pairs(b: int, c: int, p: float) -> None:
    assert round(stats.mcnemar_exact(b, c), 4) == p


def test_fisher_p_value_is_scipys() -> None:
    assert stats.fisher_p_value(48, 80, 56, 70) == pytest.approx(
        sps.fisher_exact([[48, 32], [56, 14]]).pvalue
    )


def test_holm_step_down() -> None:
    # Holm (1979): sorted p times (m, m-1, ...), made monotone, capped at 1
    assert stats.holm([0.01, 0.02, 0.03, 0.5]) == pytest.approx([0.04, 0.06, 0.06, 0.5])
    assert stats.holm([0.9, 0.8]) == [1.0, 1.0]  # 2 * 0.8, capped
    assert stats.holm([]) == []


def test_planning_formulas() -> None:
    z = sps.norm.ppf(0.975) + sps.norm.ppf(0.8)
    mde, needed = stats.planning(0.5, 0.1, 0.1)
    assert mde == pytest.approx(z * 0.1)
    assert needed == math.ceil(z * z * 0.5 / 0.01)
    assert stats.planning(math.inf, math.inf, 0.1) == (math.inf, stats.NEVER)


def test_the_paired_interval_keeps_pairs_together_and_covers_the_mean_difference() -> None:
    rng = np.random.default_rng(1)
    base = rng.normal(0, 10, 60)
    cand = base + rng.normal(1.0, 0.5, 60)  # strongly paired: the spread is in the base
    paired = stats.mean_difference_interval(base, cand, paired=True)
    unpaired = stats.mean_difference_interval(base, cand, paired=False)
    diff = float(np.mean(cand - base))
    assert paired.low < diff < paired.high
    assert paired.high - paired.low < 0.5  # about 2 * 1.96 * 0.5 / sqrt(60)
    assert unpaired.high - unpaired.low > 5 * (paired.high - paired.low)


def test_mean_interval_of_degenerate_data() -> None:
    same = np.ones(6)  # 6 pairs: the sign test's p can be 2/64, below 0.05
    assert stats.mean_difference_interval(same, same + 2, paired=True) == stats.Interval(2.0, 2.0)
    assert stats.mean_difference_interval(same, same, paired=False) == stats.Interval(0.0, 0.0)
    unbounded = stats.Interval(-math.inf, math.inf)  # 5 pairs: p is at least 2/32
    assert stats.mean_difference_interval(same[:5], same[:5] + 2, paired=True) == unbounded
    one = stats.mean_difference_interval(np.array([1.0]), np.array([1.0, 2.0]), paired=False)
    assert one.low == -math.inf and one.high == math.inf


@pytest.mark.parametrize(
    ("n1", "n2", "paired", "bounded"),
    [(2, 2, False, False), (3, 3, False, False), (2, 4, False, False), (2, 5, False, True),
     (4, 4, False, True), (1, 30, False, False), (5, 5, True, False), (6, 6, True, True)],
)  # fmt: skip
def test_no_interval_below_the_exact_tests_reach(
    n1: int, n2: int, paired: bool, bounded: bool
) -> None:
    """Below the size where the exact permutation test can reach p < 0.05 no interval is given,
    with spread or without."""
    rng = np.random.default_rng(0)
    base, cand = rng.normal(0, 1, n1), rng.normal(0, 1, n2)
    ci = stats.mean_difference_interval(base, cand, paired=paired)
    assert math.isfinite(ci.low) == math.isfinite(ci.high) == bounded
    assert (stats.too_few(n1, n2, paired=paired) is None) == bounded
    assert (stats.smallest_p(n1, n2, paired=paired) < stats.ALPHA) == (bounded or n1 < 2)


@pytest.mark.parametrize(
    ("n", "paired"), [(1024, True), (5000, True), (600, False), (60000, False)]
)
def test_many_episodes_bound_the_difference(n: int, paired: bool) -> None:
    # 2.0 ** 1024 overflows a float: compare raised OverflowError at 1 024 pairs
    rng = np.random.default_rng(1)
    base = rng.normal(0, 1, n)
    assert stats.smallest_p(n, n, paired=paired) < 1e-100
    assert stats.too_few(n, n, paired=paired) is None
    ci = stats.mean_difference_interval(base, base + rng.normal(0, 0.1, n), paired=paired)
    assert math.isfinite(ci.low) and math.isfinite(ci.high)
    assert stats.no_spread_p_value(np.ones(n), np.zeros(n), paired=paired) < 1e-100
    exact = 2 / math.comb(2 * 400, 400)  # the logarithm's value agrees where both are floats
    assert stats.smallest_p(400, 400, paired=False) == exact
    assert math.isclose(stats.smallest_p(501, 501, paired=False), 2 / math.comb(1002, 501))


@pytest.mark.parametrize("paired", [False, True])
def test_the_mean_interval_excludes_zero_exactly_when_its_t_test_rejects(paired: bool) -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(6, 30))
        base = rng.normal(0.0, 1.0, n)
        cand = base + rng.normal(0.4, 1.0, n) if paired else rng.normal(0.4, 1.0, n)
        ci = stats.mean_difference_interval(base, cand, paired=paired)
        p = stats.mean_p_value(base, cand, paired=paired)
        assert (ci.low > 0 or ci.high < 0) == (p < stats.ALPHA)


def test_mean_p_value_is_scipys_t_tests() -> None:
    rng = np.random.default_rng(2)
    a, b = rng.normal(0, 1, 30), rng.normal(0.5, 2, 30)
    assert stats.mean_p_value(a, b, paired=True) == pytest.approx(sps.ttest_rel(b, a).pvalue)
    assert stats.mean_p_value(a, b, paired=False) == pytest.approx(
        sps.ttest_ind(b, a, equal_var=False).pvalue
    )


def test_iqm() -> None:
    assert stats.iqm(np.arange(8.0)) == pytest.approx(3.5)
    assert stats.iqm(np.array([])) is None


@pytest.mark.parametrize(
    ("base", "cand", "paired", "p"),
    [
        ([1.0, 1.0], [0.0, 0.0], False, 1 / 3),  # 2 of the 6 splits of {1, 1, 0, 0}
        ([1.0, 1.0], [0.0, 0.0], True, 0.5),  # 2 of the 4 sign flips
        ([5.0] * 4, [4.0] * 4, False, 2 / 70),
        ([5.0] * 3, [4.0] * 2, False, 1 / 10),  # sizes differ: no mirror image
        ([5.0] * 6, [4.0] * 6, True, 2 / 64),
        ([1.0, 2.0, 3.0], [2.0, 3.0, 4.0], True, 0.25),  # every difference +1
        ([3.0, 3.0], [3.0, 3.0], False, 1.0),
    ],
)
def test_a_difference_without_spread_gets_the_exact_permutation_p_not_0(
    base: list[float], cand: list[float], paired: bool, p: float
) -> None:
    got = stats.mean_p_value(np.array(base), np.array(cand), paired=paired)
    assert got == pytest.approx(p)


def test_mean_p_value_keeps_scipys_precision_warnings_to_itself() -> None:
    import warnings

    base, cand = np.array([1.0, 1.0, 1.0]), np.array([1.0, 1.0, 1.0 + 1e-12])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stats.mean_p_value(base, cand, paired=False)
        stats.mean_p_value(base, cand, paired=True)
