"""Whole-game outcomes of PettingZoo files, from their agents' episodes.

A *game* is the agent-episodes one joint ``reset()`` started (their ``game`` field).
:func:`game_outcome` derives its outcome from its agents' by one rule, a team reading (the first
of ``error``, ``incomplete``, ``failure``, ``truncated`` any agent-episode has, else ``success``:
``docs/format.md``, "Game outcome"); :func:`game_table` turns an episodes table into one row per
game: its longest agent-episode's length, the sums of their returns and reward-term totals.
"""

from __future__ import annotations

import math
from typing import Any

import pyarrow as pa

from ..format import names as fmt
from ..format.columns import terms_column

__all__ = ["OUTCOME_FIELDS", "game_outcome", "game_table"]

OUTCOME_FIELDS = (
    "outcome",
    "failure_label",
    "truncation_reason",
    "terminated",
    "truncated",
    "length",
    "return",
)
"""The columns of an episode's ending a report reads; a game's row has them too."""

_ORDER = (fmt.OUTCOME_ERROR, fmt.OUTCOME_INCOMPLETE, fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED)


def game_outcome(outcomes: list[str]) -> str:
    """The outcome of a game whose agents' episodes ended with ``outcomes``.

    >>> game_outcome(["success", "truncated"]), game_outcome(["failure", "truncated"])
    ('truncated', 'failure')
    >>> game_outcome(["success", "success"])
    'success'
    """
    for outcome in _ORDER:
        if outcome in outcomes:
            return outcome
    return fmt.OUTCOME_SUCCESS


def game_table(episodes: pa.Table) -> pa.Table:
    """One row per game of an episodes table (columns as :meth:`Evidence.episodes`).

    ``episode`` and ``game`` hold the game index, ``agent`` is null; episodes without a game
    are left out.
    """
    if "game" not in episodes.column_names:
        return episodes.schema.empty_table()
    by_game: dict[int, list[dict[str, Any]]] = {}
    for row in episodes.to_pylist():
        if row.get("game") is not None:
            by_game.setdefault(int(row["game"]), []).append(row)
    rows: list[dict[str, Any]] = []
    totals: dict[int, dict[str, float]] = {}
    for i, (game, members) in enumerate(sorted(by_game.items())):
        outcome = game_outcome([str(m["outcome"]) for m in members])
        label = next(
            (m["failure_label"] for m in members if m["outcome"] == fmt.OUTCOME_FAILURE), None
        )
        reason = next(
            (m["truncation_reason"] for m in members if m["outcome"] == fmt.OUTCOME_TRUNCATED),
            None,
        )
        merged: dict[str, float] = {}
        for m in members:
            for key, value in m.get("term_totals") or []:
                merged[key] = merged.get(key, 0.0) + value
        if merged:
            totals[i] = merged
        rows.append(
            {
                "episode": game,
                "outcome": outcome,
                "failure_label": label if outcome == fmt.OUTCOME_FAILURE else None,
                "truncation_reason": reason if outcome == fmt.OUTCOME_TRUNCATED else None,
                "terminated": all(bool(m["terminated"]) for m in members),
                "truncated": any(bool(m["truncated"]) for m in members),
                "length": max(int(m["length"] or 0) for m in members),
                "return": math.fsum(float(m["return"]) for m in members),
                "game": game,
            }
        )
    columns = {
        name: pa.array([r[name] for r in rows], episodes.schema.field(name).type)
        for name in ("episode", *OUTCOME_FIELDS, "game")
    }
    columns["term_totals"] = terms_column(len(rows), totals)
    columns["env_index"] = pa.array([0] * len(rows), pa.int64())
    columns["agent"] = pa.nulls(len(rows), pa.string())
    return pa.table(columns)
