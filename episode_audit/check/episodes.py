"""The rules over the file's episode records, one column-wise check per finding code.

:func:`check_episode_records` reports ``terminated_and_truncated``, ``unlabeled_failure``,
``incomplete_episode``, ``error_episode``, ``length_mismatch`` and ``not_replayable``.
"""

from __future__ import annotations

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
    """The episode records of one file, with the episodes a mask selects."""

    def __init__(self, rows: pa.Table) -> None:
        self.rows = rows
        self.episode: IntArray = rows.column("episode").to_numpy()
        self.outcome = rows.column("outcome")

    def listed(self, mask: Any) -> list[int]:
        """The episodes of the records ``mask`` selects, in order."""
        chosen: list[int] = self.episode[np.asarray(mask, dtype=np.bool_)].tolist()
        return chosen


def check_episode_records(state: FileState, endings: EndingChecks) -> None:
    """Check the file's episode records (``endings`` counted their step rows)."""
    table = state.ev.episodes()
    state.episodes = table.num_rows
    if table.num_rows == 0:
        return
    records = _Records(table.select(_COLUMNS))
    _both_flags(state, records)
    _unlabeled_failures(state, records)
    ended = records.rows.column("ended").to_numpy(zero_copy_only=False)
    _incomplete(state, records, ended)
    _errors(state, records)
    _lengths(state, records, endings, ended)
    _seedless(state, records)


def _both_flags(state: FileState, records: _Records) -> None:
    rows = records.rows
    both = pc.fill_null(pc.and_(rows.column("terminated"), rows.column("truncated")), False)
    both_eps = records.listed(both.to_numpy(zero_copy_only=False))
    if both_eps:
        state.finding(
            TERMINATED_AND_TRUNCATED,
            f"{len(both_eps)} episode(s) ended with both terminated and truncated set; "
            f"the task ending counts (episodes {listing(both_eps)})",
            both_eps[0],
        )


def _unlabeled_failures(state: FileState, records: _Records) -> None:
    is_failure = pc.equal(records.outcome, fmt.OUTCOME_FAILURE)
    label = records.rows.column("failure_label")
    unlabeled = pc.and_(is_failure, pc.equal(label, fmt.UNLABELED))
    unlabeled_eps = records.listed(pc.fill_null(unlabeled, False).to_numpy(zero_copy_only=False))
    if unlabeled_eps:
        failures = int(pc.sum(is_failure).as_py() or 0)
        state.finding(
            UNLABELED_FAILURE,
            f"{len(unlabeled_eps)} of {failures} failure(s) have no label "
            f"(episodes {listing(unlabeled_eps)})",
            unlabeled_eps[0],
        )


def _incomplete(state: FileState, records: _Records, ended: BoolArray) -> None:
    incomplete = pc.equal(records.outcome, fmt.OUTCOME_INCOMPLETE).to_numpy(zero_copy_only=False)
    incomplete_eps = records.listed(incomplete)
    if not incomplete_eps:
        return
    cut_off = incomplete & ~ended
    lost = state.ev.damaged_episodes  # (their end records were in damaged chunks)
    if lost:
        episodes = records.rows.column(fmt.COL_EPISODE).to_pylist()
        cut_off &= ~np.array([e in lost for e in episodes])
    cut = int(cut_off.sum())
    torn = f", {cut} of them cut off by the torn end of the file" if cut else ""
    state.finding(
        INCOMPLETE_EPISODE,
        f"{len(incomplete_eps)} episode(s) stopped before they ended{torn} "
        f"(episodes {listing(incomplete_eps)})",
        incomplete_eps[0],
    )


def _errors(state: FileState, records: _Records) -> None:
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


def _lengths(state: FileState, records: _Records, endings: EndingChecks, ended: BoolArray) -> None:
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


def _seedless(state: FileState, records: _Records) -> None:
    rows = records.rows
    seedless = pc.and_(pc.is_null(rows.column("seed")), pc.is_null(rows.column("rng_state")))
    seedless_eps = records.listed(seedless.to_numpy(zero_copy_only=False))
    if seedless_eps:
        state.finding(
            NOT_REPLAYABLE,
            f"{len(seedless_eps)} episode(s) have neither a reset seed nor an RNG state "
            f"and cannot be replayed (episodes {listing(seedless_eps)})",
            seedless_eps[0],
        )
