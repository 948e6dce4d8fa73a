"""Did the candidate regress? :func:`compare` and the :class:`Comparison` it returns.

:func:`compare` opens two sets of evidence files, :func:`compare_tables` compares files already
opened, :func:`compare_parts` the parts taken from each file (:func:`side_file`, in a worker
maybe): what differs between the runs first (a different task is refused unless allowed), then
per group (report's ``by``) every metric with its interval, test and verdict, the p-values of the
primary metrics of all groups Holm-adjusted as one family, the gates, and the incentive warnings
new in the candidate (reported, untested: they fail a gate when asked, never the verdict).
:meth:`Comparison.cases` lists it all as named pass/fail cases (one test case each in a JUnit
file). Statistics and verdicts: ``docs/compare.md``.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from ..errors import ConfigurationError
from ..format.columns import counted
from ..read import Evidence, open_evidence
from ..read.arguments import path_list
from ..read.storage import is_url
from ..report import GateResult
from ..report.collect import is_by, joined
from ..report.core import FilePart, check_runs_apart, file_part, missing_tag, missing_tag_note
from ..report.gates import unmatched_why
from ..report.groups import group_reports
from ..report.wrapped import Wrapped
from .groups import (
    RATE_MARGIN,
    CompareGates,
    GroupComparison,
    check_gates,
    check_limit,
    combine,
    compare_group,
    gate_json,
    missing_gates,
)
from .metrics import Verdict, settle
from .sides import Side, sides, started
from .spec import Mismatch, field_mismatches, limits_note, run_fields
from .stats import holm

__all__ = [
    "Case",
    "Comparison",
    "SideFile",
    "check_apart",
    "check_compare_by",
    "check_tasks",
    "compare",
    "compare_parts",
    "compare_tables",
    "side_file",
]


@dataclass(frozen=True)
class Case:
    """One named outcome of a comparison: a mismatch, a metric's verdict, a gate, a warning."""

    name: str
    status: str
    passed: bool
    message: str


