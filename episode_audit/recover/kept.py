"""The episodes of a recovery's output: how many, which were cut off, which lost evidence."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import pyarrow as pa

from ..format import names as fmt
from ..format.records import EpisodeRanges
from ..format.run_end import RunEnd
from ..read import Evidence
from ..read.opening import open_own_output

__all__ = ["Damage", "Kept"]

Damage = Literal["", "inside", "at the end"]
"""Where a recovery met damage: nowhere, before an intact chunk, or after the last one."""


@dataclass(frozen=True)
class Kept:
    """The episodes of a recovery's output: how many, which were cut off, which damaged."""

    episodes: int
    cut_off: tuple[int, ...]
    damaged: EpisodeRanges

    @classmethod
    def of(cls, path: Path, damage: Damage, *, closed: bool, run_end: RunEnd) -> Kept:
        """Read the (still unfinished) output ``path``.

        ``closed``: the input has a run-end record (intact or garbled), so ``close()`` ran;
        ``run_end``: what that record says (nothing, when it could not be read). A recovered
        input's record lists the episodes its torn original had cut off: they stay cut off.

        Without damage, the episodes without an end record were cut off by the torn end. With
        damage, an episode lost evidence when its end record is missing but a later episode
        of its stream began (only a stream's last episode can be cut off), its reset row is
        missing, it has fewer step rows than its record says, its step indices have a gap, or
        it is missing altogether (indices are 0, 1, ... in a file; a finished input's run-end
        record says how many). An episode without an end record counts as damaged, not cut
        off, when the input was ``closed`` (``close()`` wrote every end record) or the
        ``damage`` comes after the last intact chunk.
        """
        ev = open_own_output(path)  # (locked by this process's writer: not a live recorder)
        table = ev.episodes()
        index = table.column(fmt.COL_EPISODE).to_pylist()
        ended = table.column("ended").to_pylist()
        unended = [e for e, done in zip(index, ended, strict=True) if not done]
        if not damage:
            return cls(len(index), tuple(unended), EpisodeRanges())
        finals = _finals(table, index, damage, closed=closed, run_end=run_end)
        cut = tuple(e for e in unended if e in finals)
        lost = {e for e in unended if e not in finals}
        resets = set(ev.resets().column(fmt.COL_EPISODE).to_pylist())
        lost.update(e for e in index if e not in resets)
        counts, gapped = _step_rows(ev)
        lost |= gapped
        lengths = table.column("length").to_pylist()
        for e, done, length in zip(index, ended, lengths, strict=True):
            if done and counts.get(e, 0) < (length or 0):
                lost.add(e)
        known = sorted(set(index) | set(counts) | resets)
        gaps = _missing(known, run_end.episodes or 0)
        return cls(len(index), cut, EpisodeRanges.of(lost, gaps))


def _finals(
    table: pa.Table, index: list[int], damage: Damage, *, closed: bool, run_end: RunEnd
) -> set[int]:
    """The episodes whose missing end record the torn end cut off (not damage)."""
    streams = zip(
        table.column("env_index").to_pylist(), table.column("agent").to_pylist(), strict=True
    )
    last: dict[tuple[Any, Any], int] = {}
    for e, stream in zip(index, streams, strict=True):
        last[stream] = max(last.get(stream, e), e)
    # After close() (its run-end record is there, even garbled) no episode is cut off —
    # but those a recovery's record lists: a recovered input's cut-off episodes were cut
    # off by the torn original, and stay so. Nor, when damage follows the last intact
    # chunk, can a missing end record be told from a lost one.
    finals = set() if closed or damage == "at the end" else set(last.values())
    if run_end.recovered:
        finals |= run_end.cut_off_episodes
    return finals


def _step_rows(ev: Evidence) -> tuple[dict[int, int], set[int]]:
    """Per episode, its step rows; and the episodes whose step indices are not 0, 1, ..."""
    rows = (
        ev.steps(columns=[fmt.COL_EPISODE, fmt.COL_STEP])
        .group_by(fmt.COL_EPISODE)
        .aggregate([(fmt.COL_STEP, "count"), (fmt.COL_STEP, "min"), (fmt.COL_STEP, "max")])
    )
    counts: dict[int, int] = {}
    gapped: set[int] = set()
    for e, n, low, high in zip(
        rows.column(fmt.COL_EPISODE).to_pylist(),
        rows.column(f"{fmt.COL_STEP}_count").to_pylist(),
        rows.column(f"{fmt.COL_STEP}_min").to_pylist(),
        rows.column(f"{fmt.COL_STEP}_max").to_pylist(),
        strict=True,
    ):
        counts[e] = n
        if low != 0 or high != n - 1:
            gapped.add(e)
    return counts, gapped


def _missing(known: Sequence[int], total: int) -> list[tuple[int, int]]:
    """The episode indices no evidence is left of: the gaps, and after the last one kept.

    >>> _missing([0, 1, 4], 7)
    [(2, 3), (5, 6)]
    """
    gaps, previous = [], -1
    for e in [*known, max(total, known[-1] + 1 if known else 0)]:
        if e > previous + 1:
            gaps.append((previous + 1, e - 1))
        previous = max(previous, e)
    return gaps
