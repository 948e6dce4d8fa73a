r"""Render audit results as Rich tables, Markdown (for CI job summaries) or JSON.

Every string that comes from an evidence file (labels, messages, env ids, tags, term names) is
made safe before display: table titles, headers and cells are ``rich.text.Text`` objects (never
parsed as markup), and control characters such as ANSI escapes are shown as escape sequences
(``\x1b``), not interpreted. In Markdown, backslashes, pipes, backticks, ``<``, ``>``, ``&``
and a ``]`` that would close a link text are backslash-escaped, so a value can neither break a
table row nor become a link, a code span or HTML.

>>> safe("[red]x[/red]\x1b[2J")
'[red]x[/red]\\x1b[2J'
>>> print(markdown_table(["a", "b"], [["1", "x|y"]]))
| a | b |
| --- | --- |
| 1 | x\|y |
>>> markdown_text("[a](x) <b>|`c`")
'[a\\](x) \\<b\\>\\|\\`c\\`'
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any, Literal

import numpy as np
from rich import box
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from ..check.core import CheckResult
from ..replay.single import ReplayResult
from ..report.core import GroupReport, Interval, Report

__all__ = [
    "OutputFormat",
    "check_output",
    "fmt_number",
    "markdown_table",
    "markdown_text",
    "replay_output",
    "report_output",
    "safe",
    "table",
    "to_json",
]

OutputFormat = Literal["table", "markdown", "json"]
Output = RenderableType | str


def safe(value: Any) -> str:
    """``str(value)`` with control characters written as escapes (no ANSI, no newlines)."""
    text = str(value)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def fmt_number(value: float | None, digits: int = 3) -> str:
    """A compact number for tables (``-`` for missing).

    ``digits`` significant digits, whole numbers in full up to a million (a MuJoCo return reads
    ``4824``, not ``4.82e+03``); ``nan`` for a NaN (not missing: a value that is not a number).

    >>> [fmt_number(x) for x in (None, math.nan, 4823.7, 1000.0, 12.345, -0.05291, 2.5e7, 7)]
    ['-', 'nan', '4824', '1000', '12.3', '-0.0529', '2.500e+07', '7']
    """
    if value is None:
        return "-"
    if isinstance(value, (int, np.integer)):
        return str(value)
    if not math.isfinite(value):
        return str(float(value))  # nan, inf, -inf
    size = abs(value)
    if size >= 1e6:
        return f"{value:.3e}"
    if size >= 10**digits:
        return f"{value:.0f}"
    return f"{value:.{digits}g}"


def _rate(rate: float | None) -> str:
    return "-" if rate is None else f"{rate:.1%}"


def table(title: str | None, headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> Table:
    """A Rich table of plain text: title, headers and cells are never parsed as markup."""
    out = Table(
        title=None if title is None else Text(safe(title), style="table.title"),
        box=box.SIMPLE_HEAD,
        title_justify="left",
        pad_edge=False,
    )
    for header in headers:
        out.add_column(Text(safe(header), style="table.header"), overflow="fold")
    for row in rows:
        out.add_row(*(Text(safe(cell)) for cell in row))
    return out


_MARKDOWN_ESCAPES = str.maketrans({c: "\\" + c for c in "\\|`<>&"})


def markdown_text(value: Any) -> str:
    """``safe(value)`` for Markdown: one line, shown literally (no link, code span or HTML)."""
    text = safe(value).translate(_MARKDOWN_ESCAPES)
    return text.replace("](", "\\](").replace("][", "\\][") if "]" in text else text


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table (cells escaped), pasteable into a CI job summary."""
    cell = markdown_text

    lines = [
        "| " + " | ".join(cell(h) for h in headers) + " |",
        "| " + " | ".join("---" for _ in headers) + " |",
    ]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def to_json(data: Any) -> str:
    """Stable, indented JSON (keys in insertion order, non-finite floats as strings)."""
    from ..format.records import to_jsonable

    return json.dumps(to_jsonable(data), indent=2, allow_nan=False)


# ----------------------------------------------------------------------------- check


def _unreadable_json(unreadable: Iterable[tuple[str, str]]) -> list[dict[str, str]]:
    """``[{"file", "why"}]``: the inputs a command could not read (each also named on stderr)."""
    return [{"file": file, "why": why} for file, why in unreadable]


def check_output(
    result: CheckResult, output: OutputFormat, *, unreadable: Sequence[tuple[str, str]] = ()
) -> Output:
    """Findings of ``check`` in the requested format.

    ``unreadable``: ``(file, why)`` of the inputs that could not be read, listed in JSON.
    """
    if output == "json":
        return to_json({**result.to_dict(), "unreadable": _unreadable_json(unreadable)})
    headers = ["severity", "file", "episode", "step", "code", "message"]
    rows = [
        [
            f.severity,
            f.file,
            "-" if f.episode is None else f.episode,
            "-" if f.step is None else f.step,
            f.code,
            f.message,
        ]
        for f in result.findings
    ]
    summary = (
        f"{len(result.files)} file(s), {result.episodes} episodes, {result.steps} steps: "
        f"{result.errors} error(s), {result.warnings} warning(s), {result.notes} note(s)"
        + (f", {result.ignored} ignored" if result.ignored else "")
    )
    if output == "markdown":
        body = markdown_table(headers, rows) if rows else "_no findings_"
        return f"### episode-audit check\n\n{summary}\n\n{body}\n"
    parts: list[RenderableType] = []
    if rows:
        parts.append(table("Findings", headers, rows))
    parts.append(Text(summary))
    return Group(*parts)