@dataclass
class Comparison:
    """Two sets of runs compared: mismatches first, then one :class:`GroupComparison` a group.

    ``verdict`` combines the groups' (:func:`~.groups.combine`); ``passed`` is false when it is
    ``regressed`` or a gate failed. ``only_baseline`` / ``only_candidate`` name the groups one
    side lacks (not compared): a group only the baseline has makes the verdict at best
    ``inconclusive``, and fails every gate that is on (``only_baseline_gates``: no evidence is
    not a pass); one only the candidate has is a note (no baseline, no change to bound);
    ``unfinished`` the files still being written or torn (compared
    with what was flushed so far), with why; ``baseline_files`` / ``candidate_files`` count
    each side's files; ``unmatched_labels`` are the labels of per-label gates no failure has
    (a misspelt label would pass every time; :attr:`notes` says so); ``baseline_wrapped`` /
    ``candidate_wrapped`` count each side's files recorded over reward wrappers
    (:attr:`reward_notes`).
    """

    by: str
    mismatches: list[Mismatch]
    groups: list[GroupComparison]
    only_baseline: list[str] = field(default_factory=list)
    only_candidate: list[str] = field(default_factory=list)
    unfinished: list[tuple[str, str]] = field(default_factory=list)
    baseline_files: int = 0
    candidate_files: int = 0
    unmatched_labels: list[str] = field(default_factory=list)
    seen_labels: list[str] = field(default_factory=list)
    baseline_wrapped: Wrapped = field(default_factory=Wrapped)
    """The baseline's files recorded over reward wrappers (their returns are not the env's)."""
    candidate_wrapped: Wrapped = field(default_factory=Wrapped)
    """The candidate's, likewise."""
    only_baseline_gates: list[GateResult] = field(default_factory=list)
    """Each gate that is on, failed on each group only the baseline has: it cannot be verified."""
    limits_note: str | None = None
    """Why the sides' time limits were not compared (:func:`~.spec.limits_note`), if so."""
    missing_tag: str | None = None
    """The tag of ``by="tag:NAME"`` when no file of either side has it (a misspelling, maybe)."""

    @property
    def reward_notes(self) -> list[str]:
        """A line (80 columns) for each side whose files' returns are a reward wrapper's.

        Said once in each output: under the metrics table, in JSON as ``reward_wrappers``.
        Where the sides' wrappers differ, a group's ``return`` is not compared (its note).
        """
        notes = [self.baseline_wrapped.note("baseline"), self.candidate_wrapped.note("candidate")]
        return [n for n in notes if n is not None]

    @property
    def verdict(self) -> Verdict:
        """The overall verdict; ``inconclusive`` stands for each group only the baseline has."""
        missing: list[Verdict] = ["inconclusive"] if self.only_baseline else []
        return combine([*(g.verdict for g in self.groups), *missing])

    @property
    def notes(self) -> list[str]:
        """What the options matched nothing of, and what the comparison could not use, a line each.

        Time limits not compared; ``by="tag:NAME"`` with a tag no file has; a per-label failure
        gate on a label no failure of either side has; a group's notes (error episodes, returns
        that are not finite), naming the group; a group on one side only.
        """
        seen = ", ".join(map(repr, self.seen_labels)) or "none"
        notes = [] if self.limits_note is None else [self.limits_note]
        if self.missing_tag is not None:
            notes.append(missing_tag_note(self.missing_tag))
        notes += [
            f"gate max_failure_increase:{label}: {unmatched_why(label)} (labels seen: {seen})"
            for label in self.unmatched_labels
        ]
        notes += [f"group {g.key}: {note}" for g in self.groups for note in g.notes]
        notes += [
            f"group {key}: only the baseline has episodes that ended or raised in it: not "
            "compared, so the verdict is at best inconclusive, and a gate there cannot be "
            "verified (fails)"
            for key in self.only_baseline
        ]
        return notes + [
            f"group {key}: only the candidate has it: no baseline to compare with, so not "
            "compared and no gate checked there (`episode-audit report` gates its rates)"
            for key in self.only_candidate
        ]

    @property
    def passed(self) -> bool:
        """Whether the candidate did not regress and every gate passed."""
        gates = all(g.passed for group in self.groups for g in group.gates)
        return self.verdict != "regressed" and gates and not self.only_baseline_gates

    def cases(self) -> list[Case]:
        """Every outcome as a named case, mismatches first (a mismatch alone does not fail)."""
        out = [Case(f"spec/{m.field}", "mismatch", True, str(m)) for m in self.mismatches]
        for group in self.groups:
            for m in group.metrics:
                if m.verdict is not None:
                    message = _metric_line(m.name, m.difference, m.interval, m.verdict)
                    if m.not_comparable is not None:
                        message = f"{m.name}: {m.verdict}, not compared: {m.not_comparable}"
                    out.append(
                        Case(f"{group.key}/{m.name}", m.verdict, m.verdict != "regressed", message)
                    )
            for w in group.new_warnings:  # (reported; only a gate fails on them)
                out.append(Case(f"{group.key}/incentive:{w.code}", "new", True, w.message))
            out += [_gate_case(g) for g in group.gates]
        return out + [_gate_case(g) for g in self.only_baseline_gates]

    def to_dict(self) -> dict[str, Any]:
        """The comparison as JSON-able values (the shape: ``docs/compare.md``)."""
        return {
            "by": self.by,
            "verdict": self.verdict,
            "passed": self.passed,
            "baseline_files": self.baseline_files,
            "candidate_files": self.candidate_files,
            "mismatches": [
                {"field": m.field, "baseline": m.baseline, "candidate": m.candidate}
                for m in self.mismatches
            ],
            "groups": [g.to_dict() for g in self.groups],
            "only_baseline": list(self.only_baseline),
            "only_candidate": list(self.only_candidate),
            "only_baseline_gates": [gate_json(g) for g in self.only_baseline_gates],
            "unfinished": [{"file": name, "why": why} for name, why in self.unfinished],
            "unmatched_labels": list(self.unmatched_labels),
            "notes": self.notes,
            "reward_wrappers": {
                "baseline": self.baseline_wrapped.to_json(),
                "candidate": self.candidate_wrapped.to_json(),
            },
            "cases": [
                {"name": c.name, "status": c.status, "passed": c.passed, "message": c.message}
                for c in self.cases()
            ],
        }


