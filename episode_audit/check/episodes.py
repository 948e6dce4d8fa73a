"""The rules over the file's episode records, one column-wise check per finding code.

:func:`check_episode_records` reports ``terminated_and_truncated``, ``unlabeled_failure``,
``incomplete_episode``, ``error_episode``, ``length_mismatch`` and ``not_replayable`` (no seed
and no RNG state; an unseeded reset of sub-envs whose own state the file lacks).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.records import listing
from ..format.run_end import RunEnd
from ..format.wrappers import unsaved_state
from ..record.rules import EndingRules
from ._state import BoolArray, FileState, IntArray
from .endings import EndingChecks
from .registry import (
    ERROR_EPISODE,
    INCOMPLETE_EPISODE,
    LENGTH_MISMATCH,
    NOT_REPLAYABLE,
    TERMINATED_AND_TRUNCATED,
    UNLABELED_FAILURE,
    Severity,
)

__all__ = ["check_episode_records"]

_DEFAULT_RULES = EndingRules()

_COLUMNS = [
    "episode",
    "outcome",
    "failure_label",
    "terminated",
    "truncated",
    "length",
    "seed",
    "rng_state",
    "error_type",
    "error_message",
    "error_during",
    "ended",
    "env_index",
    "agent",
    "game",
]


class _Records:
    """The episode records of one file, and one finding over the episodes a mask selects."""

    def __init__(self, state: FileState, rows: pa.Table) -> None:
        self.state = state
        self.rows = rows
        self.episode: IntArray = rows.column("episode").to_numpy()
        self.outcome = rows.column("outcome")
        self.unstarted = state.unstarted  # (rows: the episodes table's, in its order)

    def listed(self, mask: Any) -> list[int]:
        """The episodes of the records ``mask`` selects, in order."""
        chosen: list[int] = self.episode[np.asarray(mask, dtype=np.bool_)].tolist()
        return chosen

    def finding_over(
        self,
        code: str,
        mask: Any,
        says: Callable[[list[int]], str],
        *,
        severity: Severity | None = None,
    ) -> None:
        """One finding for the episodes ``mask`` selects, if any, at the first of them."""
        episodes = self.listed(mask)
        if episodes:
            self.state.finding(code, says(episodes), episodes[0], severity=severity)


def check_episode_records(state: FileState, endings: EndingChecks) -> None:
    """Check the file's episode records (``endings`` counted their step rows)."""
    table = state.ev.episodes()
    if table.num_rows == 0:
        return
    records = _Records(state, table.select(_COLUMNS))
    state.episodes = table.num_rows - int(records.unstarted.sum())  # (as report counts them)
    _both_flags(records)
    _unlabeled_failures(records)
    ended = records.rows.column("ended").to_numpy(zero_copy_only=False)
    _incomplete(records, ended)
    _errors(records)
    _lengths(records, endings, ended)
    _seedless(records)
    _unsaved(records)


def _both_flags(records: _Records) -> None:
    rows = records.rows
    both = pc.fill_null(pc.and_(rows.column("terminated"), rows.column("truncated")), False)
    records.finding_over(
        TERMINATED_AND_TRUNCATED,
        both.to_numpy(zero_copy_only=False),
        lambda eps: (
            f"{len(eps)} episode(s) ended with both terminated and truncated set; "
            f"the task ending counts (episodes {listing(eps)})"
        ),
    )


def _unlabeled_failures(records: _Records) -> None:
    """``unlabeled_failure``: a warning, or a note when the env labels no failure at all.

    A failure without a label is worth a warning where labels are expected: the recording
    declared where they come from (a ``failure_fn`` or another ``failure_key``), or another
    failure of the file has one. Otherwise the env gives none (CartPole, Hopper): a note.
    """
    is_failure = pc.equal(records.outcome, fmt.OUTCOME_FAILURE)
    label = records.rows.column("failure_label")
    unlabeled = pc.fill_null(pc.and_(is_failure, pc.equal(label, fmt.UNLABELED)), False)
    mask = unlabeled.to_numpy(zero_copy_only=False)
    if not mask.any():
        return
    failures = int(pc.sum(is_failure).as_py() or 0)
    rules = records.state.ev.run.ending_rules or {}
    key = rules.get("failure_key") or _DEFAULT_RULES.failure_key
    declared = bool(rules.get("failure_fn")) or key != _DEFAULT_RULES.failure_key
    severity: Severity = "warning" if declared or int(mask.sum()) < failures else "note"

    def says(eps: list[int]) -> str:
        text = f"{len(eps)} of {failures} failure(s) have no label (episodes {listing(eps)})"
        if severity == "warning":
            return text
        text += f"; the env labels no failure (no info[{key!r}] when it ends one)"
        if records.state.ev.reports_success is False:
            text += (
                " and reports no success, so every episode it ends counts as a failure; where "
                "an ending can be a success, record with ending_rules=EndingRules(success_fn=...)"
            )
        return text

    records.finding_over(UNLABELED_FAILURE, mask, says, severity=severity)


