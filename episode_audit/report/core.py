"""Report episode outcomes: pure functions from episodes to tables.

- :func:`report` opens evidence files and reports their episodes, grouped, into a :class:`Report`.
- :func:`report_tables` does the same for already opened files.
- :class:`GroupReport` holds one group's success, failure and truncation counts and rates —
  side by side, never folded into one "done" number — with a Wilson interval for the success
  rate, return and length statistics, mean reward terms per outcome and incentive warnings.
- :class:`Gates` are CI thresholds; each is checked against every group (:class:`GateResult`).
- :func:`wilson_interval` is the Wilson score interval of a binomial proportion.

Rates use the *ended* episodes (success + failure + truncated) as denominator; ``incomplete``
and ``error`` episodes are counted separately and never folded in. An episode that ended with
both ``terminated`` and ``truncated`` set counts by its task ending (success or failure) and is
also counted in ``terminated_and_truncated``.

Incentive warnings (reward hacking by proxy), each message stating the numbers behind it:

===============================  =============================================================
code                             when
===============================  =============================================================
``failure_outearns_success``     failures with some label earn a higher mean return than
                                 successes (at least one of each)
``truncation_outearns_success``  truncated episodes earn a higher mean return than successes
``no_success_positive_return``   no episode succeeded, yet failures earn a positive mean
                                 return, at least as high as the truncated episodes' (if any)
``shaping_dominates``            one reward term supplies >= 50 % of the absolute term mass of
                                 the group's ended episodes, and pays (its total is positive:
                                 a dominating cost is not shaping), while the success rate is
                                 < 0.5
                                 (needs at least two terms; declared constants count; and at
                                 least one episode the task ended, success or failure: a group
                                 only ever cut off by a time limit has no success signal)
===============================  =============================================================

The last two need a task that reports success (``success_signal``): a group whose files all
say their task never did (no success key in any episode's final info and no ``success_fn``:
CartPole, Hopper, whose endings are falls) has no success to be rare, and is not warned.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.records import to_jsonable
from ..read import Evidence, open_evidence

__all__ = [
    "GateResult",
    "Gates",
    "GroupReport",
    "IncentiveWarning",
    "Interval",
    "Report",
    "report",
    "report_tables",
    "wilson_interval",
]

Z_95 = 1.959963984540054
"""The two-sided 95 % normal quantile."""

NONE_KEY = "(none)"
SUCCESS_KEY = "(success)"
INCOMPLETE_KEY = "(incomplete)"
ERROR_KEY = "(error)"

FAILURE_OUTEARNS_SUCCESS = "failure_outearns_success"
TRUNCATION_OUTEARNS_SUCCESS = "truncation_outearns_success"
NO_SUCCESS_POSITIVE_RETURN = "no_success_positive_return"
SHAPING_DOMINATES = "shaping_dominates"

_SHAPING_SHARE = 0.5
_SHAPING_SUCCESS_RATE = 0.5
_ENDED = (fmt.OUTCOME_SUCCESS, fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED)


@dataclass(frozen=True)
class Interval:
    """A closed interval ``[low, high]``."""

    low: float
    high: float


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


@dataclass
class IncentiveWarning:
    """A sign that the reward pays for something other than success (see the module table)."""

    group: str
    code: str
    message: str


@dataclass
class GroupReport:
    """Outcome counts, rates and statistics of one group of episodes.

    Rates are over ``ended`` (success + failure + truncated) and ``None`` when no episode ended.
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
    success_signal: bool = True
    """Whether the task reports success: some file of the group says its task did (a success
    key in an episode's final info, or a ``success_fn``), or does not say (torn, or older)."""

    @property
    def failure(self) -> int:
        """Number of failed episodes, over all labels."""
        return sum(self.failures.values())

    @property
    def truncated(self) -> int:
        """Number of truncated episodes, over all reasons."""
        return sum(self.truncations.values())

    def to_dict(self) -> dict[str, Any]:
        """Return the group as JSON-able values (the shape is documented on :class:`Report`)."""
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
        }
        result: dict[str, Any] = to_jsonable(data)
        return result


def _interval(ci: Interval | None) -> dict[str, float] | None:
    return None if ci is None else {"low": ci.low, "high": ci.high}


