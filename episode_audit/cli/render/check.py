"""Render a check result: findings as a table, Markdown or JSON.

In the table and Markdown, the findings of a code found in more than :data:`GROUP_FILES`
files are one group (its counts and the first few places, :class:`FindingGroup`), so a
campaign of thousands of files reads in a screen; JSON and JUnit keep every finding.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from ...check import FINDING_CODES, CheckResult, Finding, Severity, kind_of
from ...check.registry import FILE_UNREADABLE, SEVERITY_RANK
from ...format.columns import counted
from .common import (
    Output,
    OutputFormat,
    markdown_table,
    safe,
    table,
    to_json,
    unreadable_json,
    versioned,
)
from .junit import JUnitCase, junit_xml

__all__ = ["GROUP_FILES", "FindingGroup", "check_cases", "check_output", "group_findings"]

GROUP_FILES = 5
"""A code found in more files than this is shown as one group (unless ``group`` says)."""

EXAMPLES = 3
"""The places a group shows: the first finding of each of its first files."""


@dataclass(frozen=True)
class FindingGroup:
    """The findings of one code and severity over many files, shown as one entry.

    >>> found = [Finding("note", "missing_terms", "m", f"{n}.mcap", 0, 0) for n in "aabcd"]
    >>> g = FindingGroup("note", "missing_terms", tuple(found))
    >>> g.files, g.places(), g.more
    (4, ['a.mcap:0:0', 'b.mcap:0:0', 'c.mcap:0:0'], 2)
    """

    severity: Severity
    code: str
    findings: tuple[Finding, ...]

    @property
    def files(self) -> int:
        """How many files hold these findings."""
        return len({f.file for f in self.findings})

    def examples(self) -> list[Finding]:
        """The first finding of each of the first files (then the next ones), in order."""
        firsts: dict[str, int] = {}
        for i, f in enumerate(self.findings):
            firsts.setdefault(f.file, i)
        chosen = list(firsts.values())[:EXAMPLES]
        rest = [i for i in range(len(self.findings)) if i not in set(chosen)]
        chosen += rest[: EXAMPLES - len(chosen)]
        return [self.findings[i] for i in sorted(chosen)]

    def places(self) -> list[str]:
        """The examples as ``FILE:EPISODE:STEP`` (step, or both, left out where not set)."""
        return [_place(f) for f in self.examples()]

    @property
    def more(self) -> int:
        """How many findings the examples leave out."""
        return len(self.findings) - len(self.examples())

    @property
    def summary(self) -> str:
        """The code's one-line summary from the registry (plain text)."""
        try:
            return kind_of(self.code).summary.replace("`", "")
        except KeyError:  # (a code check does not know: no summary to give)
            return ""


def _place(finding: Finding) -> str:
    where = [finding.file]
    if finding.episode is not None:
        where.append(str(finding.episode))
        if finding.step is not None:
            where.append(str(finding.step))
    return ":".join(where)


def group_findings(
    findings: Sequence[Finding], group: bool | None = None
) -> tuple[list[Finding], list[FindingGroup]]:
    """Split findings into those listed one by one and groups of one code and severity.

    ``group``: ``True`` groups every code, ``False`` none, ``None`` the codes found in more
    than :data:`GROUP_FILES` files. The listed findings keep their order; the groups come most
    severe first, then most frequent first.
    """
    by_code: dict[tuple[Severity, str], list[Finding]] = {}
    for f in findings:
        by_code.setdefault((f.severity, f.code), []).append(f)
    groups = [
        FindingGroup(severity, code, tuple(found))
        for (severity, code), found in by_code.items()
        if group or (group is None and len({f.file for f in found}) > GROUP_FILES)
    ]
    groups.sort(key=lambda g: (SEVERITY_RANK[g.severity], -len(g.findings), g.code))
    grouped = {(g.severity, g.code) for g in groups}
    listed = [f for f in findings if (f.severity, f.code) not in grouped]
    return listed, groups


