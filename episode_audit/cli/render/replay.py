"""Render a replay result: the episodes that did not replay identically."""

from __future__ import annotations

from rich.console import Group, RenderableType
from rich.text import Text

from ...format.records import listing
from ...replay import EpisodeReplay, ReplayResult
from .common import (
    Output,
    OutputFormat,
    markdown_table,
    markdown_text,
    safe,
    table,
    to_json,
    unreadable_json,
    versioned,
)
from .junit import JUnitCase, junit_xml

__all__ = ["REPLAY_SUITE", "replay_cases", "replay_output", "unverified"]

REPLAY_SUITE = "episode-audit replay"
"""The JUnit suite of what is about the whole replay, not one file."""


def replay_output(
    result: ReplayResult, output: OutputFormat, *, allow_unverified: bool = False
) -> Output:
    """Replay results: one row per episode that was not identical, plus a summary.

    JSON also lists the inputs that could not be read (``result.unreadable``); JUnit has the
    cases of :func:`replay_cases`.
    """
    if output == "json":
        data = {**result.to_dict(), "unreadable": unreadable_json(result.unreadable)}
        return to_json(versioned("replay", data))
    if output == "junit":
        cases = replay_cases(result, allow_unverified=allow_unverified)
        return junit_xml(cases, name="episode-audit replay")
    headers = ["file", "episode", "status", "steps", "where", "detail"]
    rows = _rows(result.episodes)
    summary = (
        f"{result.count('identical')} identical, {result.count('diverged')} diverged, "
        f"{result.count('not_replayable')} not replayable: {result.verified} episode(s) verified"
        + (f" (+{result.unstarted} unstarted)" if result.unstarted else "")
    )
    versions = [
        [file, lib, recorded, current]
        for file, diffs in result.version_differences.items()
        for lib, (recorded, current) in diffs.items()
    ]
    version_headers = ["file", "library", "recorded", "current"]
    differed = any(e.divergence is not None for e in result.episodes)
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
        if versions and differed:
            parts.append("Library versions differ from the recording:\n\n")
            parts.append(markdown_table(version_headers, versions) + "\n")
        parts.extend(f"{markdown_text(line)}\n" for line in live)
        return "\n".join(parts)
    out: list[RenderableType] = []
    if rows:
        out.append(table("Episodes that did not replay identically", headers, rows))
    if notes:
        out.append(table("Replayed without recorded wrappers", ["file", "note"], notes))
    if versions and differed:
        out.append(table("Library versions differ from the recording", version_headers, versions))
    out.extend(Text(safe(line)) for line in live)
    out.append(Text(summary))
    return Group(*out)


def _rows(episodes: list[EpisodeReplay]) -> list[list[object]]:
    """A row per episode that did not replay identically; not replayable ones, a row per reason.

    The not replayable episodes of a file that share a reason (an env that cannot be built:
    all of them) are one row, at the first one's place, listing them
    (:func:`~episode_audit.format.records.listing`) with their steps summed.
    """
    rows: list[list[object]] = []
    shared: dict[tuple[str, str], list[EpisodeReplay]] = {}  # (file, reason): its episodes
    for e in episodes:
        if e.status == "identical":
            continue
        d = e.divergence
        where = "-" if d is None else ("reset" if d.step is None else f"step {d.step}")
        detail = (e.reason or "") if d is None or e.status == "not_replayable" else d.describe()
        if e.restored:
            detail += f" (restored: {e.restored})"
        if e.status == "not_replayable" and d is None:
            group = shared.setdefault((e.file, detail), [])
            group.append(e)
            if len(group) > 1:
                continue  # (its row, the first's, is filled in below)
        rows.append([e.file, e.episode, e.status, e.steps, where, detail])
    for row in rows:
        group = shared.get((str(row[0]), str(row[5])), [])
        if row[2] == "not_replayable" and len(group) > 1:
            row[1] = listing([g.episode for g in group])
            row[3] = sum(g.steps for g in group)
    return rows


def unverified(result: ReplayResult) -> str:
    """Why a replay that compared no episode fails."""
    not_replayable = result.count("not_replayable")
    what = (
        f"all {not_replayable} episode(s) are not replayable (the output says why)"
        if not_replayable
        else "the file(s) hold no episode"
        + (
            f" but {result.unstarted} unstarted (reset and never stepped)"
            if result.unstarted
            else ""
        )
    )
    return f"replay verified no episode: {what}; pass --allow-unverified when that is expected"


def _episode_case(e: EpisodeReplay, context: str) -> JUnitCase:
    name = f"episode {e.episode}"
    if e.status == "identical":
        return JUnitCase(e.file, name, "passed")
    if e.status == "not_replayable":
        reason = e.reason or "not replayable"
        return JUnitCase(
            e.file, name, "skipped", reason, "\n".join(filter(None, [reason, context]))
        )
    message = e.divergence.describe() if e.divergence is not None else (e.reason or "diverged")
    restored = f"restored before its reset: {e.restored}" if e.restored else ""
    return JUnitCase(
        e.file, name, "failed", message, "\n".join(filter(None, [message, restored, context]))
    )


def _file_context(result: ReplayResult) -> dict[str, str]:
    """By file: its notes, live recorder and differing library versions, as lines."""
    lines: dict[str, list[str]] = {}
    for file, said in result.notes.items():
        lines.setdefault(file, []).extend(f"note: {note}" for note in said)
    for file, why in result.live:
        lines.setdefault(file, []).append(f"live: {why}")
    for file, diffs in result.version_differences.items():
        lines.setdefault(file, []).extend(
            f"{lib}: recorded {recorded}, here {current}"
            for lib, (recorded, current) in diffs.items()
        )
    return {file: "\n".join(said) for file, said in lines.items()}


def replay_cases(result: ReplayResult, *, allow_unverified: bool = False) -> list[JUnitCase]:
    """A suite per file, a case per episode: passed, failed (diverged) or skipped.

    A diverged episode's message is its first difference; a not replayable one's, why. An
    input that could not be read is an error case; so is each ``--episode`` no file has; a
    replay that verified no episode (unless ``allow_unverified``) fails the case ``verified``
    of the suite :data:`REPLAY_SUITE`: the document fails when the command does.
    """
    context = _file_context(result)
    cases = [_episode_case(e, context.get(e.file, "")) for e in result.episodes]
    cases += [JUnitCase(u.file, "read", "error", u.why) for u in result.unreadable]
    cases += [
        JUnitCase(REPLAY_SUITE, f"episode {n}", "error", f"no episode {n} in the file(s) given")
        for n in result.missing
    ]
    if not result.verified and not allow_unverified:
        why = unverified(result)
        cases.append(JUnitCase(REPLAY_SUITE, "verified", "failed", why))
    return cases