@dataclass(frozen=True)
class Gates:
    """CI thresholds, each checked against every group; ``None`` disables a gate."""

    min_success_rate: float | None = None
    max_failure_rate: float | None = None
    max_failure_rate_by_label: Mapping[str, float] = field(default_factory=dict)
    max_truncation_rate: float | None = None
    fail_on_incentive_warning: bool = False
    max_error_rate: float | None = None
    """Errors (the env raised) over *all* the group's episodes: the other rates leave them out."""

    def _rates(self) -> list[tuple[str, float | None]]:
        """Every rate bound, named (``None``: that gate is off)."""
        return [
            ("min_success_rate", self.min_success_rate),
            ("max_failure_rate", self.max_failure_rate),
            ("max_truncation_rate", self.max_truncation_rate),
            ("max_error_rate", self.max_error_rate),
            *(
                (f"max_failure_rate_by_label[{label!r}]", value)
                for label, value in self.max_failure_rate_by_label.items()
            ),
        ]

    @property
    def any(self) -> bool:
        """Whether any gate is on."""
        return self.fail_on_incentive_warning or any(v is not None for _, v in self._rates())

    def __post_init__(self) -> None:
        for name, value in self._rates():
            if value is not None and not (
                isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1
            ):
                raise ConfigurationError(
                    f"{name}: expected a rate between 0 and 1, actually: {value!r}"
                )


@dataclass(frozen=True)
class GateResult:
    """One gate checked against one group; ``message`` states the numbers."""

    gate: str
    group: str
    passed: bool
    message: str


@dataclass
class Report:
    """Groups of episodes with their rates, and the gates checked against each group.

    :meth:`to_dict` returns this JSON shape (stable; new keys may be added, none removed).
    Non-finite numbers are written as the strings ``"nan"``, ``"inf"``, ``"-inf"``::

        {
          "by": str,                 # "file", "env", "env_index", "agent", "tag:NAME", "label"
                                     # or "all"
          "passed": bool,            # every gate passed for every group
          "groups": [                # sorted by key
            {"key": str, "episodes": int, "ended": int,
             "success": int, "success_rate": float | null,
             "success_ci": {"low": float, "high": float} | null,
             "failure": int, "failures": {label: int}, "failure_rate": float | null,
             "failure_ci": {"low": float, "high": float} | null,
             "truncated": int, "truncations": {reason: int}, "truncation_rate": float | null,
             "truncation_ci": {"low": float, "high": float} | null,
             "incomplete": int, "errors": int, "terminated_and_truncated": int,
             "return_mean": float | null, "return_std": float | null,
             "length_mean": float | null, "length_std": float | null,
             "term_means": {outcome: {term: float}},
             "warnings": [{"code": str, "message": str}],
             "success_signal": bool},  # the task reports success (see the warnings)
            ...
          ],
          "gates": [{"gate": str, "group": str, "passed": bool, "message": str}, ...],
          "unfinished": [{"file": str, "why": str}, ...]   # files still being written or torn
          "unit": str,               # "episode", or "game" (PettingZoo games, games=True)
          "unmatched_labels": [str, ...],  # labels of per-label failure gates that no failure
                                           # has: a misspelt label would pass every time
          "notes": [str, ...]              # those labels, and a by="tag:NAME" no file has,
                                           # in words (the CLI prints them as warnings)
        }

    An unfinished file (its writer is still running, or was killed) is reported with what was
    flushed so far; ``unfinished`` names it, so a rate over a live file is never mistaken for
    a final one.
    """

    by: str
    groups: list[GroupReport]
    gates: list[GateResult]
    unfinished: list[tuple[str, str]] = field(default_factory=list)
    unit: str = "episode"
    unmatched_labels: list[str] = field(default_factory=list)
    missing_tag: str | None = None

    @property
    def notes(self) -> list[str]:
        """What the report's options matched nothing of, a line each.

        A per-label failure gate on a label no failure has; ``by="tag:NAME"`` with a tag no
        file has.
        """
        seen = sorted({label for group in self.groups for label in group.failures})
        labels = ", ".join(map(repr, seen)) if seen else "none"
        notes = [
            f"gate max_failure_rate:{label}: {_unmatched_why(label)} (labels seen: {labels})"
            for label in self.unmatched_labels
        ]
        if self.missing_tag is not None:
            notes.append(
                f"by tag:{self.missing_tag}: no file has the tag {self.missing_tag!r}, so every "
                f"episode is in the group {NONE_KEY!r}: is the tag spelt as recorded?"
            )
        return notes

    @property
    def passed(self) -> bool:
        """Whether every gate passed for every group (``True`` when there are no gates)."""
        return all(g.passed for g in self.gates)

    def to_dict(self) -> dict[str, Any]:
        """Return the report in the JSON shape documented on the class."""
        return {
            "by": self.by,
            "passed": self.passed,
            "groups": [g.to_dict() for g in self.groups],
            "gates": [
                {"gate": g.gate, "group": g.group, "passed": g.passed, "message": g.message}
                for g in self.gates
            ],
            "unfinished": [{"file": name, "why": why} for name, why in self.unfinished],
            "unit": self.unit,
            "unmatched_labels": list(self.unmatched_labels),
            "notes": self.notes,
        }


