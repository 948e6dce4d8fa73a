"""The rules over rewards and their terms, a block of steps at a time.

:class:`RewardChecks` reports ``nonfinite_reward``, ``nonfinite_term``, ``terms_sum_mismatch``,
``missing_terms`` and ``rewards_changed``. A step's terms match its reward when ``|reward -
(sum(terms) + sum(constants))| <= atol + rtol * |reward|``, the constants being those the file
declares; a mismatch names whose info held the terms. A file recorded over reward-changing
wrappers (its layout names them) holds their rewards and the env's terms: its terms are not
checked against its rewards, and ``rewards_changed`` says so.
"""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa

from ..format.columns import null_mask
from ..format.wrappers import reward_wrapper_names
from ._state import BoolArray, FileState, FloatArray, Hit, HitMessage, IntArray, first_per_episode
from .registry import (
    MISSING_TERMS,
    NONFINITE_REWARD,
    NONFINITE_TERM,
    REWARDS_CHANGED,
    TERMS_SUM_MISMATCH,
    Severity,
)

__all__ = ["RewardChecks", "number"]


def number(value: float) -> str:
    """A reward or term in a message."""
    return f"{value:.9g}"


class _TermSums:
    """One block's reward terms as flat values, with each row's sum and non-finite terms."""

    def __init__(self, terms: pa.Array, has_terms: BoolArray) -> None:
        self.terms = terms
        offsets: IntArray = terms.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        self.offsets, self.lo = offsets, lo
        values: FloatArray = terms.items.slice(lo, hi - lo).to_numpy(zero_copy_only=False)
        self.values = values
        starts = offsets[:-1] - lo
        empty = np.diff(offsets) == 0
        sums: FloatArray = np.add.reduceat(np.append(values, 0.0), starts)
        sums[empty] = 0.0
        self.sums = sums
        self.bad: BoolArray | None = None
        """Rows with a non-finite term (``None`` when the block has none)."""
        nonfinite_values = ~np.isfinite(values)
        if nonfinite_values.any():
            bad_per_row = np.add.reduceat(np.append(nonfinite_values, False), starts)
            bad_per_row[empty] = 0
            self.bad = (bad_per_row > 0) & has_terms

    def first_bad_term(self, row: int) -> str:
        """The first non-finite term of ``row``, for a message."""
        start, stop = int(self.offsets[row]), int(self.offsets[row + 1])
        segment = self.values[start - self.lo : stop - self.lo]
        j = int(np.flatnonzero(~np.isfinite(segment))[0])
        return f"term {self.terms.keys[start + j].as_py()!r} is {number(segment[j])}"


