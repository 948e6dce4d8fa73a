"""Gates: CI thresholds, each checked against every group of a report.

:class:`Gates` holds the thresholds (``None`` turns one off); :func:`check_gates` checks them
against each group, one :class:`GateResult` per gate and group, its message stating the numbers.
A per-label failure gate on a label no failure has (:func:`unmatched_labels`) passes, and says
that a misspelt label would pass every time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

from ..errors import ConfigurationError
from .groups import GroupReport
from .stats import rate

__all__ = [
    "GateResult",
    "Gates",
    "check_gateable",
    "check_gates",
    "is_rate",
    "unmatched_labels",
    "unmatched_why",
]


def is_rate(value: object) -> bool:
    """Whether ``value`` is a number between 0 and 1 (a rate a gate can bound).

    >>> is_rate(0.5), is_rate(1), is_rate(80), is_rate(float("nan")), is_rate(True)
    (True, True, False, False, False)
    """
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1


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
            if value is not None and not is_rate(value):
                raise ConfigurationError(
                    f"{name}: expected a rate between 0 and 1, actually: {value!r}"
                )
        if not isinstance(self.fail_on_incentive_warning, bool):
            raise ConfigurationError(
                "fail_on_incentive_warning: expected True or False, actually: "
                f"{self.fail_on_incentive_warning!r}"
            )


def check_gateable(by: str, gates: Gates | None) -> None:
    """Refuse gates that are not :class:`Gates`, or on a report grouped by label.

    Each label group holds one outcome, so its rates are 0 or 1 and its incentive warnings
    undefined by construction: every gate would pass or fail whatever the policy did.
    Raises :class:`ConfigurationError`.
    """
    if gates is not None and not isinstance(gates, Gates):
        given = type(gates).__name__
        how = "Gates(**gates)" if isinstance(gates, Mapping) else "Gates(min_success_rate=0.9)"
        raise ConfigurationError(f"gates: expected a Gates, got {given}; pass e.g. {how}")
    if by == "label" and gates is not None and gates.any:
        raise ConfigurationError(
            "gates: expected a grouping whose groups can hold several outcomes, actually by "
            "label (each group one outcome, its rates 0 or 1 by construction); gate a report "
            "by file, env, all or tag:NAME, and list the labels in a report by label"
        )


@dataclass(frozen=True)
class GateResult:
    """One gate checked against one group; ``message`` states the numbers."""

    gate: str
    group: str
    passed: bool
    message: str


def check_gates(
    gates: Gates, groups: Sequence[GroupReport], unit: str = "group"
) -> list[GateResult]:
    """Check every gate that is on against every group, group by group.

    Gates over no group at all fail (gate ``episodes``): nothing evaluated is not a pass. So
    do they over a group of 0 episodes (its files hold none: a torn file that lost them all),
    with one ``episodes`` result saying so of the ``unit`` (``file`` when grouped by file).
    """
    if not gates.any:
        return []
    if not groups:
        return [
            GateResult(
                "episodes", "-", False, "no episodes in these files: no gate could be checked"
            )
        ]
    unmatched = set(unmatched_labels(gates, groups))
    return [
        result
        for group in groups
        for result in (
            _group_gates(gates, group, unmatched) if group.episodes else [_no_episodes(group, unit)]
        )
    ]


def _no_episodes(group: GroupReport, unit: str) -> GateResult:
    """The gate result of a group of 0 episodes: no gate could be checked, a failure."""
    why = f"no episodes in this {unit}: no gate could be checked"
    return GateResult("episodes", group.key, False, why)


def unmatched_labels(gates: Gates | None, groups: Sequence[GroupReport]) -> list[str]:
    """The labels of per-label failure gates that no failure of any group has."""
    if gates is None:
        return []
    seen = {label for group in groups for label in group.failures}
    return sorted(set(gates.max_failure_rate_by_label) - seen)


def unmatched_why(label: str) -> str:
    """What a gate on a label no failure has means (a misspelt label always passes)."""
    return f"no failure in these files is labelled {label!r}: is the label spelt as recorded?"


def _group_gates(gates: Gates, group: GroupReport, unmatched: set[str]) -> list[GateResult]:
    """The gates that are on, checked against one group (in a fixed order)."""
    results: list[GateResult] = []
    if gates.min_success_rate is not None:
        results.append(_success_gate(group, gates.min_success_rate))
    if gates.max_failure_rate is not None:
        results.append(
            _gate(
                "max_failure_rate",
                group,
                "failure rate",
                group.failure_rate,
                gates.max_failure_rate,
            )
        )
    for label, bound in sorted(gates.max_failure_rate_by_label.items()):
        results.append(_label_gate(group, label, bound, unmatched))
    if gates.max_truncation_rate is not None:
        results.append(
            _gate(
                "max_truncation_rate",
                group,
                "truncation rate",
                group.truncation_rate,
                gates.max_truncation_rate,
            )
        )
    if gates.max_error_rate is not None:
        errors = rate(group.errors, group.episodes)
        what = "error rate (of all episodes)"
        results.append(_gate("max_error_rate", group, what, errors, gates.max_error_rate))
    if gates.fail_on_incentive_warning:
        results.append(_incentive_gate(group))
    return results


def _gate(
    gate: str,
    group: GroupReport,
    what: str,
    value: float | None,
    bound: float,
    *,
    minimum: bool = False,
) -> GateResult:
    """A rate ``value`` checked against its ``bound`` (a lower bound if ``minimum``)."""
    where = f"(group {group.key})"
    if value is None:
        return GateResult(gate, group.key, False, f"{what}: no ended episodes {where}")
    passed = value >= bound if minimum else value <= bound
    shown, limit = _show(value, bound)
    if minimum:
        op = ">=" if passed else "<"
    else:
        op = "<=" if passed else ">"
    return GateResult(gate, group.key, passed, f"{what} {shown} {op} {limit} {where}")


def _success_gate(group: GroupReport, bound: float) -> GateResult:
    """The success rate against its lower bound; a task that reports no success fails so.

    Its success rate is 0 by construction (CartPole: every ending is a fall or a time
    limit), so the gate cannot pass, and the message says why rather than "0.00 < bound".
    """
    if group.success_signal or not group.ended:
        return _gate(
            "min_success_rate", group, "success rate", group.success_rate, bound, minimum=True
        )
    return GateResult(
        "min_success_rate",
        group.key,
        False,
        f"success rate: the env reports no success (group {group.key}): no episode's final "
        "info has a success key and no success_fn was given; to gate on success, record with "
        "ending_rules=EndingRules(success_fn=...) or success_keys=(...)",
    )


def _label_gate(group: GroupReport, label: str, bound: float, unmatched: set[str]) -> GateResult:
    """The failure rate of one label; a label no failure has says so (a misspelling passes)."""
    value = rate(group.failures.get(label, 0), group.ended)
    result = _gate(f"max_failure_rate:{label}", group, f"failure rate {label!r}", value, bound)
    if label in unmatched:
        result = replace(result, message=f"{result.message}; {unmatched_why(label)}")
    return result


def _incentive_gate(group: GroupReport) -> GateResult:
    """Passes when the group has no incentive warning."""
    codes = ", ".join(w.code for w in group.warnings)
    return GateResult(
        "incentive_warnings",
        group.key,
        not group.warnings,
        f"{len(group.warnings)} incentive warning(s)"
        + (f": {codes}" if codes else "")
        + f" (group {group.key})",
    )


def _show(value: float, bound: float) -> tuple[str, str]:
    """A rate and its bound as text: the bound as given, the rate with at least its digits.

    The rate has more when needed to differ from the bound (when it does).

    >>> _show(0.25, 0.085), _show(0.9166, 0.915), _show(0.5, 0.5), _show(0.3333333, 0.3333)
    (('0.250', '0.085'), ('0.917', '0.915'), ('0.50', '0.50'), ('0.33333', '0.3333'))
    """
    given = repr(float(bound))
    decimals = len(given.partition(".")[2]) if "e" not in given else 0
    limit = given if decimals >= 2 or "e" in given else f"{bound:.2f}"
    for digits in range(max(2, min(decimals, 7)), 8):
        a, b = f"{value:.{digits}f}", f"{bound:.{digits}f}"
        if a != b or value == bound:
            return a, limit
    return repr(value), repr(bound)