# --------------------------------------------------------------------------------------------
# Collecting episodes
# --------------------------------------------------------------------------------------------


BY_KEYS = ("file", "env", "env_index", "agent", "label", "all")
"""The ``by`` groupings besides ``tag:NAME``."""


def _check_by(by: str) -> None:
    if by in BY_KEYS or (by.startswith("tag:") and len(by) > 4):
        return
    raise ConfigurationError(
        f"by: expected 'file', 'env', 'tag:NAME', 'label', 'all', 'env_index' or 'agent', "
        f"actually: {by!r}"
    )


def _label_keys(table: pa.Table) -> pa.Array:
    """Per episode, its key for ``by="label"``."""
    outcome = table.column("outcome")
    failure = pc.fill_null(table.column("failure_label"), fmt.UNLABELED)
    reason = pc.fill_null(table.column("truncation_reason"), fmt.REASON_EXTERNAL)
    truncated = pc.binary_join_element_wise("(truncated:", reason, ")", "")
    keys = pc.case_when(
        pc.make_struct(
            pc.equal(outcome, fmt.OUTCOME_SUCCESS),
            pc.equal(outcome, fmt.OUTCOME_FAILURE),
            pc.equal(outcome, fmt.OUTCOME_TRUNCATED),
            pc.equal(outcome, fmt.OUTCOME_ERROR),
        ),
        SUCCESS_KEY,
        failure,
        truncated,
        ERROR_KEY,
        INCOMPLETE_KEY,
    )
    return keys.combine_chunks() if isinstance(keys, pa.ChunkedArray) else keys


_EPISODE_FIELDS = [
    "outcome",
    "failure_label",
    "truncation_reason",
    "terminated",
    "truncated",
    "length",
    "return",
]


def _collect(
    sources: Iterable[tuple[str, Evidence]], by: str, games: bool = False
) -> tuple[pa.Table, pa.Table]:
    """Return (episodes, terms): one row per episode, one row per (episode, term) total.

    With ``games``, one row per game of a PettingZoo file instead (see :mod:`.games`).
    """
    parts: list[pa.Table] = []
    term_parts: list[pa.Table] = []
    for name, ev in sources:
        table = ev.episodes()
        if games:
            from .games import game_table

            table = game_table(table)
        n = table.num_rows
        if n == 0:
            continue
        if by == "file":
            key: pa.Array = pa.array([name] * n, pa.string())
        elif by == "env":
            key = pa.array([ev.run.env_id or NONE_KEY] * n, pa.string())
        elif by == "all":
            key = pa.array(["all"] * n, pa.string())
        elif by == "label":
            key = _label_keys(table)
        elif by == "env_index":  # vector files: one group per sub-env index
            key = pc.cast(table.column("env_index"), pa.string()).combine_chunks()
        elif by == "agent":  # PettingZoo files: one group per agent
            if games:
                raise ConfigurationError("by='agent' and games=True: a game has many agents")
            key = pc.fill_null(table.column("agent"), NONE_KEY).combine_chunks()
        else:
            value = (ev.run.tags or {}).get(by[4:])
            key = pa.array([NONE_KEY if value is None else str(value)] * n, pa.string())
        signal = pa.array([ev.reports_success is not False] * n, pa.bool_())
        parts.append(
            table.select(_EPISODE_FIELDS)
            .append_column("key", key)
            .append_column("success_signal", signal)
        )
        term_parts.extend(_term_rows(table, key, ev))
    if not parts:
        empty = pa.schema(
            [
                ("outcome", pa.string()),
                ("failure_label", pa.string()),
                ("truncation_reason", pa.string()),
                ("terminated", pa.bool_()),
                ("truncated", pa.bool_()),
                ("length", pa.int64()),
                ("return", pa.float64()),
                ("key", pa.string()),
                ("success_signal", pa.bool_()),
            ]
        ).empty_table()
        return empty, _TERM_SCHEMA.empty_table()
    terms = pa.concat_tables(term_parts) if term_parts else _TERM_SCHEMA.empty_table()
    return pa.concat_tables(parts), terms