def _gate_case(gate: GateResult) -> Case:
    status = "passed" if gate.passed else "failed"
    return Case(f"{gate.group}/gate:{gate.gate}", status, gate.passed, gate.message)


def _metric_line(name: str, diff: float, interval: Any, verdict: str) -> str:
    ci = f"95 % CI {interval.low:+.4g} to {interval.high:+.4g}"
    return f"{name}: {verdict}, difference {diff:+.4g} ({ci})"


def compare_tables(
    baseline: Iterable[tuple[str, Evidence]],
    candidate: Iterable[tuple[str, Evidence]],
    *,
    by: str = "all",
    gates: CompareGates | None = None,
    different_tasks: bool = False,
    rate_margin: float = RATE_MARGIN,
) -> Comparison:
    """Compare opened evidence files, given as ``(name, evidence)`` pairs; see :func:`compare`."""
    check_compare_by(by)
    return compare_parts(
        [side_file(name, ev, by) for name, ev in baseline],
        [side_file(name, ev, by) for name, ev in candidate],
        by=by,
        gates=gates,
        different_tasks=different_tasks,
        rate_margin=rate_margin,
    )


def check_compare_by(by: str) -> None:
    """``by`` checked: a report's grouping (:func:`~.report.collect.is_by`) two sides share."""
    groupings = "'all', 'env', 'env_index', 'agent' or 'tag:NAME'"
    if not is_by(by):
        raise ConfigurationError(f"by: expected {groupings}, actually: {by!r}")
    if by in ("file", "label"):
        why = {
            "file": "the two sides have different files, so no group would match",
            "label": "each group would hold one outcome, so every rate would be 0 or 1",
        }[by]
        raise ConfigurationError(f"by={by!r}: {why}; group by {groupings}")


@dataclass(frozen=True)
class SideFile:
    """What a comparison takes from one file (:func:`side_file`), small enough to send back."""

    part: FilePart
    fields: dict[str, str]
    """The run's fields the sides are compared on (:func:`~.spec.run_fields`)."""


def side_file(name: str, ev: Evidence, by: str) -> SideFile:
    """The part of a comparison that comes from the file ``ev`` (``name``: as listed)."""
    return SideFile(file_part(name, ev, by), run_fields(ev))


def compare_parts(
    baseline: Sequence[SideFile],
    candidate: Sequence[SideFile],
    *,
    by: str = "all",
    gates: CompareGates | None = None,
    different_tasks: bool = False,
    rate_margin: float = RATE_MARGIN,
) -> Comparison:
    """Compare the sides' files from their parts (:func:`side_file`), as :func:`compare_tables`."""
    check_compare_by(by)
    _check_options(baseline, candidate, gates, rate_margin)
    check_runs_apart([f.part for f in baseline], "the baseline's ")
    check_runs_apart([f.part for f in candidate], "the candidate's ")
    found = check_tasks(baseline, candidate, different_tasks)
    gates = gates or CompareGates()
    tables_b = _tasked(baseline, joined(f.part.rows for f in baseline))
    tables_c = _tasked(candidate, joined(f.part.rows for f in candidate))
    sides_b, sides_c = sides(*tables_b), sides(*tables_c)
    _check_sides(sides_b, "baseline", tables_b[0])
    _check_sides(sides_c, "candidate", tables_c[0])
    if not set(sides_b) & set(sides_c):
        raise ConfigurationError(
            f"by={by!r}: no group is on both sides (baseline: {_keys(sides_b)}; candidate: "
            f"{_keys(sides_c)}): group by a key the sides share, e.g. 'all' or 'env'"
        )
    warned_b = {g.key: {w.code for w in g.warnings} for g in group_reports(*tables_b)}
    warned_c = {g.key: g.warnings for g in group_reports(*tables_c)}
    groups = [
        compare_group(
            key,
            sides_b[key],
            sides_c[key],
            gates,
            [w for w in warned_c.get(key, []) if w.code not in warned_b.get(key, set())],
            rate_margin,
        )
        for key in sorted(set(sides_b) & set(sides_c))
    ]
    _decide(groups)
    for group in groups:
        group.gates = check_gates(group, gates)
    started_c = started(*tables_c)
    unverified = [
        gate
        for key in sorted(set(sides_b) - set(sides_c))
        for gate in missing_gates(key, gates, sides_b[key], started_c.get(key))
    ]
    parts = [f.part for f in [*baseline, *candidate]]
    seen = _failure_labels([*sides_b.values(), *sides_c.values()])
    return Comparison(
        by,
        found,
        groups,
        sorted(set(sides_b) - set(sides_c)),
        sorted(set(sides_c) - set(sides_b)),
        [(p.name, p.unfinished) for p in parts if p.unfinished is not None],
        len(baseline),
        len(candidate),
        sorted(set(gates.max_failure_increase_by_label) - set(seen)),
        seen,
        Wrapped.of(f.part.reward_wrappers for f in baseline),
        Wrapped.of(f.part.reward_wrappers for f in candidate),
        unverified,
        limits_note([f.fields for f in baseline], [f.fields for f in candidate]),
        missing_tag(by, parts),
    )


