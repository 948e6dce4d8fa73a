"""Render a check result: findings as a table, Markdown or JSON."""

from __future__ import annotations

from collections.abc import Collection

from rich.console import Group, RenderableType
from rich.text import Text

from ...check import FINDING_CODES, CheckResult, Finding, kind_of
from ...check.registry import FILE_UNREADABLE
from .common import (
    Output,
    OutputFormat,
    markdown_table,
    table,
    to_json,
    unreadable_json,
    versioned,
)
from .junit import JUnitCase, junit_xml

__all__ = ["check_cases", "check_output"]


def check_output(
    result: CheckResult,
    output: OutputFormat,
    *,
    strict: bool = False,
    ignored: Collection[str] = (),
) -> Output:
    """Findings of ``check`` in the requested format.

    JSON also lists the inputs that could not be read (``result.unreadable``); JUnit has the
    cases of :func:`check_cases` (``strict`` and ``ignored`` as the command's options).
    """
    if output == "json":
        data = {**result.to_dict(), "unreadable": unreadable_json(result.unreadable)}
        return to_json(versioned("check", data))
    if output == "junit":
        cases = check_cases(result, strict=strict, ignored=ignored)
        return junit_xml(cases, name="episode-audit check")
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