_TERM_SCHEMA = pa.schema(
    [("key", pa.string()), ("outcome", pa.string()), ("term", pa.string()), ("total", pa.float64())]
)


def _term_rows(table: pa.Table, key: pa.Array, ev: Evidence) -> list[pa.Table]:
    """Per (episode, term): the term's episode total, for ended episodes only."""
    ended = pc.is_in(table.column("outcome"), pa.array(_ENDED)).to_numpy(zero_copy_only=False)
    if not ended.any():
        return []
    mask = pa.array(ended)
    outcome = table.column("outcome").combine_chunks().filter(mask)
    keys = key.filter(mask)
    out: list[pa.Table] = []
    totals = table.column("term_totals").combine_chunks().filter(mask)
    if len(totals) and totals.null_count < len(totals):
        # Offsets, not pc.list_parent_indices: that kernel aborts the process on map arrays
        # (pyarrow 26).
        offsets = totals.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        parents = pa.array(np.repeat(np.arange(len(totals)), np.diff(offsets)))
        out.append(
            pa.table(
                {
                    "key": keys.take(parents),
                    "outcome": outcome.take(parents),
                    "term": totals.keys.slice(lo, hi - lo),
                    "total": totals.items.slice(lo, hi - lo),
                },
                schema=_TERM_SCHEMA,
            )
        )
    constants = (ev.run.reward_terms or {}).get("constants") or {}
    if constants:
        length = pc.cast(table.column("length").combine_chunks().filter(mask), pa.float64())
        for name, value in constants.items():
            if not isinstance(value, (int, float)):
                continue
            out.append(
                pa.table(
                    {
                        "key": keys,
                        "outcome": outcome,
                        "term": pa.array([str(name)] * len(keys), pa.string()),
                        "total": pc.multiply(length, float(value)),
                    },
                    schema=_TERM_SCHEMA,
                )
            )
    return out


# --------------------------------------------------------------------------------------------
# Groups
# --------------------------------------------------------------------------------------------


def _mean_std(values: np.ndarray[Any, Any]) -> tuple[float | None, float | None]:
    if values.size == 0:
        return None, None
    return float(np.mean(values)), float(np.std(values))


