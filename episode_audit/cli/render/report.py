"""Render a report: rates side by side with intervals, terms, warnings, gates."""

from __future__ import annotations

from collections.abc import Sequence

from rich.console import Group, RenderableType
from rich.text import Text

from ...format.columns import counted
from ...read.inputs import Unreadable
from ...report import GroupReport, Report
from ...report.core import DROPPED_TITLE, UNFINISHED_TITLE
from ...report.stats import rate_text
from .common import (
    UNREADABLE_TITLE,
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
from .junit import JUnitCase, junit_xml

__all__ = ["REPORT_HEADERS", "report_cases", "report_output"]


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "-"


def _mean_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "-"
    return f"{fmt_number(mean)} ± {fmt_number(std or 0.0)}"


def _group_row(g: GroupReport) -> list[str]:
    return [
        g.key,
        str(g.episodes),
        f"{g.success} ({rate_text(g.success_rate, g.success_ci)})",
        f"{sum(g.failures.values())} ({rate_text(g.failure_rate, g.failure_ci)})",
        _counts(g.failures),
        f"{sum(g.truncations.values())} ({rate_text(g.truncation_rate, g.truncation_ci)})",
        _counts(g.truncations),
        str(g.incomplete),
        str(g.errors),
        str(g.terminated_and_truncated),
        _mean_std(g.return_mean, g.return_std),
        _mean_std(g.length_mean, g.length_std),
    ]


REPORT_HEADERS = [
    "group",
    "episodes",
    "success (95% CI)",
    "failure (95% CI)",
    "failure labels",
    "truncated (95% CI)",
    "truncation reasons",
    "incomplete",
    "error",
    "term.+trunc.",
    "return",
    "length",
]


def report_output(
    result: Report, output: OutputFormat, *, unreadable: Sequence[Unreadable] = ()
) -> Output:
    """The success / failure / truncation table, term breakdown, warnings and gates.

    ``unreadable``: ``(file, why)`` of the inputs that could not be read, listed (a table of
    their own; in JSON, where ``passed`` is then false): the command fails (exit 2), whatever
    the gates said of the files it read.
    """
    if output == "json":
        data = {**result.to_dict(), "unreadable": unreadable_json(unreadable)}
        data["passed"] = result.passed and not unreadable
        return to_json(versioned("report", data))
    if output == "junit":
        return junit_xml(report_cases(result, unreadable), name="episode-audit report")
    rows = [_group_row(g) for g in result.groups]
    sections = [s for s in [*_sections(result), unreadable_section(unreadable)] if s[2]]
    if output == "markdown":
        parts = [
            f"### episode-audit report (by {markdown_text(result.by)}{_unit(result)})\n",
            (markdown_table(REPORT_HEADERS, rows) if rows else NO_EPISODES) + "\n",
        ]
        if result.reward_note:
            parts.append(markdown_text(result.reward_note) + "\n")
        for title, headers, section_rows in sections:
            parts += [f"#### {title}\n", markdown_table(headers, section_rows) + "\n"]
        return "\n".join(parts)
    if not result.groups:  # (an empty table's title would wrap in its one column)
        kept = [table(*s) for s in sections if s[0] in _KEPT]
        return Group(Text(NO_EPISODES + ("\n" if kept else "")), *kept)
    # The terminal keeps labels and reasons in a table of their own, each label on its own
    # line; the outcomes are side by side when no cell wraps (about 150 columns), else vertical
    narrow = [i for i, h in enumerate(REPORT_HEADERS) if h not in _LABEL_HEADERS]
    out: list[RenderableType] = [
        table(
            f"Outcomes (by {result.by}{_unit(result)})",
            [REPORT_HEADERS[i] for i in narrow],
            [[row[i] for i in narrow] for row in rows],
            whole_cells=True,
        )
    ]
    if result.reward_note:
        out.append(Text(result.reward_note + "\n"))  # (a blank line, as under a table)
    endings = _ending_rows(result)
    if endings:
        out.append(
            table(
                "Failure labels and truncation reasons",
                ["group", "outcome", "label / reason", "episodes"],
                endings,
            )
        )
    out += [table(*s) for s in sections]
    return Group(*out)


_GATES = "Gates"
_KEPT = (_GATES, UNFINISHED_TITLE, DROPPED_TITLE, UNREADABLE_TITLE)
"""The tables a report without episodes still shows."""


def _sections(result: Report) -> list[tuple[str, list[str], list[list[str]]]]:
    """The tables under the outcomes, as (title, headers, rows): terms, warnings, gates, files.

    The files: unfinished ones, and those whose recorder dropped what it could not write.
    """
    terms = [
        [g.key, outcome, term, fmt_number(value)]
        for g in result.groups
        for outcome, means in sorted(g.term_means.items())
        for term, value in sorted(means.items())
    ]
    warnings = [[w.group, w.code, w.message] for g in result.groups for w in g.warnings]
    gates = [[r.gate, r.group, "pass" if r.passed else "FAIL", r.message] for r in result.gates]
    return [
        ("Reward terms by outcome", ["group", "outcome", "term", "mean total per episode"], terms),
        ("Incentive warnings", ["group", "warning", "why"], warnings),
        (_GATES, ["gate", "group", "result", "detail"], gates),
        (UNFINISHED_TITLE, ["file", "why"], [[name, why] for name, why in result.unfinished]),
        (DROPPED_TITLE, ["file", "what"], [[name, what] for name, what in result.dropped]),
    ]


_LABEL_HEADERS = ("failure labels", "truncation reasons")

NO_EPISODES = "No episodes: none in these files took a step (only those are counted)."


def _ending_rows(result: Report) -> list[list[str]]:
    """Per group, outcome and failure label / truncation reason: the episodes."""
    return [
        [g.key, outcome, label, str(n)]
        for g in result.groups
        for outcome, counted in (("failure", g.failures), ("truncated", g.truncations))
        for label, n in sorted(counted.items())
    ]


def _group_line(g: GroupReport, unit: str) -> str:
    """One line of a group's outcomes, as the table shows them."""
    return (
        f"group {g.key}: {counted(g.episodes, unit)}; success {g.success} "
        f"({rate_text(g.success_rate, g.success_ci)}), failure {g.failure} "
        f"({rate_text(g.failure_rate, g.failure_ci)}; {_counts(g.failures)}), truncated "
        f"{g.truncated} ({rate_text(g.truncation_rate, g.truncation_ci)}; "
        f"{_counts(g.truncations)}), incomplete {g.incomplete}, error {g.errors}; "
        f"return {_mean_std(g.return_mean, g.return_std)}"
    )


def report_cases(result: Report, unreadable: Sequence[Unreadable] = ()) -> list[JUnitCase]:
    """A suite per group, a case per gate; an input not read is an error case.

    A gate's message states its numbers; its details, the group's outcomes and incentive
    warnings. A report without gates has no case but the unreadable inputs'.
    """
    groups = {g.key: g for g in result.groups}
    details: dict[str, str] = {}
    for key, g in groups.items():
        lines = [_group_line(g, result.unit)]
        lines += [f"incentive warning {w.code}: {w.message}" for w in g.warnings]
        lines += [result.reward_note] if result.reward_note else []
        details[key] = "\n".join(lines)
    cases = [
        JUnitCase(
            r.group,
            r.gate,
            "passed" if r.passed else "failed",
            "" if r.passed else r.message,
            "\n".join(filter(None, [r.message, details.get(r.group, "")])),
        )
        for r in result.gates
    ]
    return cases + [JUnitCase(u.file, "read", "error", u.why) for u in unreadable]


def _unit(result: Report) -> str:
    """``", games"`` when a report counts PettingZoo games instead of episodes."""
    return ", games" if result.unit == "game" else ""
