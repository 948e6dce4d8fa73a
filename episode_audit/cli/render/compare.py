"""Render a comparison: mismatches first, then metrics with verdicts, new warnings, gates."""

from __future__ import annotations

from collections.abc import Sequence

from rich.console import Group, RenderableType
from rich.text import Text

from ...compare import Comparison, MetricComparison
from ...compare.stats import NEVER
from ...read.inputs import Unreadable
from ...report.core import UNFINISHED_TITLE
from .common import (
    Output,
    OutputFormat,
    fmt_number,
    markdown_table,
    markdown_text,
    table,
    to_json,
    unreadable_json,
    unreadable_section,
    versioned,
)
from .junit import JUnitCase, JUnitStatus, junit_xml

__all__ = ["COMPARE_HEADERS", "compare_cases", "compare_output"]

COMPARE_HEADERS = [
    "group",
    "metric",
    "baseline",
    "candidate",
    "difference (95% CI)",
    "test",
    "p (Holm)",
    "verdict",
    "MDE",
    "n needed",
]


def _value(m: MetricComparison, value: float | None) -> str:
    if value is None:
        return "-"
    return f"{value:.1%}" if m.kind == "rate" else fmt_number(value)


def _difference(m: MetricComparison) -> str:
    if m.not_comparable is not None:  # (a side without an ended episode has no value)
        return "-" if m.baseline is None or m.candidate is None else "- (other units)"
    if m.kind == "rate":
        return f"{m.difference:+.1%} [{m.interval.low:+.1%}, {m.interval.high:+.1%}]"
    return (
        f"{fmt_number(m.difference)} [{fmt_number(m.interval.low)}, {fmt_number(m.interval.high)}]"
    )


def _test(m: MetricComparison) -> str:
    if m.not_comparable is not None:
        return "not compared"
    how = f"{m.pairs} pairs" if m.paired else f"unpaired: {m.pairs} pairs"
    return f"{m.test} ({how})"


def _files(n: int) -> str:
    return f"{n} file" if n == 1 else f"{n} files"


def _row(key: str, m: MetricComparison) -> list[str]:
    p = "-" if m.p_adjusted is None or m.not_comparable else fmt_number(m.p_adjusted)
    p_value = "-" if m.not_comparable else fmt_number(m.p_value)
    iqm = ""
    if m.kind == "mean" and m.baseline_iqm is not None and m.candidate_iqm is not None:
        iqm = f" (IQM {fmt_number(m.baseline_iqm)} -> {fmt_number(m.candidate_iqm)})"
    return [
        key,
        m.name + iqm,
        f"{_value(m, m.baseline)} (n {m.baseline_n})",
        f"{_value(m, m.candidate)} (n {m.candidate_n})",
        _difference(m),
        _test(m),
        f"{p_value} ({p})",
        m.verdict or "-",
        "-" if m.not_comparable else _value(m, m.mde),
        _needed(m),
    ]


def _needed(m: MetricComparison) -> str:
    """The units needed to decide the metric: for a metric not yet decided only.

    A ``regressed``, ``improved`` or ``held`` metric is decided with the units it has; a count
    there would read as the units still missing.
    """
    if m.verdict not in ("underpowered", "inconclusive") or m.not_comparable:
        return "-"
    return "∞" if m.n_needed >= NEVER else str(m.n_needed)


