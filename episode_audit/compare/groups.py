"""One group compared: its metrics, gates and new incentive warnings (:class:`GroupComparison`).

:func:`compare_group` builds every metric of a group from its two :class:`~.sides.Side`
values: the success rate, the failure rate and each failure label's, the truncation rate, the
error rate (when a side has errors, or a gate bounds it), the return, and each reward term's
episode total. :class:`CompareGates` are the non-inferiority gates (:func:`check_gates`; on a
group the candidate lacks, :func:`missing_gates`); :func:`combine` is how verdicts add up to
one.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.columns import counted
from ..read.arguments import non_negative
from ..report import GateResult, IncentiveWarning
from ..report.gates import is_rate
from .metrics import (
    MetricComparison,
    Verdict,
    mean_metric,
    not_compared,
    not_computable,
    rate_metric,
)
from .sides import Array, Pairs, Side, pair
from .stats import too_few

__all__ = [
    "NEW_WARNINGS_GATE",
    "RATE_MARGIN",
    "CompareGates",
    "GroupComparison",
    "check_gates",
    "check_limit",
    "combine",
    "compare_group",
    "gate_json",
    "missing_gates",
    "unverifiable",
]

RATE_MARGIN = 0.05
"""The margin a rate is ``held`` within when no gate declares one."""
NEW_WARNINGS_GATE = "new_incentive_warnings"
"""The gate of :attr:`CompareGates.fail_on_new_incentive_warning`."""


@dataclass(frozen=True)
class CompareGates:
    """Non-inferiority gates: each passes when its metric's 95 % interval stays within it.

    ``max_success_drop``: the success rate may fall at most this much;
    ``max_failure_increase`` (all failures) and ``max_failure_increase_by_label`` may rise at
    most this much; ``max_return_drop``: the mean return may fall at most this much;
    ``max_error_increase``: the error rate (episodes the env raised in, of every episode
    started) may rise at most this much. A gate is
    also the margin its metric is ``held`` within. ``fail_on_new_incentive_warning``: a group
    with an incentive warning the baseline's lacks fails (no test backs it: by chance alone a
    warning can appear on one side, see ``docs/compare.md``).

    Each limit is checked as ``episode-audit compare`` checks its option (:func:`check_limit`):
    a rate between 0 and 1, a return drop a finite number >= 0; else
    :class:`~episode_audit.errors.ConfigurationError`.

    >>> CompareGates(max_return_drop=-1)
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: max_return_drop: expected a finite number >= 0, got -1
    """

    max_success_drop: float | None = None
    max_failure_increase: float | None = None
    max_failure_increase_by_label: Mapping[str, float] = field(default_factory=dict)
    max_return_drop: float | None = None
    fail_on_new_incentive_warning: bool = False
    max_error_increase: float | None = None

    def __post_init__(self) -> None:
        check_limit("max_success_drop", self.max_success_drop, "rate")
        check_limit("max_failure_increase", self.max_failure_increase, "rate")
        check_limit("max_return_drop", self.max_return_drop, "amount")
        check_limit("max_error_increase", self.max_error_increase, "rate")
        by_label = self.max_failure_increase_by_label
        if not isinstance(by_label, Mapping):
            raise ConfigurationError(
                "max_failure_increase_by_label: expected a mapping of failure labels to rates, "
                f"e.g. {{'collision': 0.02}}, got {type(by_label).__name__}"
            )
        for label, limit in by_label.items():
            if not (isinstance(label, str) and label):
                raise ConfigurationError(
                    "max_failure_increase_by_label: expected failure labels as text, got "
                    f"{label!r}; a label is the text a failure was recorded with"
                )
            check_limit(f"max_failure_increase_by_label[{label!r}]", limit, "rate")
        if not isinstance(self.fail_on_new_incentive_warning, bool):
            raise ConfigurationError(
                "fail_on_new_incentive_warning: expected True or False, got "
                f"{self.fail_on_new_incentive_warning!r}"
            )

    def limits(self) -> dict[str, float]:
        """Metric name to its gate's limit, for the gates that are on."""
        out: dict[str, float] = {}
        if self.max_success_drop is not None:
            out["success_rate"] = self.max_success_drop
        if self.max_failure_increase is not None:
            out["failure_rate"] = self.max_failure_increase
        for label, limit in self.max_failure_increase_by_label.items():
            out[f"failure_rate:{label}"] = limit
        if self.max_error_increase is not None:
            out["error_rate"] = self.max_error_increase
        if self.max_return_drop is not None:
            out["return"] = self.max_return_drop
        return out


