"""One side of a comparison as per-episode arrays, and the pairs two sides share.

:func:`sides` splits the tables :func:`~episode_audit.report.collect.collect` returns into one
:class:`Side` per group key an episode of which ended or raised: the side's ended episodes
(success, failure, truncated; the denominator of every rate but the error rate; none when
every one raised), their returns, reward-term totals, reset seeds
and RNG states, the task (env id) of each; and (``Side.started``) every episode it started,
errors and incomplete ones too (the error rate's denominator, as report's).
:func:`pair` matches two sides' episodes on how they began (the k-th episode of a task seeded
``s`` of one side with the k-th of that task seeded ``s`` of the other; unseeded ones by the
RNG state recorded).
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

__all__ = ["PAIRED_SHARE", "Pairs", "Side", "pair", "sides", "started"]

Array = np.ndarray[Any, Any]


@dataclass
class Side:
    """The ended episodes of one group of one side, one value per episode in each array.

    ``seed`` is ``-1`` where an episode's reset had no seed; ``rng`` a digest of the RNG state
    an unseeded reset began from (``-1``: none recorded). ``terms[name]`` is the term's episode
    total (0.0 in an episode that did not report the term). ``success_signal``: some file of
    the side reports success (a success key or ``success_fn``); without, no episode can
    succeed, whatever the policy. ``reward_wrappers``: whose rewards its returns are.
    ``started``: every episode of the group that began (ended, ``incomplete`` or ``error``),
    as a side of its own; ``None``: the ended ones are all (no error, nothing incomplete).
    """

    outcome: Array
    failure_label: Array
    truncation_reason: Array
    returns: Array
    seed: Array
    terms: dict[str, Array] = field(default_factory=dict)
    rng: Array | None = None
    success_signal: bool = True
    reward_wrappers: frozenset[str] = frozenset()
    """The reward wrappers the side's episodes were recorded over, with their settings, a chain
    each (:func:`~episode_audit.report.wrapped.file_setup`; ``""``: none, the env's own
    rewards)."""
    started: Side | None = None
    reported: dict[str, Array] = field(default_factory=dict)
    """Per term, whether each episode reported it at all (absent: every episode did)."""
    task: Array | None = None
    """Per episode, the env id of its file (``None``: one task, unnamed): episodes pair only
    within a task."""

    @property
    def everything(self) -> Side:
        """Every episode the group started (:attr:`started`, or this side when that is unset)."""
        return self if self.started is None else self.started

    @property
    def n(self) -> int:
        """The number of ended episodes."""
        return len(self.outcome)

    def failure_names(self) -> Array:
        """Per episode, its failure label as report names it (``None`` unless a failure).

        A failure without a label (null or empty: another writer's file, a game's) is
        ``unlabeled`` (:data:`~episode_audit.format.names.UNLABELED`), as in report.
        """
        failed = self.outcome == fmt.OUTCOME_FAILURE
        return np.array(
            [str(label or fmt.UNLABELED) if f else None
             for f, label in zip(failed.tolist(), self.failure_label.tolist(), strict=True)],
            dtype=object,
        )  # fmt: skip

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
        """The episodes at ``index``, in that order (:attr:`started` unset: they are all)."""
        return Side(
            self.outcome[index],
            self.failure_label[index],
            self.truncation_reason[index],
            self.returns[index],
            self.seed[index],
            {k: v[index] for k, v in self.terms.items()},
            None if self.rng is None else self.rng[index],
            self.success_signal,
            self.reward_wrappers,
            task=None if self.task is None else self.task[index],
            reported={k: v[index] for k, v in self.reported.items()},
        )

    def tasks(self) -> list[str]:
        """The env ids of the side's episodes, sorted (empty when unnamed)."""
        return [] if self.task is None else sorted(set(self.task.tolist()))


PAIRED_SHARE = 0.5
"""Paired when the matched pairs of each task are at least this share of its smaller side's
episodes (:func:`pair`)."""


@dataclass(frozen=True)
class Pairs:
    """The episodes two sides share a reset seed with: ``base[i]`` pairs with ``cand[i]``.

    ``usable``: whether to compare paired (:func:`pair` says when); ``unpaired``: how many
    episodes of each side (baseline, candidate) found no pair, left out when paired.
    """

    base: Array
    cand: Array
    usable: bool = False
    unpaired: tuple[int, int] = (0, 0)

    def __len__(self) -> int:
        return len(self.base)

    def left_out(self, what: str) -> list[str]:
        """The note on the episodes a paired comparison of ``what`` leaves out, if it does."""
        b, c = self.unpaired
        if not self.usable or not b + c:
            return []
        return [
            f"{what} compared paired on {len(self)} pairs: {b} baseline and {c} candidate "
            "episodes have no pair (no episode of the other side began as they did) and are "
            "left out of it"
        ]