def _incomplete(records: _Records, ended: BoolArray) -> None:
    """``incomplete_episode``: a warning for the cut-off episodes, a note for those close() cut.

    Unstarted episodes (reset, never stepped) are left out: nothing of them stopped early.
    """
    incomplete = pc.equal(records.outcome, fmt.OUTCOME_INCOMPLETE).to_numpy(zero_copy_only=False)
    if not incomplete.any():
        return
    incomplete &= ~records.unstarted
    at_close = incomplete & _cut_at_close(records, ended)

    def says(eps: list[int]) -> str:
        cut_off = incomplete & ~ended
        lost = records.state.ev.damaged_episodes  # (their end records were in damaged chunks)
        if lost:
            episodes = records.rows.column(fmt.COL_EPISODE).to_pylist()
            cut_off &= ~np.array([e in lost for e in episodes])
        cut = int(cut_off.sum())
        return (
            f"{len(eps)} episode(s) stopped before they ended{_cut_off_why(records, cut)} "
            f"(episodes {listing(eps)})"
        )

    def closed(eps: list[int]) -> str:
        return (
            f"{len(eps)} episode(s) were running when the recorder was closed, at the end of "
            f"the recording: their outcome is unknown and report counts them apart "
            f"(episodes {listing(eps)})"
        )

    records.finding_over(INCOMPLETE_EPISODE, incomplete & ~at_close, says)
    records.finding_over(INCOMPLETE_EPISODE, at_close, closed, severity="note")


def _cut_off_why(records: _Records, cut: int) -> str:
    """What ended the recording of ``cut`` episodes without an end record, as a clause.

    A finished file whose run-end record counts dropped episode records lost their ends
    with them (a full disk); an unfinished file, at its torn end or by a live recorder. A
    finished file is never said to be torn.
    """
    if not cut:
        return ""
    ev = records.state.ev
    if ev.writer is not None:
        return f", {cut} of them still being recorded (the file is still being written)"
    if not ev.finished:
        return f", {cut} of them cut off by the torn end of the file"
    if RunEnd.of(ev.run_end).lost_episode_records:
        return (
            f", {cut} of them without an end record: their end was among what the recorder "
            "dropped (recorder_trouble), so how they ended is unknown"
        )
    return f", {cut} of them without an end record"


def _cut_at_close(records: _Records, ended: BoolArray) -> BoolArray:
    """The episodes whose end record ``close()`` wrote: the last of each stream.

    A stream's episode that is not its last was ended by the next one's reset; its last one,
    when it has an end record and did not end by itself, by the recorder's ``close()`` (in a
    file with games, only in the file's last game: a new game ends every open episode). A
    file that lost episodes to damage is not read so: a lost later episode would not show.
    """
    rows = records.rows
    if records.state.ev.damaged_episodes:
        return np.zeros(rows.num_rows, dtype=np.bool_)
    streams = rows.select([fmt.COL_ENV_INDEX, fmt.COL_AGENT, fmt.COL_EPISODE])
    tops = streams.group_by([fmt.COL_ENV_INDEX, fmt.COL_AGENT]).aggregate(
        [(fmt.COL_EPISODE, "max")]
    )
    last: BoolArray = np.isin(records.episode, tops.column(f"{fmt.COL_EPISODE}_max").to_numpy())
    games = rows.column(fmt.COL_GAME)
    if games.null_count < len(games):
        top = pc.max(games).as_py()
        last &= pc.fill_null(pc.equal(games, top), False).to_numpy(zero_copy_only=False)
    return last & ended


def _errors(records: _Records) -> None:
    state = records.state
    errors = pc.equal(records.outcome, fmt.OUTCOME_ERROR).to_numpy(zero_copy_only=False)
    if not errors.any():
        return
    for record in records.rows.filter(pa.array(errors)).to_pylist():
        during = record["error_during"] or "step"
        where = "during reset" if during == "reset" else f"while taking step {record['length']}"
        state.finding(
            ERROR_EPISODE,
            f"the environment raised {record['error_type'] or 'an exception'} "
            f"{where}: {record['error_message'] or ''}",
            int(record["episode"]),
            None if during == "reset" else int(record["length"]),
        )


def _lengths(records: _Records, endings: EndingChecks, ended: BoolArray) -> None:
    state = records.state
    episode = records.episode
    length: IntArray = records.rows.column("length").to_numpy()
    counted = endings.rows_counted(episode)
    wrong = ended & (counted != length)
    for e, n, c in zip(
        episode[wrong].tolist(), length[wrong].tolist(), counted[wrong].tolist(), strict=True
    ):
        state.finding(
            LENGTH_MISMATCH,
            f"the episode record says {n} steps, the file holds {c} step rows up to its outcome",
            e,
        )


def _seedless(records: _Records) -> None:
    """The episodes with neither a seed nor an RNG state (unstarted ones left out: no replay)."""
    rows = records.rows
    seedless = pc.and_(pc.is_null(rows.column("seed")), pc.is_null(rows.column("rng_state")))
    records.finding_over(
        NOT_REPLAYABLE,
        seedless.to_numpy(zero_copy_only=False) & ~records.unstarted,
        lambda eps: (
            f"{len(eps)} episode(s) have neither a reset seed nor an RNG state "
            f"and cannot be replayed (episodes {listing(eps)})"
        ),
    )


def _unsaved(records: _Records) -> None:
    """The episodes an unseeded reset began, of sub-envs whose own state the file lacks.

    (Those with neither a seed nor an RNG state are :func:`_seedless`'s.) A seeded reset sets
    that state anew; when every episode needs it, it is a cause of ``check_state_causes``.
    Unstarted episodes are left out: there is nothing of them to replay.
    """
    unsaved = unsaved_state(records.state.ev.run.layout)
    if unsaved is None or unsaved[1]:
        return
    rows = records.rows
    unseeded = pc.and_(pc.is_null(rows.column("seed")), pc.is_valid(rows.column("rng_state")))
    records.finding_over(
        NOT_REPLAYABLE,
        unseeded.to_numpy(zero_copy_only=False) & ~records.unstarted,
        lambda eps: (
            f"{len(eps)} episode(s) began with an unseeded reset and cannot be replayed "
            f"(episodes {listing(eps)}): {unsaved[0]}"
        ),
    )