def compare_output(
    result: Comparison, output: OutputFormat, *, unreadable: Sequence[Unreadable] = ()
) -> Output:
    """The mismatches, the metrics with their verdicts, new warnings, gates and the verdict.

    ``unreadable``: the inputs that could not be read, listed (a table of their own, as the
    unfinished files; in JSON, where ``passed`` is then false): the command fails (exit 2),
    whatever the comparison of the files read says.
    """
    if output == "json":
        data = {**result.to_dict(), "unreadable": unreadable_json(unreadable)}
        data["passed"] = result.passed and not unreadable
        return to_json(versioned("compare", data))
    if output == "junit":
        return junit_xml(compare_cases(result, unreadable), name="episode-audit compare")
    sections: list[tuple[str, list[str], list[list[str]]]] = []
    if result.mismatches:
        rows = [[m.field, ", ".join(m.baseline), ", ".join(m.candidate)] for m in result.mismatches]
        sections.append(("Runs differ", ["field", "baseline", "candidate"], rows))
    rows = [_row(g.key, m) for g in result.groups for m in g.metrics]
    title = (
        f"Candidate ({_files(result.candidate_files)}) against baseline "
        f"({_files(result.baseline_files)}), by {result.by}"
    )
    sections.append((title, COMPARE_HEADERS, rows))
    warned = [[g.key, w.code, w.message] for g in result.groups for w in g.new_warnings]
    if warned:
        sections.append(
            ("Incentive warnings new in the candidate", ["group", "warning", "why"], warned)
        )
    gates = [
        [r.gate, r.group, "pass" if r.passed else "FAIL", r.message]
        for r in [*(r for g in result.groups for r in g.gates), *result.only_baseline_gates]
    ]
    if gates:
        sections.append(("Gates", ["gate", "group", "result", "detail"], gates))
    alone = [[k, "baseline"] for k in result.only_baseline]
    alone += [[k, "candidate"] for k in result.only_candidate]
    if alone:
        sections.append(("Groups on one side only (not compared)", ["group", "side"], alone))
    files = [
        (UNFINISHED_TITLE, ["file", "why"], [[name, why] for name, why in result.unfinished]),
        unreadable_section(unreadable),
    ]
    sections += [section for section in files if section[2]]
    verdicts = [[g.key, g.verdict] for g in result.groups] + [["overall", result.verdict]]
    sections.append(("Verdict", ["group", "verdict"], verdicts))
    if output == "markdown":
        parts = [f"### episode-audit compare: {markdown_text(result.verdict)}\n"]
        for title, headers, body in sections:
            parts += [f"#### {markdown_text(title)}\n", markdown_table(headers, body) + "\n"]
            if headers is COMPARE_HEADERS:
                parts += [markdown_text(note) + "\n" for note in result.reward_notes]
        return "\n".join(parts)
    # (the metrics side by side only when no cell wraps: "0.0% (n 20)" read over two lines is
    # no table; else the vertical layout)
    out: list[RenderableType] = []
    for title, headers, body in sections:
        out.append(table(title, headers, body, whole_cells=headers is COMPARE_HEADERS))
        if headers is COMPARE_HEADERS and result.reward_notes:  # (a blank line, as a table's)
            out.append(Text("\n".join(result.reward_notes) + "\n"))
    return Group(*out)


# A metric that could not be decided either way is skipped: a reporter shows it, CI does not fail.
_METRIC_STATUS: dict[str, JUnitStatus] = {
    "regressed": "failed",
    "improved": "passed",
    "held": "passed",
    "inconclusive": "skipped",
    "underpowered": "skipped",
    "mismatch": "passed",
    "passed": "passed",
    "failed": "failed",
    "new": "skipped",  # (reported, untested; the gate new_incentive_warnings fails on them)
}


def compare_cases(result: Comparison, unreadable: Sequence[Unreadable] = ()) -> list[JUnitCase]:
    """A suite per group (``spec`` for the runs' differences), a case per verdict, warning, gate.

    Fails exactly when the command exits 1 (a regression, a gate missed; a new incentive
    warning is skipped, and fails its gate when that is on); an input not read is an error
    case, as the command exits 2.
    """
    cases = []
    for c in result.cases():
        suite, _, name = c.name.partition("/")
        status = _METRIC_STATUS.get(c.status, "passed" if c.passed else "failed")
        cases.append(
            JUnitCase(suite, name, status, "" if status == "passed" else c.message, c.message)
        )
    return cases + [JUnitCase(u.file, "read", "error", u.why) for u in unreadable]
