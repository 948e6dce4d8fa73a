"""What the rule groups of one file share, and how they group a block's rows by episode.

- :class:`FileState`: the open evidence, its findings so far, its per-episode :class:`Hits`
  and what was counted; :meth:`FileState.finding` adds a finding with the registry's severity.
- :func:`first_per_episode` and :func:`counts_per_episode` group one block's rows by episode
  with numpy, so no Python code runs per step.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from ..format.records import unstarted
from ..read import Evidence
from .findings import Finding
from .registry import SEVERITY, Severity

__all__ = [
    "BoolArray",
    "FileState",
    "FloatArray",
    "Hit",
    "HitMessage",
    "Hits",
    "IntArray",
    "counts_per_episode",
    "first_per_episode",
    "short",
    "steps_of",
]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]


@dataclass
class Hit:
    """First occurrence, count and worst value of one kind of problem in one episode."""

    step: int | None
    count: int
    worst: float = 0.0
    detail: str = ""


HitMessage = Callable[[Hit, str], str]
"""The message of a per-episode finding, from its merged hit and where it was first."""


@dataclass
class Hits:
    """Per (code, episode, at reset): the merged :class:`Hit` over every block."""

    by_key: dict[tuple[str, int, bool], Hit] = field(default_factory=dict)

    def add(
        self,
        code: str,
        episodes: IntArray,
        first_steps: list[int | None],
        counts: IntArray,
        worst: FloatArray | None = None,
        details: list[str] | None = None,
    ) -> None:
        """Merge one block's per-episode results (earlier blocks keep their first step)."""
        table = self.by_key
        worst_list = None if worst is None else worst.tolist()
        for i, (episode, count) in enumerate(zip(episodes.tolist(), counts.tolist(), strict=True)):
            key = (code, episode, first_steps[i] is None)
            hit = table.get(key)
            w = 0.0 if worst_list is None else worst_list[i]
            if hit is None:
                detail = "" if details is None else details[i]
                table[key] = Hit(first_steps[i], count, w, detail)
            else:
                hit.count += count
                if w > hit.worst or math.isnan(w):
                    hit.worst = w


class FileState:
    """One file being checked: its evidence, findings and hits, and what was counted."""

    def __init__(self, ev: Evidence) -> None:
        self.ev = ev
        self.file = str(ev.path)
        self.findings: list[Finding] = []
        self.hits = Hits()
        self.steps = 0
        self.episodes = 0

    @functools.cached_property
    def unstarted(self) -> BoolArray:
        """Which rows of the file's episodes table are unstarted episodes (computed once)."""
        return unstarted(self.ev.episodes())

    def finding(
        self,
        code: str,
        message: str,
        episode: int | None = None,
        step: int | None = None,
        *,
        severity: Severity | None = None,
    ) -> None:
        """Add a finding; its severity is the code's in the registry unless given."""
        self.findings.append(
            Finding(severity or SEVERITY[code], code, message, self.file, episode, step)
        )


def first_per_episode(
    episode: IntArray, mask: BoolArray, values: FloatArray | None = None
) -> tuple[IntArray, IntArray, IntArray, FloatArray | None]:
    """Group the rows in ``mask`` by episode.

    Return the episodes (ascending), the row of each one's first hit, its number of hits and,
    given ``values``, the largest value over its hits.
    """
    rows = np.flatnonzero(mask)
    eps = episode[rows]
    if eps.size and not (eps[1:] >= eps[:-1]).all():
        rows = rows[np.argsort(eps, kind="stable")]  # stable: first hits stay first
        eps = episode[rows]
    starts = np.flatnonzero(np.r_[True, eps[1:] != eps[:-1]]) if eps.size else rows
    counts = np.diff(np.r_[starts, eps.size]).astype(np.int64)
    largest = None if values is None else np.maximum.reduceat(values[rows], starts)
    return eps[starts], rows[starts], counts, largest


def counts_per_episode(episode: IntArray, ordered: bool = False) -> tuple[IntArray, IntArray]:
    """Return (episodes, rows per episode) of one block (``ordered``: it never decreases)."""
    if episode.size == 0:
        return episode, episode
    if ordered:
        starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]])
        return episode[starts], np.diff(np.r_[starts, episode.size]).astype(np.int64)
    low = int(episode.min())
    span = int(episode.max()) - low
    if 0 <= span <= 4 * episode.size:
        counts = np.bincount(episode - low, minlength=span + 1)
        present = np.flatnonzero(counts)
        return present.astype(np.int64) + low, counts[present].astype(np.int64)
    uniq, counts = np.unique(episode, return_counts=True)
    return uniq, counts.astype(np.int64)


def steps_of(step: IntArray | None, rows: IntArray) -> list[int | None]:
    """The steps of ``rows`` (all ``None`` for resets, which have no ``step``)."""
    if step is None:
        return [None] * len(rows)
    steps: list[int | None] = step[rows].tolist()
    return steps


def short(value: object, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
