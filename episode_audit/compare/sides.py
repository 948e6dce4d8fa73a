"""One side of a comparison as per-episode arrays, and the pairs two sides share.

:func:`sides` splits the tables :func:`~episode_audit.report.collect.collect` returns into one
:class:`Side` per group key: the side's ended episodes (success, failure, truncated; the
denominator of every rate), their returns, reward-term totals and reset seeds. :func:`pair`
matches two sides' episodes on their reset seeds (the k-th episode seeded ``s`` of one side
with the k-th seeded ``s`` of the other).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..report.collect import ENDED
from ..report.groups import keyed

__all__ = ["Pairs", "Side", "pair", "sides"]

Array = np.ndarray[Any, Any]


@dataclass
class Side:
    """The ended episodes of one group of one side, one value per episode in each array.

    ``seed`` is ``-1`` where an episode's reset had no seed. ``terms[name]`` is the term's
    episode total (0.0 in an episode that did not report the term).
    """

    outcome: Array
    failure_label: Array
    truncation_reason: Array
    returns: Array
    seed: Array
    terms: dict[str, Array] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """The number of ended episodes."""
        return len(self.outcome)

    @classmethod
    def of(
        cls,
        outcome: list[str],
        returns: list[float] | None = None,
        *,
        failure_label: list[str | None] | None = None,
        seed: list[int | None] | None = None,
        terms: dict[str, list[float]] | None = None,
    ) -> Side:
        """A side from plain lists (truncation reasons left unset); for tests and simulations."""
        n = len(outcome)
        labels = failure_label or [
            fmt.UNLABELED if o == fmt.OUTCOME_FAILURE else None for o in outcome
        ]
        return cls(
            np.array(outcome, dtype=object),
            np.array(labels, dtype=object),
            np.array([None] * n, dtype=object),
            np.asarray(returns if returns is not None else [0.0] * n, dtype=np.float64),
            np.array([-1 if s is None else s for s in (seed or [None] * n)], dtype=np.int64),
            {k: np.asarray(v, dtype=np.float64) for k, v in (terms or {}).items()},
        )

    def take(self, index: Array) -> Side:
        """The episodes at ``index``, in that order."""
        return Side(
            self.outcome[index],
            self.failure_label[index],
            self.truncation_reason[index],
            self.returns[index],
            self.seed[index],
            {k: v[index] for k, v in self.terms.items()},
        )


@dataclass(frozen=True)
class Pairs:
    """The episodes two sides share a reset seed with: ``base[i]`` pairs with ``cand[i]``."""

    base: Array
    cand: Array

    def __len__(self) -> int:
        return len(self.base)


def sides(episodes: pa.Table, terms: pa.Table) -> dict[str, Side]:
    """One :class:`Side` per group key of ``collect``'s tables, of its ended episodes."""
    ended = episodes.filter(pc.is_in(episodes.column("outcome"), pa.array(ENDED)))
    return {key: _side(rows, key_terms) for key, rows, key_terms in keyed(ended, terms)}


def _side(rows: pa.Table, terms: pa.Table) -> Side:
    row_ids = rows.column("row").to_numpy(zero_copy_only=False)
    index = {int(r): i for i, r in enumerate(row_ids)}
    totals: dict[str, Array] = {}
    for name, row, total in zip(
        terms.column("term").to_pylist(),
        terms.column("row").to_pylist(),
        terms.column("total").to_pylist(),
        strict=True,
    ):
        i = index.get(int(row))
        if i is None:
            continue
        values = totals.setdefault(name, np.zeros(len(row_ids), dtype=np.float64))
        values[i] += np.nan if total is None else total
    seeds = pc.fill_null(rows.column("seed"), -1).to_numpy(zero_copy_only=False)
    return Side(
        np.array(rows.column("outcome").to_pylist(), dtype=object),
        np.array(rows.column("failure_label").to_pylist(), dtype=object),
        np.array(rows.column("truncation_reason").to_pylist(), dtype=object),
        rows.column("return").to_numpy(zero_copy_only=False).astype(np.float64),
        np.asarray(seeds, dtype=np.int64),
        dict(sorted(totals.items())),
    )


def pair(base: Side, cand: Side) -> Pairs:
    """Match the episodes of two sides on their reset seeds (unseeded ones match nothing)."""
    waiting: dict[int, list[int]] = defaultdict(list)
    for i, s in enumerate(base.seed.tolist()):
        if s >= 0:
            waiting[s].append(i)
    b: list[int] = []
    c: list[int] = []
    for j, s in enumerate(cand.seed.tolist()):
        queue = waiting.get(s)
        if s >= 0 and queue:
            b.append(queue.pop(0))
            c.append(j)
    return Pairs(np.array(b, dtype=np.int64), np.array(c, dtype=np.int64))