# ----------------------------------------------------------------------------- replay


def replay_output(
    result: ReplayResult, output: OutputFormat, *, unreadable: Sequence[tuple[str, str]] = ()
) -> Output:
    """Replay results: one row per episode that was not identical, plus a summary.

    ``unreadable``: ``(file, why)`` of the inputs that could not be read, listed in JSON.
    """
    if output == "json":
        return to_json({**result.to_dict(), "unreadable": _unreadable_json(unreadable)})
    headers = ["file", "episode", "status", "steps", "where", "detail"]
    rows = []
    for e in result.episodes:
        if e.status == "identical":
            continue
        d = e.divergence
        where = "-" if d is None else ("reset" if d.step is None else f"step {d.step}")
        detail = d.describe() if d is not None else (e.reason or "")
        rows.append([e.file, e.episode, e.status, e.steps, where, detail])
    summary = (
        f"{result.count('identical')} identical, {result.count('diverged')} diverged, "
        f"{result.count('not_replayable')} not replayable"
    )
    versions = [
        [file, lib, recorded, current]
        for file, diffs in result.version_differences.items()
        for lib, (recorded, current) in diffs.items()
    ]
    version_headers = ["file", "library", "recorded", "current"]
    if output == "markdown":
        parts = [f"### episode-audit replay\n\n{summary}\n"]
        if rows:
            parts.append(markdown_table(headers, rows) + "\n")
        if versions and result.count("diverged"):
            parts.append("Library versions differ from the recording:\n\n")
            parts.append(markdown_table(version_headers, versions) + "\n")
        return "\n".join(parts)
    out: list[RenderableType] = []
    if rows:
        out.append(table("Episodes that did not replay identically", headers, rows))
    if versions and result.count("diverged"):
        out.append(table("Library versions differ from the recording", version_headers, versions))
    out.append(Text(summary))
    return Group(*out)


# ----------------------------------------------------------------------------- report


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "-"


def _mean_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "-"
    return f"{fmt_number(mean)} ± {fmt_number(std or 0.0)}"


def _ci(ci: Interval | None) -> str:
    return "" if ci is None else f" [{ci.low:.2f}, {ci.high:.2f}]"


def _group_row(g: GroupReport) -> list[str]:
    return [
        g.key,
        str(g.episodes),
        f"{g.success} ({_rate(g.success_rate)}{_ci(g.success_ci)})",
        f"{sum(g.failures.values())} ({_rate(g.failure_rate)}{_ci(g.failure_ci)})",
        _counts(g.failures),
        f"{sum(g.truncations.values())} ({_rate(g.truncation_rate)}{_ci(g.truncation_ci)})",
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
    result: Report, output: OutputFormat, *, unreadable: Sequence[tuple[str, str]] = ()
) -> Output:
    """The success / failure / truncation table, term breakdown, warnings and gates.

    ``unreadable``: ``(file, why)`` of the inputs that could not be read, listed in JSON.
    """
    if output == "json":
        return to_json({**result.to_dict(), "unreadable": _unreadable_json(unreadable)})
    rows = [_group_row(g) for g in result.groups]
    term_rows = [
        [g.key, outcome, term, fmt_number(value)]
        for g in result.groups
        for outcome, terms in sorted(g.term_means.items())
        for term, value in sorted(terms.items())
    ]
    term_headers = ["group", "outcome", "term", "mean total per episode"]
    warnings = [[w.group, w.code, w.message] for g in result.groups for w in g.warnings]
    warning_headers = ["group", "warning", "why"]
    gates = [[r.gate, r.group, "pass" if r.passed else "FAIL", r.message] for r in result.gates]
    gate_headers = ["gate", "group", "result", "detail"]
    unfinished = [[name, why] for name, why in result.unfinished]
    unfinished_title = "Unfinished files (still being written, or torn): counts so far"
    unfinished_headers = ["file", "why"]
    if output == "markdown":
        parts = [
            f"### episode-audit report (by {result.by}{_unit(result)})\n",
            markdown_table(REPORT_HEADERS, rows) + "\n",
        ]
        if term_rows:
            parts += [
                "#### Reward terms by outcome\n",
                markdown_table(term_headers, term_rows) + "\n",
            ]
        if warnings:
            parts += ["#### Incentive warnings\n", markdown_table(warning_headers, warnings) + "\n"]
        if gates:
            parts += ["#### Gates\n", markdown_table(gate_headers, gates) + "\n"]
        if unfinished:
            parts += [
                f"#### {unfinished_title}\n",
                markdown_table(unfinished_headers, unfinished) + "\n",
            ]
        return "\n".join(parts)
    out: list[RenderableType] = [
        table(f"Outcomes (by {result.by}{_unit(result)})", REPORT_HEADERS, rows)
    ]
    if term_rows:
        out.append(table("Reward terms by outcome", term_headers, term_rows))
    if warnings:
        out.append(table("Incentive warnings", warning_headers, warnings))
    if gates:
        out.append(table("Gates", gate_headers, gates))
    if unfinished:
        out.append(table(unfinished_title, unfinished_headers, unfinished))
    return Group(*out)


def _unit(result: Report) -> str:
    """``", games"`` when a report counts PettingZoo games instead of episodes."""
    return ", games" if result.unit == "game" else ""
