"""The rules over the file's episode records, one column-wise check per finding code.

:func:`check_episode_records` reports ``terminated_and_truncated``, ``unlabeled_failure``,
``incomplete_episode``, ``error_episode``, ``length_mismatch`` and ``not_replayable``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.records import listing
from ._state import BoolArray, FileState, IntArray
from .endings import EndingChecks
from .registry import (
    ERROR_EPISODE,
    INCOMPLETE_EPISODE,
    LENGTH_MISMATCH,
    NOT_REPLAYABLE,
    TERMINATED_AND_TRUNCATED,
    UNLABELED_FAILURE,
)

__all__ = ["check_episode_records"]

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
]


class _Records:
    """The episode records of one file, and one finding over the episodes a mask selects."""

    def __init__(self, state: FileState, rows: pa.Table) -> None:
        self.state = state
        self.rows = rows
        self.episode: IntArray = rows.column("episode").to_numpy()
        self.outcome = rows.column("outcome")

    def listed(self, mask: Any) -> list[int]:
        """The episodes of the records ``mask`` selects, in order."""
        chosen: list[int] = self.episode[np.asarray(mask, dtype=np.bool_)].tolist()
        return chosen

    def finding_over(self, code: str, mask: Any, says: Callable[[list[int]], str]) -> None:
        """One finding for the episodes ``mask`` selects, if any, at the first of them."""
        episodes = self.listed(mask)
        if episodes:
            self.state.finding(code, says(episodes), episodes[0])


def check_episode_records(state: FileState, endings: EndingChecks) -> None:
    """Check the file's episode records (``endings`` counted their step rows)."""
    table = state.ev.episodes()
    state.episodes = table.num_rows
    if table.num_rows == 0:
        return
    records = _Records(state, table.select(_COLUMNS))
    _both_flags(records)
    _unlabeled_failures(records)
    ended = records.rows.column("ended").to_numpy(zero_copy_only=False)
    _incomplete(records, ended)
    _errors(records)
    _lengths(records, endings, ended)
    _seedless(records)


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
    is_failure = pc.equal(records.outcome, fmt.OUTCOME_FAILURE)
    label = records.rows.column("failure_label")
    unlabeled = pc.fill_null(pc.and_(is_failure, pc.equal(label, fmt.UNLABELED)), False)

    def says(eps: list[int]) -> str:
        failures = int(pc.sum(is_failure).as_py() or 0)
        return f"{len(eps)} of {failures} failure(s) have no label (episodes {listing(eps)})"

    records.finding_over(UNLABELED_FAILURE, unlabeled.to_numpy(zero_copy_only=False), says)


def _incomplete(records: _Records, ended: BoolArray) -> None:
    incomplete = pc.equal(records.outcome, fmt.OUTCOME_INCOMPLETE).to_numpy(zero_copy_only=False)

    def says(eps: list[int]) -> str:
        cut_off = incomplete & ~ended
        lost = records.state.ev.damaged_episodes  # (their end records were in damaged chunks)
        if lost:
            episodes = records.rows.column(fmt.COL_EPISODE).to_pylist()
            cut_off &= ~np.array([e in lost for e in episodes])
        cut = int(cut_off.sum())
        torn = f", {cut} of them cut off by the torn end of the file" if cut else ""
        if cut and records.state.ev.writer is not None:
            torn = f", {cut} of them still being recorded (the file is still being written)"
        return f"{len(eps)} episode(s) stopped before they ended{torn} (episodes {listing(eps)})"

    records.finding_over(INCOMPLETE_EPISODE, incomplete, says)


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
    rows = records.rows
    seedless = pc.and_(pc.is_null(rows.column("seed")), pc.is_null(rows.column("rng_state")))
    records.finding_over(
        NOT_REPLAYABLE,
        seedless.to_numpy(zero_copy_only=False),
        lambda eps: (
            f"{len(eps)} episode(s) have neither a reset seed nor an RNG state "
            f"and cannot be replayed (episodes {listing(eps)})"
        ),
    )
