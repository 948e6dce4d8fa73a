"""Where episodes end in the step rows: ``step_after_end``, and each episode's rows up to its end.

:class:`EndingChecks` finds, block by block, the rows after an episode's outcome row (or noted
by the recorder as stepped after the end) and counts the others, for ``length_mismatch``.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from ..format.columns import null_mask
from ..format.wrappers import autoreset_wrapped
from ._state import (
    BoolArray,
    FileState,
    Hit,
    HitMessage,
    IntArray,
    counts_per_episode,
    first_per_episode,
)
from .registry import STEP_AFTER_END

__all__ = ["EndingChecks"]


class EndingChecks:
    """The ending rules of one file: which episodes ended, and their rows up to the end."""

    def __init__(self, state: FileState) -> None:
        self.state = state
        self.ended: set[int] = set()
        self.max_ended: int | None = None
        self.count_parts: list[tuple[IntArray, IntArray]] = []

    def messages(self) -> dict[str, HitMessage]:
        """The messages of this group's per-episode findings."""
        autoreset = autoreset_wrapped(self.state.ev.run.env_spec)
        return {STEP_AFTER_END: _after_autoreset_message if autoreset else _after_end_message}

    def rows_after_end(
        self, outcome: pa.Array, episode: IntArray, present: IntArray, ordered: bool
    ) -> BoolArray | None:
        """Record which episodes ended; return the rows after an episode's outcome row.

        ``present`` holds the block's episodes in ascending order; ``ordered`` says whether
        ``episode`` never decreases.
        """
        n = len(outcome)
        after: BoolArray | None = None
        if self.max_ended is not None and present[0] <= self.max_ended:
            seen = [e for e in present.tolist() if e in self.ended]
            if seen:
                after = np.isin(episode, np.array(seen, dtype=np.int64))
        if outcome.null_count == n:
            return after
        end_rows = np.flatnonzero(~null_mask(outcome))
        end_eps = episode[end_rows]
        self.ended.update(end_eps.tolist())
        top = int(end_eps.max())
        self.max_ended = top if self.max_ended is None else max(self.max_ended, top)
        # The usual layout: each episode's rows are contiguous and its outcome row is its last,
        # so the row after an outcome row (if any) belongs to another episode.
        following = end_rows + 1
        following[following == n] = end_rows[following == n]
        if ordered and not (episode[following] == end_eps)[following != end_rows].any():
            return after
        uniq_eps, first = np.unique(end_eps, return_index=True)
        end_pos = end_rows[first]
        k = np.minimum(np.searchsorted(uniq_eps, episode), uniq_eps.size - 1)
        within = (uniq_eps[k] == episode) & (np.arange(n) > end_pos[k])
        if within.any():
            after = within if after is None else after | within
        return after

    def count_rows(
        self,
        episode: IntArray,
        step: IntArray,
        after_end: BoolArray | None,
        present: IntArray,
        counts: IntArray,
        ordered: bool,
    ) -> None:
        """Hits for the rows after the end; count the block's other rows per episode.

        ``present`` and ``counts`` are the block's rows per episode, ``after_end`` included.
        """
        if after_end is not None and after_end.any():
            eps, first, hits, _ = first_per_episode(episode, after_end)
            self.state.hits.add(STEP_AFTER_END, eps, step[first].tolist(), hits)
            present, counts = counts_per_episode(episode[~after_end], ordered)
        self.count_parts.append((present, counts))

    def rows_counted(self, episode: IntArray) -> IntArray:
        """For each of ``episode``, the step rows counted up to its end (0 for none)."""
        if self.count_parts:
            eps = np.concatenate([p[0] for p in self.count_parts])
            counts = np.concatenate([p[1] for p in self.count_parts])
            uniq, inverse = np.unique(eps, return_inverse=True)
            totals = np.bincount(inverse, weights=counts).astype(np.int64)
        else:
            uniq = totals = np.zeros(0, dtype=np.int64)
        if uniq.size:
            k = np.minimum(np.searchsorted(uniq, episode), uniq.size - 1)
            counted: IntArray = np.where(uniq[k] == episode, totals[k], 0)
            return counted
        return np.zeros_like(episode)


def _after_end_message(hit: Hit, where: str) -> str:
    return f"{hit.count} step(s) recorded after the episode ended, first {where}"


def _after_autoreset_message(hit: Hit, where: str) -> str:
    """The message when the file's env had an ``Autoreset`` (it reset the env in a step)."""
    return (
        f"{_after_end_message(hit, where)}: the env's Autoreset wrapper reset it inside "
        "step(), not recorded as a reset; put Autoreset right under the recorder (which "
        "records those resets as episodes) or over it"
    )
