"""Whole-game outcomes of PettingZoo files, from their agents' episodes.

A *game* is the agent-episodes one joint ``reset()`` started (their ``game`` field). Its outcome
is derived from its agents' outcomes by one rule, the first that applies:

1. ``error`` if any agent-episode is ``error``;
2. ``incomplete`` if any is ``incomplete`` (the recording cut the game);
3. ``failure`` if any agent failed (label: the first failing agent's label, in episode order);
4. ``truncated`` if any agent was truncated (reason: the first truncated agent's reason);
5. ``success`` — every agent succeeded.

That is a team reading (a game succeeds only if every agent does; a task ending beats a cutoff,
as for one episode). For competitive games read the agents' own outcomes (``--by agent``).
A game's ``length`` is its longest agent-episode, its ``return`` the sum of its agents'
returns, its ``term_totals`` the sums of theirs.
"""

from __future__ import annotations

import math
from typing import Any

import pyarrow as pa

from ..format import names as fmt
from ..format.columns import terms_column

__all__ = ["game_outcome", "game_table"]

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
        name: pa.array([r[name] for r in rows], episodes.schema.field(name).type) for name in _NAMES
    }
    columns["term_totals"] = terms_column(len(rows), totals)
    columns["env_index"] = pa.array([0] * len(rows), pa.int64())
    columns["agent"] = pa.nulls(len(rows), pa.string())
    return pa.table(columns)


_NAMES = (
    "episode",
    "outcome",
    "failure_label",
    "truncation_reason",
    "terminated",
    "truncated",
    "length",
    "return",
    "game",
)
