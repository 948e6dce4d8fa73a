"""One group of episodes: its outcome counts, rates and statistics (:class:`GroupReport`).

:func:`group_reports` splits the tables :func:`~.collect.collect` returns by group key and makes
each group's report: counts, rates over the ended episodes with Wilson intervals, return and
length statistics, mean reward-term totals per outcome and incentive warnings.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.records import to_jsonable
from .collect import ENDED
from .incentives import IncentiveWarning, incentive_warnings
from .stats import Interval, counts, mean_std, rate, wilson_interval

__all__ = ["GroupReport", "group_reports"]


@dataclass
class GroupReport:
    """Outcome counts, rates and statistics of one group of episodes.

    Rates are over ``ended`` (success + failure + truncated) and ``None`` when no episode ended,
    or when the grouping gives every group one outcome (by label, :func:`group_reports`).
    Return and length statistics are over the ended episodes (population standard deviation).
    ``term_means[outcome][term]`` is the mean per-episode total of a reward term over the ended
    episodes of that outcome (declared constant terms included, as constant x length).
    """

    key: str
    episodes: int
    ended: int
    success: int
    success_rate: float | None
    success_ci: Interval | None
    failures: dict[str, int]
    failure_rate: float | None
    truncations: dict[str, int]
    truncation_rate: float | None
    incomplete: int
    errors: int
    terminated_and_truncated: int
    return_mean: float | None
    return_std: float | None
    length_mean: float | None
    length_std: float | None
    term_means: dict[str, dict[str, float]]
    warnings: list[IncentiveWarning]
    failure_ci: Interval | None = None
    truncation_ci: Interval | None = None
    nonfinite_returns: int = 0
    """The ended episodes whose return is not finite (NaN or infinite): the return statistics
    are then not finite, and the incentive warnings leave them out."""
    success_signal: bool = True
    """Whether the task reports success: some file of the group says its task did (a success
    key in an episode's final info, or a ``success_fn``), or does not say (torn, or older)."""
    mixed_rewards: bool = False
    """Whether the group's files were recorded over different reward wrappers or settings (or
    some over none): their returns are in different units, so the group has no return
    statistics and no incentive warning that compares returns."""

    @property
    def failure(self) -> int:
        """Number of failed episodes, over all labels."""
        return sum(self.failures.values())

    @property
    def truncated(self) -> int:
        """Number of truncated episodes, over all reasons."""
        return sum(self.truncations.values())

    def to_dict(self) -> dict[str, Any]:
        """Return the group as JSON-able values (the shape: ``docs/reporting.md``)."""
        data: dict[str, Any] = {
            "key": self.key,
            "episodes": self.episodes,
            "ended": self.ended,
            "success": self.success,
            "success_rate": self.success_rate,
            "success_ci": _interval(self.success_ci),
            "failure": self.failure,
            "failures": dict(self.failures),
            "failure_rate": self.failure_rate,
            "failure_ci": _interval(self.failure_ci),
            "truncated": self.truncated,
            "truncations": dict(self.truncations),
            "truncation_rate": self.truncation_rate,
            "truncation_ci": _interval(self.truncation_ci),
            "incomplete": self.incomplete,
            "errors": self.errors,
            "terminated_and_truncated": self.terminated_and_truncated,
            "return_mean": self.return_mean,
            "return_std": self.return_std,
            "length_mean": self.length_mean,
            "length_std": self.length_std,
            "term_means": {k: dict(v) for k, v in self.term_means.items()},
            "warnings": [{"code": w.code, "message": w.message} for w in self.warnings],
            "success_signal": self.success_signal,
            "nonfinite_returns": self.nonfinite_returns,
        }
        result: dict[str, Any] = to_jsonable(data)
        return result


def _interval(ci: Interval | None) -> dict[str, float] | None:
    return None if ci is None else {"low": ci.low, "high": ci.high}


def group_reports(
    episodes: pa.Table,
    terms: pa.Table,
    *,
    one_outcome: bool = False,
    empty: Iterable[str] = (),
) -> list[GroupReport]:
    """One report per group key of ``episodes`` (:func:`natural` order), with its ``terms`` rows.

    ``one_outcome``: every group holds episodes of one outcome by construction (grouped by
    label), so its rates would be 0 or 1 whatever the episodes, and its incentive warnings,
    which set a group's outcomes against each other, would compare nothing: neither is
    computed (rates and intervals ``None``, no warnings); the counts and statistics stay.

    ``empty``: keys of groups whose files hold no episode (a torn file that lost them all),
    each a group of 0 episodes among the others, unless no group holds any episode.
    """
    if not episodes.num_rows:
        return []
    return [
        _group(key, rows, key_terms, one_outcome)
        for key, rows, key_terms in keyed(episodes, terms, empty)
    ]


def keyed(
    episodes: pa.Table, terms: pa.Table, empty: Iterable[str] = ()
) -> list[tuple[str, pa.Table, pa.Table]]:
    """Each key of ``episodes``, in :func:`natural` order, with its rows and ``terms`` rows.

    Each of ``empty`` that is no key of ``episodes`` too, with no rows.
    """
    rows, term_rows = by_key(episodes), by_key(terms)
    no_rows, no_terms = episodes.slice(0, 0), terms.slice(0, 0)
    keys = sorted({*rows, *empty}, key=natural)
    return [(key, rows.get(key, no_rows), term_rows.get(key, no_terms)) for key in keys]


def natural(key: str) -> tuple[tuple[int, int, str], ...]:
    """A group key's place: numbers in it compare as numbers (``step-512`` before ``step-1024``).

    >>> sorted(["1024", "512", "b", "a10", "a9"], key=natural)
    ['512', '1024', 'a9', 'a10', 'b']
    """
    return tuple(
        (0, int(part), "") if part.isdigit() else (1, 0, part)
        for part in re.split(r"(\d+)", key)
        if part
    )


def by_key(table: pa.Table) -> dict[str, pa.Table]:
    """The rows of ``table`` by their ``key`` column, in their order in ``table``.

    One stable sort of the keys' codes, then a slice per key: a campaign reported by file has
    a group per file, and a filter per group would pass over every row once per file.

    >>> t = pa.table({"key": ["b", "a", "b"], "x": [1, 2, 3]})
    >>> {k: v.column("x").to_pylist() for k, v in by_key(t).items()}
    {'b': [1, 3], 'a': [2]}
    """
    if not table.num_rows:
        return {}
    encoded = pc.dictionary_encode(table.column("key")).combine_chunks()
    keys = encoded.dictionary.to_pylist()
    codes = encoded.indices.to_numpy(zero_copy_only=False)
    order = np.argsort(codes, kind="stable")
    ordered = table.take(pa.array(order)).combine_chunks()
    sorted_codes = codes[order]
    starts = [*np.flatnonzero(np.diff(sorted_codes, prepend=-1)).tolist(), len(order)]
    return {
        keys[sorted_codes[start]]: ordered.slice(start, end - start)
        for start, end in pairwise(starts)
    }


def _group(key: str, rows: pa.Table, terms: pa.Table, one_outcome: bool) -> GroupReport:
    outcome = rows.column("outcome").to_pylist()
    failure_labels = rows.column("failure_label").to_pylist()
    reasons = rows.column("truncation_reason").to_pylist()
    success = outcome.count(fmt.OUTCOME_SUCCESS)
    failures = counts(
        label or fmt.UNLABELED
        for o, label in zip(outcome, failure_labels, strict=True)
        if o == fmt.OUTCOME_FAILURE
    )
    truncations = counts(
        r or fmt.REASON_EXTERNAL
        for o, r in zip(outcome, reasons, strict=True)
        if o == fmt.OUTCOME_TRUNCATED
    )
    failure = sum(failures.values())
    truncated = sum(truncations.values())
    ended = success + failure + truncated
    outcome_arr = np.array(outcome, dtype=object)
    ended_mask = np.isin(outcome_arr, ENDED)
    returns = rows.column("return").to_numpy(zero_copy_only=False).astype(np.float64)
    lengths = rows.column("length").to_numpy(zero_copy_only=False).astype(np.float64)
    mixed = _mixed_rewards(rows)
    return_mean, return_std = (None, None) if mixed else mean_std(returns[ended_mask])
    length_mean, length_std = mean_std(lengths[ended_mask])
    group = GroupReport(
        key=key,
        episodes=rows.num_rows,
        ended=ended,
        success=success,
        success_rate=rate(success, ended),
        success_ci=wilson_interval(success, ended) if ended else None,
        failures=failures,
        failure_rate=rate(failure, ended),
        truncations=truncations,
        truncation_rate=rate(truncated, ended),
        incomplete=outcome.count(fmt.OUTCOME_INCOMPLETE),
        errors=outcome.count(fmt.OUTCOME_ERROR),
        terminated_and_truncated=_both_flags(rows),
        return_mean=return_mean,
        return_std=return_std,
        length_mean=length_mean,
        length_std=length_std,
        term_means=_term_means(terms, outcome_arr),
        warnings=[],
        failure_ci=wilson_interval(failure, ended) if ended else None,
        truncation_ci=wilson_interval(truncated, ended) if ended else None,
        success_signal=bool(pc.any(rows.column("success_signal")).as_py() is not False),
        nonfinite_returns=int((~np.isfinite(returns[ended_mask])).sum()),
        mixed_rewards=mixed,
    )
    if one_outcome:  # (each rate 0 or 1, each warning comparing nothing, by construction)
        group.success_rate = group.failure_rate = group.truncation_rate = None
        group.success_ci = group.failure_ci = group.truncation_ci = None
        return group
    group.warnings = incentive_warnings(
        group,
        outcome_arr,
        np.array(failure_labels, dtype=object),
        None if mixed else returns,
        terms,
    )
    return group


def _mixed_rewards(rows: pa.Table) -> bool:
    """Whether ``rows`` (a group's episodes) come from files of other reward wrappers or setups."""
    if "reward_wrappers" not in rows.column_names or rows.num_rows < 2:
        return False
    chains = pc.count_distinct(rows.column("reward_wrappers"), mode="all").as_py()
    return bool(chains > 1)


def _both_flags(rows: pa.Table) -> int:
    """The episodes that ended with both ``terminated`` and ``truncated`` set."""
    both = pc.and_(
        pc.fill_null(rows.column("terminated"), False),
        pc.fill_null(rows.column("truncated"), False),
    )
    return int(pc.sum(both).as_py() or 0)


def _term_means(terms: pa.Table, outcome: np.ndarray[Any, Any]) -> dict[str, dict[str, float]]:
    """Per outcome and term, the term's mean total over the ended episodes of that outcome."""
    if terms.num_rows == 0:
        return {}
    sums = terms.group_by(["outcome", "term"]).aggregate([("total", "sum")])
    out: dict[str, dict[str, float]] = {}
    for o, term, total in zip(
        sums.column("outcome").to_pylist(),
        sums.column("term").to_pylist(),
        sums.column("total_sum").to_pylist(),
        strict=True,
    ):
        n = int((outcome == o).sum())
        if n:
            out.setdefault(o, {})[term] = (total if total is not None else math.nan) / n
    return {o: dict(sorted(v.items())) for o, v in sorted(out.items())}
