"""Recorder notes: the ``recorder_note:<code>`` findings.

:func:`recorder_notes` turns a column of notes into per-episode hits (a ``step_after_end`` note
is handed back to the ending rules); :func:`note_finding` and :func:`notes_summary` word them,
the latter for one note repeated in many episodes. :func:`reset_notes` leaves out the notes
that are for readers without a column the file has, and those on replaying an episode that
never ran.
"""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.records import listing, note_items
from ._state import BoolArray, FileState, Hit, IntArray, first_per_episode, short, steps_of
from .registry import RECORDER_NOTE, SEVERITY, STEP_AFTER_END, Severity

__all__ = ["is_note", "note_finding", "notes_summary", "recorder_notes", "reset_notes"]

_PREFIX = RECORDER_NOTE + ":"
_ERROR_NOTES = frozenset({f"{RECORDER_NOTE}:env_raised"})
"""Recorder notes that say what an ``error`` outcome says elsewhere: the env raised."""
_OPTIONS_NOTE = "options_unserializable"
_REPLAY_NOTES = ("seed_out_of_range", "rng_state_unavailable", _OPTIONS_NOTE, "state_unavailable")
"""Reset notes on what replaying the episode needs (its seed, RNG state, options, state)."""


def is_note(code: str) -> bool:
    """Whether ``code`` is a recorder note's (``recorder_note:<code>``)."""
    return code.startswith(_PREFIX)


def _severity(code: str) -> Severity:
    """A recorder note's severity: the family's, unless it says the environment raised."""
    return "error" if code in _ERROR_NOTES else SEVERITY[RECORDER_NOTE]


def recorder_notes(
    state: FileState, notes: pa.Array, episode: IntArray, step: IntArray | None
) -> BoolArray | None:
    """Turn recorder notes into per-episode hits; return the rows noted ``step_after_end``.

    ``step`` is ``None`` for the notes of resets.
    """
    n = len(notes)
    if notes.null_count == n:
        return None
    encoded = pc.dictionary_encode(notes)
    size = len(encoded.dictionary)
    indices = encoded.indices.fill_null(size).to_numpy(zero_copy_only=False)
    by_code: dict[str, list[tuple[int, str]]] = {}
    for slot, text in enumerate(encoded.dictionary.to_pylist()):
        for note in _parse_notes(text):
            code, _, message = note.partition(":")
            by_code.setdefault(code.strip(), []).append((slot, message.strip()))
    after_end: BoolArray | None = None
    for code, slots in by_code.items():
        in_slot = np.zeros(size + 1, dtype=np.bool_)
        message_of: dict[int, str] = {}
        for slot, message in slots:
            in_slot[slot] = True
            message_of.setdefault(slot, message)
        mask = in_slot[indices]
        if code == STEP_AFTER_END and step is not None:
            after_end = mask
            continue
        eps, first, counts, _ = first_per_episode(episode, mask)
        details = [message_of[int(indices[row])] for row in first.tolist()]
        state.hits.add(f"{_PREFIX}{code}", eps, steps_of(step, first), counts, details=details)
    return after_end


def reset_notes(resets: pa.RecordBatch, unstarted: frozenset[int] = frozenset()) -> pa.Array:
    """The ``notes`` of reset rows, without the notes that say nothing wrong.

    Left out: ``options_unserializable`` where the options are held (the recorder notes
    options plain JSON does not hold exactly for readers without the ``options_typed``
    column; a row that has its options there holds them exactly, and replay resets with
    them), and the notes on what a replay needs (:data:`_REPLAY_NOTES`: no seed nor RNG state,
    no state snapshot) at the resets of the ``unstarted`` episodes, reset and never stepped:
    there is nothing of them to replay.
    """
    notes = resets.column(fmt.COL_NOTES)
    typed = (
        resets.column(fmt.COL_OPTIONS_TYPED)
        if fmt.COL_OPTIONS_TYPED in resets.schema.names
        else None
    )
    held = (
        np.zeros(len(notes), dtype=np.bool_)
        if typed is None or typed.null_count == len(typed)
        else np.asarray(typed.is_valid(), dtype=np.bool_)
    )
    moot = np.zeros(len(notes), dtype=np.bool_)
    if unstarted:
        episodes = resets.column(fmt.COL_EPISODE).to_numpy(zero_copy_only=False)
        moot = np.isin(episodes, np.fromiter(unstarted, dtype=np.int64))
    if not (held.any() or moot.any()):
        return notes
    values = notes.to_pylist()
    for row in np.flatnonzero(held | moot).tolist():
        items = note_items(values[row]) if values[row] else None
        if items is None:
            continue  # (none, or garbled: said as it is)
        left_out = (_OPTIONS_NOTE,) * bool(held[row]) + _REPLAY_NOTES * bool(moot[row])
        kept = [item for item in items if item.partition(":")[0].strip() not in left_out]
        values[row] = json.dumps(kept) if kept else None
    return pa.array(values, pa.string())


def note_finding(state: FileState, code: str, episode: int, hit: Hit, where: str) -> None:
    """The finding of one recorder note in one episode."""
    noted = code.partition(":")[2]
    message = f"recorder noted {noted} {where} ({hit.count} time(s) in the episode): {hit.detail}"
    state.finding(code, message, episode, hit.step, severity=_severity(code))


def notes_summary(state: FileState, code: str, group: list[tuple[int, Hit]]) -> None:
    """The one finding of a recorder note repeated in the episodes of ``group``."""
    episodes = sorted(e for e, _ in group)
    first_episode, first = min(group, key=lambda item: item[0])
    where = "at reset" if first.step is None else "on steps"
    message = (
        f"recorder noted {code.partition(':')[2]} {where} in {len(episodes)} episodes "
        f"(episodes {listing(episodes)}; {sum(h.count for _, h in group)} time(s) in all): "
        f"{first.detail}"
    )
    state.finding(code, message, first_episode, first.step, severity=_severity(code))


def _parse_notes(text: str) -> list[str]:
    notes = note_items(text)
    return [f"notes_unreadable: {short(text)}"] if notes is None else notes