def check_output(
    result: CheckResult,
    output: OutputFormat,
    *,
    strict: bool = False,
    ignored: Collection[str] = (),
    group: bool | None = None,
) -> Output:
    """Findings of ``check`` in the requested format.

    JSON also lists the inputs that could not be read (``result.unreadable``); JUnit has the
    cases of :func:`check_cases` (``strict`` and ``ignored`` as the command's options). The
    table and Markdown show groups of findings as :func:`group_findings` makes them with
    ``group``; JSON and JUnit list every finding.
    """
    if output == "json":
        data = {**result.to_dict(), "unreadable": unreadable_json(result.unreadable)}
        return to_json(versioned("check", data))
    if output == "junit":
        cases = check_cases(result, strict=strict, ignored=ignored)
        return junit_xml(cases, name="episode-audit check")
    listed, groups = group_findings(result.findings, group)
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
        for f in listed
    ]
    episodes, steps = result.episodes, result.steps
    summary = (
        f"{len(result.files)} file(s), {counted(episodes, 'episode')}, "
        f"{counted(steps, 'step')}: "
        f"{result.errors} error(s), {result.warnings} warning(s), {result.notes} note(s)"
        + (f", {result.ignored} ignored" if result.ignored else "")
    )
    if output == "markdown":
        body = markdown_table(headers, rows) if rows else ""
        if groups:
            body += ("\n\n" if body else "") + _groups_markdown(groups, group)
        return f"### episode-audit check\n\n{summary}\n\n{body or '_no findings_'}\n"
    parts: list[RenderableType] = []
    if rows:
        parts.append(table("Findings", headers, rows))
    if groups:
        parts.append(_groups_table(groups, group))
    parts.append(Text(summary))
    return Group(*parts)


def _groups_title(group: bool | None) -> str:
    where = "" if group else f" in more than {GROUP_FILES} files"
    return f"Findings{where}, by code (--no-group lists each one)"


def _groups_table(groups: Sequence[FindingGroup], group: bool | None) -> Group:
    """One entry a group: its counts, the code's summary, a few places, how many more."""
    grid = Table.grid(padding=(0, 2))
    grid.add_column(no_wrap=True)
    grid.add_column(overflow="fold")
    for i, g in enumerate(groups):
        lines = [f"{safe(g.code)}: {len(g.findings)} in {g.files} file(s)"]
        lines += [g.summary] if g.summary else []
        lines += [safe(p) for p in g.places()]
        lines += [f"… and {g.more} more"] if g.more else []
        gap = "\n" if i else ""
        grid.add_row(Text(gap + g.severity), Text(gap + "\n".join(lines)))
    title = Text(_groups_title(group), style="table.title")
    return Group(title, Text(""), grid, Text(""))


def _groups_markdown(groups: Sequence[FindingGroup], group: bool | None) -> str:
    """The groups as a Markdown table under their title."""
    rows = [
        [
            g.severity,
            g.code,
            len(g.findings),
            g.files,
            ", ".join(g.places()) + (f" and {g.more} more" if g.more else ""),
        ]
        for g in groups
    ]
    headers = ["severity", "code", "findings", "files", "first at"]
    return f"{_groups_title(group)}:\n\n{markdown_table(headers, rows)}"


def _where(finding: Finding) -> str:
    """``episode 1: `` (or nothing, for a file-wide finding)."""
    return "" if finding.episode is None else f"episode {finding.episode}: "


def check_cases(
    result: CheckResult, *, strict: bool = False, ignored: Collection[str] = ()
) -> list[JUnitCase]:
    """A suite per file, a case per finding code: failed when its findings fail the command.

    Findings that do not fail it (warnings without ``strict``, notes) are the passed case's
    output; an ignored code is skipped; a file that could not be read has one case,
    ``file_unreadable``, an error.
    """
    unreadable = {u.file: u.why for u in result.unreadable}
    found: dict[tuple[str, str], list[Finding]] = {}
    for f in result.findings:
        found.setdefault((f.file, kind_of(f.code).code), []).append(f)
    cases: list[JUnitCase] = []
    for file in result.files:
        if file in unreadable:
            cases.append(JUnitCase(file, FILE_UNREADABLE, "error", unreadable[file]))
            continue
        for code in FINDING_CODES:
            if code in ignored:
                cases.append(JUnitCase(file, code, "skipped", "ignored (--ignore)"))
                continue
            findings = found.get((file, code), [])
            details = "\n".join(f"{f.severity}: {_where(f)}{f.message}" for f in findings)
            failing = [
                f for f in findings if f.severity == "error" or (strict and f.severity == "warning")
            ]
            if not failing:
                cases.append(JUnitCase(file, code, "passed", details=details))
                continue
            more = f" (and {len(failing) - 1} more)" if len(failing) > 1 else ""
            message = f"{_where(failing[0])}{failing[0].message}{more}"
            cases.append(JUnitCase(file, code, "failed", message, details))
    return cases