def _counts(values: list[Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for value in values:
        out[value] = out.get(value, 0) + 1
    return dict(sorted(out.items()))


def _rate(count: int, ended: int) -> float | None:
    return count / ended if ended else None


def _num(value: float) -> str:
    return f"{value:.4g}"


def _group(key: str, rows: pa.Table, terms: pa.Table) -> GroupReport:
    outcome = rows.column("outcome").to_pylist()
    failure_labels = rows.column("failure_label").to_pylist()
    reasons = rows.column("truncation_reason").to_pylist()
    both = pc.and_(
        pc.fill_null(rows.column("terminated"), False),
        pc.fill_null(rows.column("truncated"), False),
    )
    success = outcome.count(fmt.OUTCOME_SUCCESS)
    failures = _counts(
        [
            label or fmt.UNLABELED
            for o, label in zip(outcome, failure_labels, strict=True)
            if o == "failure"
        ]
    )
    truncations = _counts(
        [
            r or fmt.REASON_EXTERNAL
            for o, r in zip(outcome, reasons, strict=True)
            if o == "truncated"
        ]
    )
    failure = sum(failures.values())
    truncated = sum(truncations.values())
    ended = success + failure + truncated
    outcome_arr = np.array(outcome, dtype=object)
    ended_mask = np.isin(outcome_arr, _ENDED)
    returns = rows.column("return").to_numpy(zero_copy_only=False).astype(np.float64)
    lengths = rows.column("length").to_numpy(zero_copy_only=False).astype(np.float64)
    return_mean, return_std = _mean_std(returns[ended_mask])
    length_mean, length_std = _mean_std(lengths[ended_mask])
    term_means = _term_means(terms, outcome_arr)
    group = GroupReport(
        key=key,
        episodes=rows.num_rows,
        ended=ended,
        success=success,
        success_rate=_rate(success, ended),
        success_ci=wilson_interval(success, ended) if ended else None,
        failures=failures,
        failure_rate=_rate(failure, ended),
        truncations=truncations,
        truncation_rate=_rate(truncated, ended),
        incomplete=outcome.count(fmt.OUTCOME_INCOMPLETE),
        errors=outcome.count(fmt.OUTCOME_ERROR),
        terminated_and_truncated=int(pc.sum(both).as_py() or 0),
        return_mean=return_mean,
        return_std=return_std,
        length_mean=length_mean,
        length_std=length_std,
        term_means=term_means,
        warnings=[],
        failure_ci=wilson_interval(failure, ended) if ended else None,
        truncation_ci=wilson_interval(truncated, ended) if ended else None,
        success_signal=bool(pc.any(rows.column("success_signal")).as_py()),
    )
    group.warnings = _incentive_warnings(
        group, outcome_arr, np.array(failure_labels, dtype=object), returns, terms
    )
    return group


def _term_means(terms: pa.Table, outcome: np.ndarray[Any, Any]) -> dict[str, dict[str, float]]:
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


def _incentive_warnings(
    group: GroupReport,
    outcome: np.ndarray[Any, Any],
    labels: np.ndarray[Any, Any],
    returns: np.ndarray[Any, Any],
    terms: pa.Table,
) -> list[IncentiveWarning]:
    warnings: list[IncentiveWarning] = []
    key = group.key

    def warn(code: str, message: str) -> None:
        warnings.append(IncentiveWarning(key, code, message))

    success_returns = returns[outcome == fmt.OUTCOME_SUCCESS]
    failure_mask = outcome == fmt.OUTCOME_FAILURE
    truncated_returns = returns[outcome == fmt.OUTCOME_TRUNCATED]
    if success_returns.size:
        success_mean = float(np.mean(success_returns))
        against = f"successes ({_num(success_mean)} over {success_returns.size} episodes)"
        named = np.array([str(x or fmt.UNLABELED) for x in labels], dtype=object)
        for label in sorted(set(named[failure_mask].tolist())):
            chosen = failure_mask & (named == label)
            mean = float(np.mean(returns[chosen]))
            if mean > success_mean:
                warn(
                    FAILURE_OUTEARNS_SUCCESS,
                    f"failures labelled {label!r} earn a mean return of {_num(mean)} over "
                    f"{int(chosen.sum())} episodes, more than {against}",
                )
        if truncated_returns.size:
            mean = float(np.mean(truncated_returns))
            if mean > success_mean:
                warn(
                    TRUNCATION_OUTEARNS_SUCCESS,
                    f"truncated episodes earn a mean return of {_num(mean)} over "
                    f"{truncated_returns.size} episodes, more than {against}",
                )
    elif failure_mask.any() and group.success_signal:
        mean = float(np.mean(returns[failure_mask]))
        truncated_mean = float(np.mean(truncated_returns)) if truncated_returns.size else None
        if mean > 0 and (truncated_mean is None or mean >= truncated_mean):
            beside = (
                ""
                if truncated_mean is None
                else f", at least the truncated episodes' {_num(truncated_mean)}"
            )
            warn(
                NO_SUCCESS_POSITIVE_RETURN,
                f"no episode succeeded (0 of {group.ended} ended), yet failures earn a positive "
                f"mean return of {_num(mean)} over {int(failure_mask.sum())} episodes{beside}",
            )

    rate = group.success_rate
    # success can only be rare where the task can end by itself: a group whose episodes were
    # all cut off (HalfCheetah, Reacher: time limit only) has no success signal to compare with
    task_endings = group.success + group.failure
    if (
        rate is not None
        and rate < _SHAPING_SUCCESS_RATE
        and task_endings
        and group.success_signal
        and terms.num_rows
    ):
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
        if len(names) >= 2 and total > 0 and math.isfinite(total):
            top = int(np.argmax(masses))
            share = float(masses[top]) / total
            # a cost (a term that takes return, as a control cost) does not pay for anything
            if share >= _SHAPING_SHARE and paid[top] > 0:
                warn(
                    SHAPING_DOMINATES,
                    f"term {names[top]!r} supplies {share:.0%} of the absolute term mass "
                    f"({_num(float(masses[top]))} of {_num(total)}) while the success rate is "
                    f"{rate:.2f} ({group.success} of {group.ended} ended episodes)",
                )
    return warnings


# --------------------------------------------------------------------------------------------
# Gates
# --------------------------------------------------------------------------------------------


def _show(rate: float, bound: float) -> tuple[str, str]:
    """Format a rate and its bound with enough digits that they differ when they differ."""
    for digits in range(2, 8):
        a, b = f"{rate:.{digits}f}", f"{bound:.{digits}f}"
        if a != b or rate == bound:
            return a, b
    return repr(rate), repr(bound)


def _gate(
    gate: str, group: GroupReport, what: str, rate: float | None, bound: float, minimum: bool
) -> GateResult:
    where = f"(group {group.key})"
    if rate is None:
        return GateResult(gate, group.key, False, f"{what}: no ended episodes {where}")
    passed = rate >= bound if minimum else rate <= bound
    shown, limit = _show(rate, bound)
    if minimum:
        op = ">=" if passed else "<"
    else:
        op = "<=" if passed else ">"
    return GateResult(gate, group.key, passed, f"{what} {shown} {op} {limit} {where}")


def _unmatched_labels(gates: Gates | None, groups: Sequence[GroupReport]) -> list[str]:
    """The labels of per-label failure gates that no failure of any group has."""
    if gates is None:
        return []
    seen = {label for group in groups for label in group.failures}
    return sorted(set(gates.max_failure_rate_by_label) - seen)


def _unmatched_why(label: str) -> str:
    """What a gate on a label no failure has means (a misspelt label always passes)."""
    return f"no failure in these files is labelled {label!r}: is the label spelt as recorded?"


def _gates(gates: Gates, groups: list[GroupReport]) -> list[GateResult]:
    if not groups and gates.any:  # nothing evaluated is not a pass
        return [
            GateResult(
                "episodes", "-", False, "no episodes in these files: no gate could be checked"
            )
        ]
    results: list[GateResult] = []
    unmatched = set(_unmatched_labels(gates, groups))
    for group in groups:
        if gates.min_success_rate is not None:
            results.append(
                _gate(
                    "min_success_rate",
                    group,
                    "success rate",
                    group.success_rate,
                    gates.min_success_rate,
                    True,
                )
            )
        if gates.max_failure_rate is not None:
            results.append(
                _gate(
                    "max_failure_rate",
                    group,
                    "failure rate",
                    group.failure_rate,
                    gates.max_failure_rate,
                    False,
                )
            )
        for label, bound in sorted(gates.max_failure_rate_by_label.items()):
            rate = _rate(group.failures.get(label, 0), group.ended)
            result = _gate(
                f"max_failure_rate:{label}", group, f"failure rate {label!r}", rate, bound, False
            )
            if label in unmatched:  # a misspelt label would pass every time: say so
                result = replace(result, message=f"{result.message}; {_unmatched_why(label)}")
            results.append(result)
        if gates.max_truncation_rate is not None:
            results.append(
                _gate(
                    "max_truncation_rate",
                    group,
                    "truncation rate",
                    group.truncation_rate,
                    gates.max_truncation_rate,
                    False,
                )
            )
        if gates.max_error_rate is not None:
            results.append(
                _gate(
                    "max_error_rate",
                    group,
                    "error rate (of all episodes)",
                    _rate(group.errors, group.episodes),
                    gates.max_error_rate,
                    False,
                )
            )
        if gates.fail_on_incentive_warning:
            codes = ", ".join(w.code for w in group.warnings)
            results.append(
                GateResult(
                    "incentive_warnings",
                    group.key,
                    not group.warnings,
                    f"{len(group.warnings)} incentive warning(s)"
                    + (f": {codes}" if codes else "")
                    + f" (group {group.key})",
                )
            )
    return results


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def report_tables(
    sources: Iterable[tuple[str, Evidence]],
    *,
    by: str = "file",
    gates: Gates | None = None,
    games: bool = False,
) -> Report:
    """Report the episodes of opened evidence files, given as ``(name, evidence)`` pairs.

    ``name`` is the group key for ``by="file"``. See :func:`report` for ``by``, ``gates`` and
    ``games``.
    """
    _check_by(by)
    sources = list(sources)
    unfinished = [(name, ev.torn or "no run-end record") for name, ev in sources if not ev.finished]
    episodes, terms = _collect(sources, by, games)
    groups: list[GroupReport] = []
    if episodes.num_rows:
        keys = sorted(set(episodes.column("key").to_pylist()))
        for key in keys:
            rows = episodes.filter(pc.equal(episodes.column("key"), key))
            group_terms = terms.filter(pc.equal(terms.column("key"), key))
            groups.append(_group(key, rows, group_terms))
    return Report(
        by,
        groups,
        _gates(gates, groups) if gates is not None else [],
        unfinished,
        "game" if games else "episode",
        _unmatched_labels(gates, groups),
        _missing_tag(by, sources),
    )


def _missing_tag(by: str, sources: Sequence[tuple[str, Evidence]]) -> str | None:
    """The tag of ``by="tag:NAME"`` when no file has it (every episode would be ``(none)``)."""
    if not by.startswith("tag:") or not sources:
        return None
    name = by[4:]
    return None if any(name in (ev.run.tags or {}) for _, ev in sources) else name


def report(
    paths: Iterable[str | os.PathLike[str]],
    *,
    by: str = "file",
    gates: Gates | None = None,
    games: bool = False,
) -> Report:
    """Open evidence files and report their episodes, grouped, with gates checked per group.

    ``by`` is ``"file"``, ``"env"`` (the run's env id), ``"env_index"`` (a vector env's
    sub-env index, ``"0"`` for single envs), ``"agent"`` (a PettingZoo agent; ``"(none)"``
    for single-agent files), ``"tag:NAME"`` (a run tag such as
    ``policy`` or ``checkpoint``; ``"(none)"`` when a file lacks it), ``"label"`` (the failure
    label; successes as ``"(success)"``, truncations as ``"(truncated:REASON)"``, and
    ``"(incomplete)"`` / ``"(error)"``) or ``"all"``. Torn files count the episodes they hold
    (cut-off ones as incomplete). An unreadable file raises
    :class:`~episode_audit.errors.EvidenceError`. With ``games``, PettingZoo files are
    counted by game instead of by agent-episode, each game's outcome derived from its agents'
    by the rule of :mod:`episode_audit.report.games` (files without games then count nothing).

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from episode_audit import RecordEvidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.mcap"
        >>> with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), path) as env:
        ...     for seed in range(3):
        ...         _ = env.reset(seed=seed)
        ...         for _ in range(5):
        ...             _ = env.step(seed % 2)
        >>> result = report([path], by="env", gates=Gates(max_truncation_rate=0.5))
        >>> (group,) = result.groups
        >>> group.key, group.ended, group.truncations, group.truncation_rate
        ('CartPole-v1', 3, {'time_limit': 3}, 1.0)
        >>> result.passed, result.gates[0].message
        (False, 'truncation rate 1.00 > 0.50 (group CartPole-v1)')
    """
    _check_by(by)
    opened = [(str(p), open_evidence(p)) for p in paths]
    return report_tables(opened, by=by, gates=gates, games=games)