def _tasked(
    files: Sequence[SideFile], tables: tuple[pa.Table, pa.Table]
) -> tuple[pa.Table, pa.Table]:
    """``joined``'s tables of ``files`` with each episode's env id (``task``): pairs stay in one."""
    episodes, terms = tables
    ids = [
        f.fields["env_id"]
        for f in files
        if f.part.rows[0] is not None
        for _ in range(f.part.rows[0].num_rows)
    ]
    return episodes.append_column("task", pa.array(ids, pa.string())), terms


def check_tasks(
    baseline: Sequence[SideFile],
    candidate: Sequence[SideFile],
    allowed: bool,
    how: str = "different_tasks=True",
) -> list[Mismatch]:
    """What differs between the sides' runs; a different task refused unless ``allowed``.

    The :class:`ConfigurationError` says to pass ``how`` (``--different-tasks`` on the
    command line).
    """
    found = field_mismatches([f.fields for f in baseline], [f.fields for f in candidate])
    tasks = [m for m in found if m.task]
    if tasks and not allowed:
        raise ConfigurationError(
            f"the sides run different tasks ({tasks[0]}); to compare them anyway pass {how}"
        )
    return found


def _check_options(
    baseline: Sequence[SideFile], candidate: Sequence[SideFile], gates: Any, rate_margin: Any
) -> None:
    """Refuse a side without files, gates that are not :class:`CompareGates`, a bad margin."""
    for side, files in (("baseline", baseline), ("candidate", candidate)):
        if not files:
            raise ConfigurationError(
                f"no {side} files: expected at least one evidence file on each side, got none "
                f"for the {side}; give its files"
            )
    if gates is not None and not isinstance(gates, CompareGates):
        hint = (
            "report's Gates bound one run's rates, compare's bound the change: "
            if type(gates).__name__ == "Gates"
            else ""
        )
        raise ConfigurationError(
            f"gates: expected a CompareGates, got {type(gates).__name__}; {hint}pass e.g. "
            "CompareGates(max_success_drop=0.05)"
        )
    check_limit("rate_margin", rate_margin, "margin")


def _failure_labels(found: Iterable[Side]) -> list[str]:
    """The failure labels of the sides' failed episodes, sorted."""
    return sorted({label for side in found for label in side.failure_names() if label})


def check_apart(baseline: Sequence[Any], candidate: Sequence[Any]) -> None:
    """Refuse a file on both sides (:class:`ConfigurationError`): it would be compared with itself.

    ``baseline`` and ``candidate`` hold paths, URLs or :class:`~..read.storage.RemoteFile`;
    local paths are compared resolved.
    """

    def where(path: Any) -> str:
        text = str(getattr(path, "url", path))
        return text if is_url(text) else str(Path(text).resolve())

    base = {where(p) for p in baseline}
    both = [p for p in candidate if where(p) in base]
    if both:
        raise ConfigurationError(
            f"{both[0]} is on both sides: a file compared with itself shows nothing; give each "
            "side its own files (--candidate takes one path each time: repeat it before each "
            "candidate file, or give the candidates' directory)"
        )


