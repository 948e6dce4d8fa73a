"""Render a replay result: the episodes that did not replay identically."""

from __future__ import annotations

from rich.console import Group, RenderableType
from rich.text import Text

from ...replay import ReplayResult
from .common import (
    Output,
    OutputFormat,
    markdown_table,
    markdown_text,
    safe,
    table,
    to_json,
    unreadable_json,
)

__all__ = ["replay_output"]


def replay_output(result: ReplayResult, output: OutputFormat) -> Output:
    """Replay results: one row per episode that was not identical, plus a summary.

    JSON also lists the inputs that could not be read (``result.unreadable``).
    """
    if output == "json":
        return to_json({**result.to_dict(), "unreadable": unreadable_json(result.unreadable)})
    headers = ["file", "episode", "status", "steps", "where", "detail"]
    rows = []
    for e in result.episodes:
        if e.status == "identical":
            continue
        d = e.divergence
        where = "-" if d is None else ("reset" if d.step is None else f"step {d.step}")
        detail = d.describe() if d is not None else (e.reason or "")
        if e.restored:
            detail += f" (restored: {e.restored})"
        rows.append([e.file, e.episode, e.status, e.steps, where, detail])
    summary = (
        f"{result.count('identical')} identical, {result.count('diverged')} diverged, "
        f"{result.count('not_replayable')} not replayable: {result.verified} episode(s) verified"
    )
    versions = [
        [file, lib, recorded, current]
        for file, diffs in result.version_differences.items()
        for lib, (recorded, current) in diffs.items()
    ]
    version_headers = ["file", "library", "recorded", "current"]
    notes = [[file, note] for file, said in result.notes.items() for note in said]
    live = [
        f"{file}: {why}; replay it again once its recorder has closed it"
        for file, why in result.live
    ]
    if output == "markdown":
        parts = [f"### episode-audit replay\n\n{summary}\n"]
        if rows:
            parts.append(markdown_table(headers, rows) + "\n")
        if notes:
            parts.append(markdown_table(["file", "note"], notes) + "\n")
        if versions and result.count("diverged"):
            parts.append("Library versions differ from the recording:\n\n")
            parts.append(markdown_table(version_headers, versions) + "\n")
        parts.extend(f"{markdown_text(line)}\n" for line in live)
        return "\n".join(parts)
    out: list[RenderableType] = []
    if rows:
        out.append(table("Episodes that did not replay identically", headers, rows))
    if notes:
        out.append(table("Replayed without recorded wrappers", ["file", "note"], notes))
    if versions and result.count("diverged"):
        out.append(table("Library versions differ from the recording", version_headers, versions))
    out.extend(Text(safe(line)) for line in live)
    out.append(Text(summary))
    return Group(*out)
