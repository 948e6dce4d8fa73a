"""Render a check result: findings as a table, Markdown or JSON."""

from __future__ import annotations

from rich.console import Group, RenderableType
from rich.text import Text

from ...check import CheckResult
from .common import (
    Output,
    OutputFormat,
    markdown_table,
    table,
    to_json,
    unreadable_json,
)

__all__ = ["check_output"]


def check_output(result: CheckResult, output: OutputFormat) -> Output:
    """Findings of ``check`` in the requested format.

    JSON also lists the inputs that could not be read (``result.unreadable``).
    """
    if output == "json":
        return to_json({**result.to_dict(), "unreadable": unreadable_json(result.unreadable)})
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
