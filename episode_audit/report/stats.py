"""The statistics a report is built with.

- :class:`Interval` and :func:`wilson_interval`: the Wilson score interval of a proportion
  (at :data:`Z_95` by default);
- :func:`rate`, :func:`mean_std` and :func:`counts`: a rate over the ended episodes, the mean and
  (population) standard deviation of some values, and how often each value occurs;
- :func:`rate_text`: a rate and its interval as the report's tables and page show them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Z_95", "Interval", "counts", "mean_std", "rate", "rate_text", "wilson_interval"]

Z_95 = 1.959963984540054
"""The two-sided 95 % normal quantile."""


@dataclass(frozen=True)
class Interval:
    """A closed interval ``[low, high]``."""

    low: float
    high: float


def rate_text(value: float | None, ci: Interval | None = None) -> str:
    """A rate as a percentage, its interval in percent too (``-`` when there is no rate).

    >>> rate_text(0.574, Interval(0.5602, 0.5897)), rate_text(1.0, Interval(0.965, 1.0))
    ('57.4% [56.0, 59.0]', '100.0% [96.5, 100.0]')
    >>> rate_text(0.25), rate_text(None)
    ('25.0%', '-')
    """
    if value is None:
        return "-"
    text = f"{value:.1%}"
    return text if ci is None else f"{text} [{ci.low * 100:.1f}, {ci.high * 100:.1f}]"


def wilson_interval(successes: int, n: int, z: float = Z_95) -> Interval:
    """Return the Wilson score interval of ``successes`` out of ``n`` trials.

    Unlike the normal approximation it stays inside [0, 1] and is sensible at 0 and n.

    >>> ci = wilson_interval(8, 10)
    >>> round(ci.low, 4), round(ci.high, 4)
    (0.4902, 0.9433)
    >>> wilson_interval(0, 10).low, round(wilson_interval(0, 10).high, 4)
    (0.0, 0.2775)
    >>> wilson_interval(1, 0)
    Traceback (most recent call last):
    ...
    ValueError: Expect 0 <= successes <= n and n >= 1, actually: successes=1, n=0
    """
    if not (0 <= successes <= n and n >= 1):
        raise ValueError(
            f"Expect 0 <= successes <= n and n >= 1, actually: successes={successes}, n={n}"
        )
    p = successes / n
    z2 = z * z
    denominator = 1.0 + z2 / n
    center = (p + z2 / (2 * n)) / denominator
    half = z / denominator * math.sqrt(p * (1.0 - p) / n + z2 / (4 * n * n))
    low = 0.0 if successes == 0 else max(0.0, center - half)
    high = 1.0 if successes == n else min(1.0, center + half)
    return Interval(low, high)


def rate(count: int, total: int) -> float | None:
    """``count / total``, or ``None`` when there is nothing to count over.

    >>> rate(1, 4), rate(0, 0)
    (0.25, None)
    """
    return count / total if total else None


def mean_std(values: np.ndarray[Any, Any]) -> tuple[float | None, float | None]:
    """The mean and population standard deviation of ``values`` (``None`` when empty)."""
    if values.size == 0:
        return None, None
    return float(np.mean(values)), float(np.std(values))


def counts(values: Iterable[str]) -> dict[str, int]:
    """How often each value occurs, sorted by value.

    >>> counts(["b", "a", "b"])
    {'a': 1, 'b': 2}
    """
    out: dict[str, int] = {}
    for value in values:
        out[value] = out.get(value, 0) + 1
    return dict(sorted(out.items()))