def _keys(found: dict[str, Any]) -> str:
    keys = sorted(found)
    return ", ".join(map(repr, keys[:5])) + (f" and {len(keys) - 5} more" if len(keys) > 5 else "")


def _check_sides(found: dict[str, Any], side: str, episodes: pa.Table) -> None:
    """Refuse a side without an episode that ended or raised, saying how its episodes went.

    Its episodes are then all ``incomplete`` (the recording stopped inside them), or none
    began: no metric has a value of it. A side whose episodes all raised is compared (its
    error rate is measured).
    """
    if not found:
        counts = Counter(episodes.column("outcome").to_pylist()) if episodes.num_rows else {}
        how = ", ".join(f"{outcome} {n}" for outcome, n in sorted(counts.items()))
        raise ConfigurationError(
            f"the {side} has no episode that ended or raised (success, failure, truncated or "
            "error) to compare"
            + (f" (its {counted(episodes.num_rows, 'episode')}: {how})" if how else "")
            + ": record some, or check its files with `episode-audit report`"
        )


def _decide(groups: Sequence[GroupComparison]) -> None:
    """Holm-adjust the primary metrics' p-values of all groups as one family; set verdicts.

    A metric whose test cannot reject (``can_reject`` false) is left out of the family (its
    p-value stands), and one that repeats another's test (``same_test_as``) takes that one's
    adjusted p-value: each hypothesis is counted once.
    """
    primary = [(g, m) for g in groups for m in g.metrics if m.better != "none"]
    family = [m for _, m in primary if m.can_reject and m.same_test_as is None]
    for metric, adjusted in zip(family, holm([m.p_value for m in family]), strict=True):
        metric.p_adjusted = adjusted
    for group, metric in primary:
        if metric.same_test_as is not None:
            metric.p_adjusted = group.metric(metric.same_test_as).p_adjusted
        elif not metric.can_reject:
            metric.p_adjusted = metric.p_value
        settle(metric)


def compare(
    baseline: Iterable[str | os.PathLike[str]],
    candidate: Iterable[str | os.PathLike[str]],
    *,
    by: str = "all",
    gates: CompareGates | None = None,
    different_tasks: bool = False,
    rate_margin: float = RATE_MARGIN,
) -> Comparison:
    """Compare the episodes of the ``candidate`` files with those of the ``baseline`` files.

    Episodes are grouped as :func:`~episode_audit.report.report` groups them (``by``; not
    ``"file"`` nor ``"label"``), and groups of the same key are compared. Where the sides
    share reset seeds the comparison is paired. Files of different env ids raise
    :class:`~episode_audit.errors.ConfigurationError` unless ``different_tasks``; other
    differences (env kwargs, time limit, library versions) are listed in
    :attr:`Comparison.mismatches`. A rate without a gate is ``held`` when its interval stays
    within ``rate_margin`` of no change (a return without a gate: half the baseline's standard
    deviation).

    Example:
        >>> import tempfile, pathlib
        >>> from episode_audit.rollout import record_episodes
        >>> out = pathlib.Path(tempfile.mkdtemp())
        >>> for name in ("base", "cand"):
        ...     _ = record_episodes("CartPole-v1", out / f"{name}.mcap", episodes=5,
        ...                         max_episode_steps=20)
        >>> result = compare([out / "base.mcap"], [out / "cand.mcap"])
        >>> result.verdict, result.groups[0].pairs, result.passed
        ('underpowered', 5, True)
    """
    check_compare_by(by)
    baseline, candidate = path_list(baseline, "baseline"), path_list(candidate, "candidate")
    check_apart(baseline, candidate)
    opened_b = [(str(p), open_evidence(p)) for p in baseline]
    opened_c = [(str(p), open_evidence(p)) for p in candidate]
    return compare_tables(
        opened_b,
        opened_c,
        by=by,
        gates=gates,
        different_tasks=different_tasks,
        rate_margin=rate_margin,
    )