def check_limit(name: str, value: object, kind: Literal["rate", "margin", "amount"]) -> None:
    """Refuse a gate's limit or a margin out of its range (a limit ``None``: no gate, accepted).

    ``kind``: ``"rate"`` between 0 and 1, ``"margin"`` a rate above 0, ``"amount"`` a finite
    number >= 0 (a return). The :class:`~episode_audit.errors.ConfigurationError` names it
    ``name``, as the caller calls it (``--rate-margin`` on the command line).

    >>> check_limit("rate_margin", 2, "margin")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: rate_margin: expected a rate in (0, 1], got 2
    """
    if value is None and kind != "margin":
        return
    if kind == "amount":
        non_negative(name, value)
    elif not is_rate(value) or (kind == "margin" and value == 0):
        what = "in (0, 1]" if kind == "margin" else "between 0 and 1"
        raise ConfigurationError(f"{name}: expected a rate {what}, got {value!r}")


@dataclass
class GroupComparison:
    """A group's metrics (primary ones first, then reward terms), gates and new warnings."""

    key: str
    baseline_episodes: int
    candidate_episodes: int
    pairs: int
    metrics: list[MetricComparison]
    new_warnings: list[IncentiveWarning]
    gates: list[GateResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    """What the group's metrics left out or could not use, a line each (error episodes,
    returns that are not finite, returns in other units, too few episodes)."""

    def metric(self, name: str) -> MetricComparison:
        """The group's metric ``name`` (:class:`KeyError` when it has none)."""
        for m in self.metrics:
            if m.name == name:
                return m
        raise KeyError(name)

    @property
    def verdict(self) -> Verdict:
        """The group's verdict: :func:`combine` of its tested metrics' (not the new warnings)."""
        return combine(m.verdict for m in self.metrics if m.verdict is not None)

    def to_dict(self) -> dict[str, Any]:
        """The group as JSON-able values (``docs/compare.md``)."""
        return {
            "key": self.key,
            "verdict": self.verdict,
            "baseline_episodes": self.baseline_episodes,
            "candidate_episodes": self.candidate_episodes,
            "pairs": self.pairs,
            "metrics": [m.to_dict() for m in self.metrics],
            "new_warnings": [{"code": w.code, "message": w.message} for w in self.new_warnings],
            "gates": [gate_json(g) for g in self.gates],
            "notes": list(self.notes),
        }


def gate_json(gate: GateResult) -> dict[str, Any]:
    """A gate's result as JSON-able values (``docs/compare.md``)."""
    return {"gate": gate.gate, "group": gate.group, "passed": gate.passed, "message": gate.message}


def combine(verdicts: Iterable[Verdict]) -> Verdict:
    """Many verdicts as one.

    ``regressed`` if any is; else ``improved`` if any is; else ``held`` if all are; else
    ``underpowered`` if any is; else ``inconclusive``.

    >>> combine(["held", "improved"]), combine(["held", "underpowered", "inconclusive"])
    ('improved', 'underpowered')
    """
    seen = set(verdicts)
    for verdict in ("regressed", "improved"):
        if verdict in seen:
            return verdict
    if seen <= {"held"}:
        return "held"
    return "underpowered" if "underpowered" in seen else "inconclusive"


def compare_group(
    key: str,
    base: Side,
    cand: Side,
    gates: CompareGates,
    new_warnings: list[IncentiveWarning],
    rate_margin: float = RATE_MARGIN,
) -> GroupComparison:
    """Every metric of one group (verdicts are set later, after the Holm adjustment).

    A rate is ``held`` within its gate, or ``rate_margin`` when it has none. The error rate is
    over every episode started (:attr:`~.sides.Side.everything`), paired as those pair; it is
    there when a side has an error episode or ``max_error_increase`` is on. Where a side has
    no ended episode (every one raised), the metrics over ended episodes are not computed
    (:func:`~.metrics.not_computable`): only the error rate is.
    """
    pairs = pair(base, cand)
    limits = gates.limits()
    unended = _unended(base, cand)

    def rate(name: str, b: Any, c: Any, better: Any) -> MetricComparison:
        margin = limits.get(name, rate_margin)
        if unended is not None:
            return not_computable(name, "rate", better, b, c, margin, unended)
        return rate_metric(name, b, c, pairs, better=better, margin=margin)

    failed_b, failed_c = _is(base, cand, fmt.OUTCOME_FAILURE)
    rates = [("failure_rate", failed_b, failed_c, "lower")]
    if base.success_signal or cand.success_signal:  # (else 0 against 0 by construction)
        rates.insert(0, ("success_rate", *_is(base, cand, fmt.OUTCOME_SUCCESS), "higher"))
    named_b, named_c = base.failure_names(), cand.failure_names()  # (unlabelled: as report)
    labels = set(named_b[failed_b]) | set(named_c[failed_c])
    labels |= set(gates.max_failure_increase_by_label)
    for label in sorted(labels):
        b = failed_b & (named_b == label)
        c = failed_c & (named_c == label)
        rates.append((f"failure_rate:{label}", b, c, "lower"))
    # (descriptive: at the time limit a survival task succeeds and a goal task times out)
    rates.append(("truncation_rate", *_is(base, cand, fmt.OUTCOME_TRUNCATED), "none"))
    metrics = [rate(*spec) for spec in rates]
    _mark_repeats(metrics, [(b, c) for _, b, c, _ in rates])
    all_b, all_c = base.everything, cand.everything
    errors_b, errors_c = _is(all_b, all_c, fmt.OUTCOME_ERROR)
    notes = _mixed_tasks(base, cand)
    if unended is None:
        notes += pairs.left_out("the rates and the return")
    if errors_b.any() or errors_c.any() or "error_rate" in limits:
        margin = limits.get("error_rate", rate_margin)
        began = pair(all_b, all_c)
        metrics.append(
            rate_metric("error_rate", errors_b, errors_c, began, better="lower", margin=margin)
        )
        notes += began.left_out("error_rate")
    means, mean_notes = _means(base, cand, pairs, gates, unended)
    notes += _errors(errors_b, errors_c) + _nonfinite_returns(base, cand)
    if unended is not None:
        notes.append(
            f"{unended}: the rates (but error_rate) and the return are not computed "
            "(inconclusive), and a gate on them cannot be verified"
        )
    notes += mean_notes
    return GroupComparison(
        key, base.n, cand.n, len(pairs), metrics + means, new_warnings, notes=notes
    )


def _means(
    base: Side, cand: Side, pairs: Pairs, gates: CompareGates, unended: str | None
) -> tuple[list[MetricComparison], list[str]]:
    """The return and each reward term's episode total, and the notes on the return."""
    if unended is not None:
        metrics = [
            not_computable("return", "mean", "higher", base.returns, cand.returns,
                           gates.max_return_drop, unended)
        ]  # fmt: skip
        for term in sorted(set(base.terms) & set(cand.terms)):
            b, c = base.terms[term], cand.terms[term]
            metrics.append(not_computable(f"term:{term}", "mean", "none", b, c, None, unended))
        return metrics, []
    returns = mean_metric(
        "return", base.returns, cand.returns, pairs, better="higher",
        margin=gates.max_return_drop,
    )  # fmt: skip
    apart = _returns_apart(base, cand) or _terms_apart(base, cand)
    if apart is not None:  # (no test, no gate: a difference in other units says nothing)
        returns = not_compared(returns, apart)
    metrics = [returns]
    for term in sorted(set(base.terms) & set(cand.terms)):
        metrics.append(
            mean_metric(
                f"term:{term}", base.terms[term], cand.terms[term], pairs, better="none",
                margin=None,
            )
        )  # fmt: skip
    if apart is not None:
        return metrics, [
            f"return: not compared (inconclusive), nor a max_return_drop gate: {apart}"
        ]
    return metrics, _unbounded(returns)


def _unended(base: Side, cand: Side) -> str | None:
    """Why the metrics over ended episodes are not computed: a side has none (else ``None``).

    >>> _unended(Side.of([]), Side.of(["success"]))
    'the baseline has no ended episode'
    """
    empty = [name for name, side in (("baseline", base), ("candidate", cand)) if side.n == 0]
    if not empty:
        return None
    if len(empty) == 2:
        return (
            f"neither side has an ended episode ({_how(base, 'the baseline')}; "
            f"{_how(cand, 'the candidate')})"
        )
    side = base if empty[0] == "baseline" else cand
    how = _how(side, "its")
    return f"the {empty[0]} has no ended episode" + (f" ({how})" if how else "")


def _how(side: Side, whose: str) -> str:
    """How a side's episodes went, e.g. ``its 30 episodes: error 30`` (``""``: none began)."""
    every = side.everything
    if not every.n:
        return ""
    counts = Counter(every.outcome.tolist())
    owner = whose if whose == "its" else f"{whose}'s"
    return f"{owner} {counted(every.n, 'episode')}: " + ", ".join(
        f"{outcome} {n}" for outcome, n in sorted(counts.items())
    )


def _mixed_tasks(base: Side, cand: Side) -> list[str]:
    """The note on a group whose side holds episodes of several env ids, when one does."""
    mixed = [
        f"the {name}'s ({', '.join(side.tasks())})"
        for name, side in (("baseline", base.everything), ("candidate", cand.everything))
        if len(side.tasks()) > 1
    ]
    if not mixed:
        return []
    return [
        f"episodes of several env ids in one group ({' and '.join(mixed)}): its rates and "
        "returns pool the tasks, and episodes pair only within an env id; compare each task "
        "on its own with --by env (by='env')"
    ]


def _errors(base: Any, cand: Any) -> list[str]:
    """The note on error episodes (the env raised), when a side has any: the rates leave them out.

    >>> _errors(np.zeros(4, bool), np.array([True, False, True, False]))[0][:51]
    '0 of 4 baseline and 2 of 4 candidate episodes ended'
    """
    if not (base.any() or cand.any()):
        return []
    return [
        f"{int(base.sum())} of {len(base)} baseline and {int(cand.sum())} of {len(cand)} "
        "candidate episodes ended in error (the env raised): the other rates and the return "
        "leave them out, error_rate counts them"
    ]


def _nonfinite_returns(base: Side, cand: Side) -> list[str]:
    """The note on returns that are not finite, when a side has any."""
    bad_b, bad_c = (int((~np.isfinite(s.returns)).sum()) for s in (base, cand))
    if not bad_b + bad_c:
        return []
    return [
        f"{bad_b} of {base.n} baseline and {bad_c} of {cand.n} candidate episodes have a return "
        "that is not finite (NaN or infinite): the mean return is undefined, so it is not tested "
        "(inconclusive), and the incentive warnings leave those episodes out "
        "(`episode-audit check` finds them)"
    ]


def _returns_apart(base: Side, cand: Side) -> str | None:
    """Why the sides' returns are not in the same units, or ``None`` when they are.

    They are when every episode of both sides was recorded over the same reward wrappers
    (none: the env's own rewards). A side that mixes files of several is not.
    """
    b, c = base.reward_wrappers or frozenset({""}), cand.reward_wrappers or frozenset({""})
    if b == c and len(b) == 1:
        return None
    return (
        f"the baseline's returns are {_whose(b)} and the candidate's {_whose(c)}; record "
        "both sides over the same reward wrappers, or beneath them (the env's own rewards)"
    )


def _terms_apart(base: Side, cand: Side) -> str | None:
    """Why the sides' returns sum different rewards (their reward terms differ), or ``None``.

    A reward term that one side's episodes of some outcome all reported, and no episode of the
    other side did although it has episodes of that outcome too, means the reward is defined
    otherwise (an env kwarg, a new reward function): its returns are in other units, and that
    term has nothing to be compared with either. A term that goes with an outcome (a bonus
    reported at a success, a penalty at a failure) says nothing of that: a side whose episodes
    all fail never reports the bonus.
    """
    only_b, only_c = _other_terms(base, cand), _other_terms(cand, base)
    if not (only_b or only_c):
        return None
    said = [
        f"{side} only: {', '.join(names)}"
        for side, names in (("baseline", only_b), ("candidate", only_c))
        if names
    ]
    return (
        f"the sides' rewards have different terms ({'; '.join(said)}), so their returns sum "
        "different rewards and those terms are not compared; record both sides with the same "
        "reward (env kwargs, reward function) to compare returns"
    )


def _other_terms(one: Side, other: Side) -> list[str]:
    """The terms of ``one`` that ``other`` never reported, where it should have (above)."""
    shared = set(one.outcome.tolist()) & set(other.outcome.tolist())
    return sorted(
        name
        for name in set(one.terms) - set(other.terms)
        if any(_every_episode(one, name, one.outcome == outcome) for outcome in shared)
    )


def _every_episode(side: Side, term: str, where: Array) -> bool:
    """Whether every episode of ``side`` at ``where`` (a mask) reported ``term``."""
    reported = side.reported.get(term)
    return reported is None or bool(reported[where].all())


def _whose(chains: frozenset[str]) -> str:
    """Whose rewards returns of ``chains`` are, in words.

    >>> _whose(frozenset({""})), _whose(frozenset({"ClipReward", ""}))
    ("the env's", "a mix of the env's and ClipReward's")
    """
    named = ["the env's" if not c else f"{c}'s" for c in sorted(chains)]
    return named[0] if len(named) == 1 else "a mix of " + " and ".join(named)


NONFINITE = (
    "a return is not finite (NaN or infinite), so the mean return is undefined and more "
    "episodes would not help"
)
"""Why a return gate on returns that are not finite cannot be verified."""


def _nonfinite(metric: MetricComparison) -> bool:
    """Whether a mean's sides hold a value that is not finite (its mean is then undefined)."""
    means = (metric.baseline, metric.candidate)
    return metric.kind == "mean" and not all(m is not None and math.isfinite(m) for m in means)


def _unbounded(returns: MetricComparison) -> list[str]:
    """The note on a return whose interval too few episodes leave unbounded, if it is so.

    None on returns that are not finite: more episodes would not bound those (their own note).
    """
    if _nonfinite(returns):
        return []
    why = unverifiable(returns)
    if why is None:
        return []
    return [
        f"return: {why}, so the difference has no 95 % interval and a max_return_drop "
        "gate cannot be verified: record more episodes"
    ]


def unverifiable(metric: MetricComparison) -> str | None:
    """Why a mean's interval is unbounded for want of episodes (:func:`~.stats.too_few`)."""
    if metric.kind != "mean":
        return None
    return too_few(metric.baseline_n, metric.candidate_n, paired=metric.paired)


def _mark_repeats(metrics: list[MetricComparison], events: list[tuple[Any, Any]]) -> None:
    """Set ``same_test_as`` of each rate whose events (or their complement) an earlier one has.

    The same episodes counted (``failure_rate`` and its only label's), or the others
    (``success_rate`` and ``failure_rate`` without truncations), make the same test. A rate
    without a better direction (``truncation_rate``) has no test to share.
    """
    first: dict[bytes, str] = {}
    for metric, (b, c) in zip(metrics, events, strict=True):
        if not metric.can_reject or metric.better == "none":
            continue
        both = np.concatenate([b, c])
        key = (both if not both[0] else ~both).tobytes()
        metric.same_test_as = first.get(key)
        first.setdefault(key, metric.name)


def _is(base: Side, cand: Side, outcome: str) -> tuple[Any, Any]:
    return np.asarray(base.outcome == outcome, bool), np.asarray(cand.outcome == outcome, bool)


def check_gates(group: GroupComparison, gates: CompareGates) -> list[GateResult]:
    """Each gate that is on, checked against the group's metric: its interval's worse end.

    A return gate on returns of different reward wrappers (``not_comparable``), on returns
    that are not finite (whatever the number of episodes), or on too few episodes to bound the
    difference (:func:`unverifiable`), fails saying it cannot be verified, and why, not that
    the interval is beyond it.

    With ``fail_on_new_incentive_warning``, last, the gate ``new_incentive_warnings``.
    """
    by_name = {m.name: m for m in group.metrics}
    out: list[GateResult] = []
    for name, limit in gates.limits().items():
        metric = by_name.get(name)
        if metric is None:  # (success_rate: the env reports no success, as report's gate says)
            out.append(GateResult(_gate_name(name), group.key, False, _no_success(group.key)))
            continue
        if metric.not_comparable is not None:
            message = f"{name}: cannot be verified, {metric.not_comparable} (group {group.key})"
            out.append(GateResult(_gate_name(name), group.key, False, message))
            continue
        if _nonfinite(metric):
            message = f"{name}: cannot be verified, {NONFINITE} (group {group.key})"
            out.append(GateResult(_gate_name(name), group.key, False, message))
            continue
        why = unverifiable(metric)
        if why is not None:
            message = f"{name}: cannot be verified, {why}; record more (group {group.key})"
            out.append(GateResult(_gate_name(name), group.key, False, message))
            continue
        worse = metric.worse_bound()
        passed = worse <= limit
        what = "drop" if metric.better == "higher" else "increase"
        verb = "within" if passed else "beyond"
        shown, bound = _nums(worse, limit)
        out.append(
            GateResult(
                _gate_name(name),
                group.key,
                passed,
                f"{name}: the 95 % interval allows {'a' if what == 'drop' else 'an'} {what} of up "
                f"to {shown}, {verb} {bound} (group {group.key})",
            )
        )
    if gates.fail_on_new_incentive_warning:
        codes = ", ".join(w.code for w in group.new_warnings)
        message = f"{len(group.new_warnings)} incentive warning(s) new in the candidate"
        message += (f": {codes}" if codes else "") + f" (group {group.key})"
        out.append(GateResult(NEW_WARNINGS_GATE, group.key, not group.new_warnings, message))
    return out


def missing_gates(key: str, gates: CompareGates, base: Side, cand: Side | None) -> list[GateResult]:
    """Each gate that is on, failed on group ``key``: no candidate episode ended or raised there.

    ``base`` is the baseline's side of the group; ``cand`` every episode the candidate started
    in it (:func:`~.sides.started`: all ``incomplete``), ``None`` when it has none. No evidence
    is not a pass.
    """
    why = f"the candidate has no episode that ended or raised in group {key} (the baseline has "
    why += f"{base.everything.n}"
    if cand is not None:
        why += f"; the candidate's {cand.n}: {cand.n} {fmt.OUTCOME_INCOMPLETE}"
    why += "); record the candidate's episodes of it"
    names = [_gate_name(name) for name in gates.limits()]
    names += [NEW_WARNINGS_GATE] if gates.fail_on_new_incentive_warning else []
    return [GateResult(g, key, False, f"{g}: cannot be verified, {why}") for g in names]


def _no_success(key: str) -> str:
    """Why a success gate fails in a group whose env reports no success."""
    return (
        f"success_rate: the env reports no success (group {key}): no episode's final info "
        "has a success key and no success_fn was given; to gate on success, record with "
        "ending_rules=EndingRules(success_fn=...) or success_keys=(...)"
    )


def _gate_name(metric: str) -> str:
    """The gate of a metric: ``failure_rate:L`` -> ``max_failure_increase:L``."""
    if metric == "success_rate":
        return "max_success_drop"
    if metric == "return":
        return "max_return_drop"
    if metric == "error_rate":
        return "max_error_increase"
    label = metric.partition(":")[2]
    return "max_failure_increase" + (f":{label}" if label else "")


def _nums(value: float, limit: float) -> tuple[str, str]:
    """``value`` and ``limit`` to 4 significant figures, or more where they would read the same.

    >>> _nums(0.27751, 0.2775), _nums(0.05, 0.05), _nums(-0.0, 5.0)
    (('0.27751', '0.2775'), ('0.05', '0.05'), ('0', '5'))
    """
    for digits in range(4, 18):
        a, b = f"{value + 0.0:.{digits}g}", f"{limit + 0.0:.{digits}g}"  # (+ 0.0: no "-0")
        if a != b or value == limit:
            return a, b
    return a, b
