"""GitHub Actions job summaries: a command's Markdown appended to ``$GITHUB_STEP_SUMMARY``.

GitHub sets the variable in every step of a job; ``check``, ``replay`` and ``report`` then
append their Markdown output to the file it names, whatever ``--format`` prints on stdout,
unless ``--no-step-summary``. GitHub refuses a step summary over 1 MiB whole, so the Markdown
is cut, at a line, to the room the file has left, and says so (:func:`fit_summary`).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Annotated

import typer

from ._app import warn

__all__ = [
    "STEP_SUMMARY_ENV",
    "STEP_SUMMARY_LIMIT",
    "NoStepSummaryOption",
    "append_step_summary",
    "fit_summary",
]

STEP_SUMMARY_ENV = "GITHUB_STEP_SUMMARY"
STEP_SUMMARY_LIMIT = 1024 * 1024
"""Bytes GitHub shows of one step's summary (a larger one is not shown at all)."""

NoStepSummaryOption = Annotated[
    bool,
    typer.Option(
        "--no-step-summary",
        help=f"Do not append the Markdown summary to ${STEP_SUMMARY_ENV} "
        "(done when it is set, as in GitHub Actions).",
    ),
]
"""``--no-step-summary`` of ``check``, ``replay`` and ``report``: :func:`append_step_summary`."""


def fit_summary(markdown: str, room: int) -> str | None:
    r"""``markdown`` cut to ``room`` bytes (UTF-8), at a line, saying how many lines were cut.

    ``None`` when not even that note fits.

    >>> fit_summary("a\nb\n", 100)
    'a\nb\n'
    >>> fit_summary("### t\n" + "| x |\n" * 50, 80)
    '### t\n| x |\n\n_(cut here: 49 more line(s) did not fit in the step summary)_\n'
    """
    if len(markdown.encode()) <= room:
        return markdown
    lines = markdown.splitlines(keepends=True)

    def note(cut: int) -> str:
        return f"\n_(cut here: {cut} more line(s) did not fit in the step summary)_\n"

    kept, size = 0, 0
    while size + len(lines[kept].encode()) + len(note(len(lines) - kept - 1).encode()) <= room:
        size += len(lines[kept].encode())
        kept += 1
    end = note(len(lines) - kept)
    return None if size + len(end.encode()) > room else "".join(lines[:kept]) + end


def append_step_summary(markdown: Callable[[], str], *, off: bool = False) -> None:
    """Append ``markdown()`` to ``$GITHUB_STEP_SUMMARY`` when it is set and not ``off``.

    Nothing when stdout already goes to that file (``>> $GITHUB_STEP_SUMMARY``). A file that
    cannot be written is a warning on stderr: the command's output and exit code stand.
    """
    path = os.environ.get(STEP_SUMMARY_ENV)
    if off or not path or _is_stdout(path):
        return
    try:
        used = os.path.getsize(path) if os.path.exists(path) else 0
        separator = "\n" if used else ""
        text = fit_summary(markdown(), STEP_SUMMARY_LIMIT - used - len(separator))
        if text is None:
            warn(f"${STEP_SUMMARY_ENV} {path}: full ({used} bytes); no summary appended")
            return
        with open(path, "a", encoding="utf-8") as out:
            out.write(separator + text)
    except OSError as exc:
        warn(f"${STEP_SUMMARY_ENV} {path}: cannot append the summary ({exc.strerror or exc})")


def _is_stdout(path: str) -> bool:
    """Whether stdout is the file ``path`` (so the summary is already being written)."""
    try:
        return os.path.samestat(os.fstat(sys.stdout.fileno()), os.stat(path))
    except (OSError, ValueError, AttributeError):  # (no such file; stdout not a real file)
        return False