def sides(episodes: pa.Table, terms: pa.Table) -> dict[str, Side]:
    """One :class:`Side` per group key of ``collect``'s tables, of its ended episodes.

    A key is there when an episode of it ended or raised (``error``): a group whose episodes
    all raised has a side of no ended episode, its error rate still measured. Each side's
    :attr:`Side.started` holds all its group's episodes when some did not end.
    """
    ended = episodes.filter(pc.is_in(episodes.column("outcome"), pa.array(ENDED)))
    found = {key: _side(rows, key_terms) for key, rows, key_terms in keyed(ended, terms)}
    if ended.num_rows == episodes.num_rows:
        return found
    for key, every in started(episodes, terms).items():
        side = found.get(key)
        if side is None and (every.outcome == fmt.OUTCOME_ERROR).any():
            side = found[key] = every.take(np.zeros(0, dtype=np.int64))
        if side is not None:
            side.started = every
    return found


def started(episodes: pa.Table, terms: pa.Table) -> dict[str, Side]:
    """One :class:`Side` per group key of ``collect``'s tables, of every episode it started."""
    return {key: _side(rows, key_terms) for key, rows, key_terms in keyed(episodes, terms)}


def _side(rows: pa.Table, terms: pa.Table) -> Side:
    row_ids = rows.column("row").to_numpy(zero_copy_only=False)
    index = {int(r): i for i, r in enumerate(row_ids)}
    totals: dict[str, Array] = {}
    reported: dict[str, Array] = {}
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
        reported.setdefault(name, np.zeros(len(row_ids), dtype=np.bool_))[i] = True
    seeds = pc.fill_null(rows.column("seed"), -1).to_numpy(zero_copy_only=False)
    rngs = pc.fill_null(rows.column("rng"), -1).to_numpy(zero_copy_only=False)
    return Side(
        np.array(rows.column("outcome").to_pylist(), dtype=object),
        np.array(rows.column("failure_label").to_pylist(), dtype=object),
        np.array(rows.column("truncation_reason").to_pylist(), dtype=object),
        rows.column("return").to_numpy(zero_copy_only=False).astype(np.float64),
        np.asarray(seeds, dtype=np.int64),
        dict(sorted(totals.items())),
        np.asarray(rngs, dtype=np.int64),
        bool(pc.any(rows.column("success_signal")).as_py()),
        frozenset(pc.fill_null(rows.column("reward_wrappers"), "").unique().to_pylist()),
        task=(
            np.array(rows.column("task").to_pylist(), dtype=object)
            if "task" in rows.column_names
            else None
        ),
        reported=reported,
    )


def pair(base: Side, cand: Side) -> Pairs:
    """Match the episodes of two sides on how they began.

    The same reset seed, or (unseeded) the same recorded RNG state, of the same task (env id):
    the k-th of one side with the k-th of the other. An episode with neither matches nothing.
    Two sides of one task each (the same, or two versions compared with ``different_tasks``)
    pair across them.

    The pairs are ``usable`` when they number at least 2 and, for each task of either side, at
    least :data:`PAIRED_SHARE` of its smaller side's episodes, and one: a paired comparison
    leaves the episodes without a pair out, and must not leave out a task (whose episodes
    would then be in no comparison), nor most of one. Else the comparison is unpaired, over
    every episode.
    """
    by_task = len(base.tasks()) > 1 or len(cand.tasks()) > 1
    waiting: dict[tuple[str, int, str | None], list[int]] = defaultdict(list)
    for i, start in enumerate(_starts(base, by_task)):
        if start is not None:
            waiting[start].append(i)
    b: list[int] = []
    c: list[int] = []
    for j, start in enumerate(_starts(cand, by_task)):
        queue = waiting.get(start) if start is not None else None
        if queue:
            b.append(queue.pop(0))
            c.append(j)
    found_b, found_c = np.array(b, dtype=np.int64), np.array(c, dtype=np.int64)
    usable = len(b) >= 2 and _each_task_paired(base, cand, found_b, by_task)
    return Pairs(found_b, found_c, usable, (base.n - len(b), cand.n - len(c)))


def _each_task_paired(base: Side, cand: Side, paired: Array, by_task: bool) -> bool:
    """Whether each task has pairs, at least :data:`PAIRED_SHARE` of its smaller side's episodes.

    ``paired``: the baseline's episodes that found a pair. One task when not ``by_task``.
    """
    if not by_task or base.task is None or cand.task is None:
        return len(paired) >= PAIRED_SHARE * min(base.n, cand.n)
    tasks_b, tasks_c = base.task.tolist(), cand.task.tolist()
    of_pairs = base.task[paired].tolist()
    for task in set(tasks_b) | set(tasks_c):
        n = of_pairs.count(task)
        if n < max(1, PAIRED_SHARE * min(tasks_b.count(task), tasks_c.count(task))):
            return False
    return True


def _starts(side: Side, by_task: bool) -> list[tuple[str, int, str | None] | None]:
    """Each episode's start: ``("seed", s, task)``, ``("rng", digest, task)`` or ``None``.

    ``task`` is ``None`` unless ``by_task``.
    """
    rngs = side.rng.tolist() if side.rng is not None else [-1] * side.n
    tasks = side.task.tolist() if by_task and side.task is not None else [None] * side.n
    return [
        ("seed", s, t) if s >= 0 else ("rng", r, t) if r >= 0 else None
        for s, r, t in zip(side.seed.tolist(), rngs, tasks, strict=True)
    ]
