"""Recorder notes: what the recorder says about a value it recorded as well as it could.

A note is the text ``"code: message"`` (:func:`note`; the codes are listed in ``docs/format.md``,
"Step blocks"). A row's notes go to its ``notes`` column; a row with notes counts once in its
episode record's ``notes`` (:func:`add_notes`). See ``docs/recording.md``, "Notes".
"""

from __future__ import annotations

from typing import Any, Protocol

from ..format.spaces import ColumnBuffer

__all__ = ["add_notes", "append_noted", "has_note", "note", "short"]

_NOTE_LIMIT = 300


def short(value: Any) -> str:
    """``repr(value)``, cut to 80 characters (for notes and messages); never raises."""
    try:
        shown = repr(value)
    except Exception as exc:
        shown = f"<{type(value).__name__}: repr() raised {type(exc).__name__}>"
    return shown if len(shown) <= 80 else shown[:77] + "..."


def note(code: str, message: str) -> str:
    """A recorder note ``"code: message"`` (see ``docs/format.md`` for the codes)."""
    return f"{code}: {message}"[:_NOTE_LIMIT]


def has_note(notes: list[str], code: str) -> bool:
    """Whether ``notes`` already has a note ``code`` (a caller may know the better reason)."""
    prefix = f"{code}:"
    return any(item.startswith(prefix) for item in notes)


class _Noted(Protocol):
    """An episode being recorded, as far as notes go: how many of its rows have notes."""

    notes: int


def add_notes(
    episode: _Noted | None, by_row: dict[int, list[str]], row: int, texts: list[str]
) -> None:
    """Add notes to ``row`` of ``by_row`` (a block's step or reset notes).

    A row with notes counts once in its episode's ``notes`` (``None``: a row of no episode),
    however many notes it gets and whenever: while stepping, or when its block is written
    (before the records of the episodes that ended, in the same flush).
    """
    row_notes = by_row.get(row)
    if row_notes is None:
        by_row[row] = texts
        if episode is not None:
            episode.notes += 1
    else:
        row_notes.extend(texts)


def append_noted(
    buffer: ColumnBuffer, value: Any, what: str, notes: list[str], context: str = ""
) -> None:
    """Append ``value``; a cast or a value that does not fit (stored as null) gets a note."""
    try:
        cast = buffer.append(value)
    except (ValueError, TypeError) as exc:
        buffer.append_null()
        notes.append(note(f"{what}_invalid", f"{context}{exc}"))
        return
    if cast is not None:
        notes.append(note(f"{what}_cast", cast))