class RewardChecks:
    """The reward rules of one file: block by block, then :meth:`missing_terms_finding`."""

    def __init__(self, state: FileState, *, atol: float, rtol: float, require_terms: bool) -> None:
        self.state = state
        self.atol = float(atol)
        self.rtol = float(rtol)
        self.require_terms = require_terms
        constants = (state.ev.run.reward_terms or {}).get("constants") or {}
        self.constants: dict[str, float] = {
            str(k): float(v) for k, v in constants.items() if isinstance(v, (int, float))
        }
        self.constant_sum = math.fsum(self.constants.values())
        self.changed_by = reward_wrapper_names(state.ev.run.layout)
        """The reward-changing wrappers under the recorder: the rewards are theirs, the terms the
        env's, so the terms are not checked against the rewards."""
        self.unchecked = 0
        """The steps with terms not checked against their reward (:attr:`changed_by`)."""
        info_of = (state.ev.run.reward_terms or {}).get("info_of")
        self.source = (
            f"; terms read automatically from the info of {str(info_of)[:200]}"
            if isinstance(info_of, str)
            else ""
        )
        self.missing_terms = 0
        self.first_missing: tuple[int, int] | None = None

    def messages(self) -> dict[str, HitMessage]:
        """The messages of this group's per-episode findings."""
        return {
            TERMS_SUM_MISMATCH: self._mismatch_message,
            NONFINITE_REWARD: _nonfinite_message,
            NONFINITE_TERM: _nonfinite_message,
        }

    def block(self, terms: pa.Array, episode: IntArray, step: IntArray, reward: FloatArray) -> None:
        """Check one block's rewards against themselves and their terms."""
        finite_reward = self._nonfinite_rewards(episode, step, reward)
        has_terms = self._with_terms(terms, episode, step)
        if has_terms is None:
            return
        sums = _TermSums(terms, has_terms)
        if sums.bad is not None and sums.bad.any():
            self._nonfinite_terms(sums, sums.bad, episode, step)
        if self.changed_by:
            self.unchecked += int(has_terms.sum())
        else:
            self._mismatches(sums, has_terms & finite_reward, episode, step, reward)

    def _nonfinite_rewards(
        self, episode: IntArray, step: IntArray, reward: FloatArray
    ) -> BoolArray:
        """Hits for NaN and infinite rewards; return which rewards are finite."""
        finite_reward: BoolArray = np.isfinite(reward)
        bad_reward = ~finite_reward
        if bad_reward.any():
            eps, first, counts, _ = first_per_episode(episode, bad_reward)
            details = [f"reward {number(r)}" for r in reward[first].tolist()]
            self.state.hits.add(
                NONFINITE_REWARD, eps, step[first].tolist(), counts, details=details
            )
        return finite_reward

    def _with_terms(self, terms: pa.Array, episode: IntArray, step: IntArray) -> BoolArray | None:
        """Count the steps without terms; return the rows with terms (``None``: no row has)."""
        n = len(terms)
        if not terms.null_count:
            return np.ones(n, dtype=np.bool_)
        missing = null_mask(terms)
        count = int(missing.sum())
        if self.first_missing is None and count:
            row = int(np.argmax(missing))
            self.first_missing = (int(episode[row]), int(step[row]))
        self.missing_terms += count
        if count == n:
            return None
        has_terms: BoolArray = ~missing
        return has_terms

    def _nonfinite_terms(
        self, sums: _TermSums, bad: BoolArray, episode: IntArray, step: IntArray
    ) -> None:
        eps, first, counts, _ = first_per_episode(episode, bad)
        details = [sums.first_bad_term(row) for row in first.tolist()]
        self.state.hits.add(NONFINITE_TERM, eps, step[first].tolist(), counts, details=details)

    def _mismatches(
        self,
        sums: _TermSums,
        comparable: BoolArray,
        episode: IntArray,
        step: IntArray,
        reward: FloatArray,
    ) -> None:
        """Hits for rewards that differ from their terms' sum beyond the tolerance."""
        expected = sums.sums + self.constant_sum
        with np.errstate(invalid="ignore", over="ignore"):
            residual = np.abs(reward - expected)
            tolerance = self.atol + self.rtol * np.abs(reward)
            mismatch = comparable & (residual > tolerance)
        if sums.bad is not None:
            mismatch &= ~sums.bad
        if not mismatch.any():
            return
        eps, first, counts, worst = first_per_episode(episode, mismatch, residual)
        constants = f" + constants {number(self.constant_sum)}" if self.constants else ""
        details = [
            f"reward {number(r)} != terms sum {number(s)}{constants} (residual {d:.3g})"
            for r, s, d in zip(
                reward[first].tolist(),
                sums.sums[first].tolist(),
                residual[first].tolist(),
                strict=True,
            )
        ]
        self.state.hits.add(
            TERMS_SUM_MISMATCH, eps, step[first].tolist(), counts, worst=worst, details=details
        )

    def _mismatch_message(self, hit: Hit, where: str) -> str:
        return (
            f"{hit.detail} {where}; {hit.count} step(s) of the episode mismatch, worst residual "
            f"{hit.worst:.3g} (tolerance {self.atol:g} + {self.rtol:g}*|reward|)" + self.source
        )

    def rewards_changed_finding(self) -> None:
        """After the steps: the rewards are the wrappers', and the terms were not checked."""
        names = self.changed_by
        if not names:
            return
        it = "it" if len(names) == 1 else "them"
        said = (
            f"the recorded rewards and returns are {', '.join(names)}'s, not the env's: the "
            f"recorder sat over {it}"
        )
        if not self.unchecked:
            self.state.finding(
                REWARDS_CHANGED, f"{said}; record beneath {it} (innermost) for the env's own"
            )
            return
        self.state.finding(
            REWARDS_CHANGED,
            f"{said}; the reward terms of {self.unchecked} step(s) were not checked against "
            "these rewards, the terms being the env's (the wrappers change the reward, not its "
            f"terms): record beneath {it} (innermost) for the env's own rewards, checked against "
            "their terms",
        )

    def missing_terms_finding(self) -> None:
        """After the steps: one finding for the steps without terms, if any.

        A warning where terms are expected: the recording named where they come from (a list
        of keys, a callable), or some step of the file has terms. With the default source
        (``"auto"``) and no step with terms, the env reports none (CartPole): a note, as for
        ``reward_terms=None``. An error with ``require_terms``.
        """
        if not self.missing_terms:
            return
        source = (self.state.ev.run.reward_terms or {}).get("source")
        severity: Severity = "warning"
        why = "; their rewards cannot be checked against terms"
        if source is None:
            severity = "note"  # reward_terms=None: the recording was told to keep none
        elif source == "auto" and self.missing_terms == self.state.steps:
            severity = "note"
            why = (
                ": the env reports none (no info['reward_terms'], no info['reward_*'] keys); "
                "name them with reward_terms= to check its rewards against them"
            )
        if self.require_terms:
            severity = "error"
        episode, step = self.first_missing or (None, None)
        self.state.finding(
            MISSING_TERMS,
            f"{self.missing_terms} of {self.state.steps} steps have no reward terms "
            f"(terms source {source!r}){why}",
            episode,
            step,
            severity=severity,
        )


def _nonfinite_message(hit: Hit, where: str) -> str:
    return f"{hit.detail} {where}; {hit.count} step(s) of the episode"
