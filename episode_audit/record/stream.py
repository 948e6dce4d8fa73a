"""One stream of episodes in an evidence file, and its per-step hot path (:class:`Stream`).

:meth:`Stream.step` records what ``env.step(action)`` returned: the hot path only appends to the
stream's :class:`~.block.Block` (lengths, returns and term totals are derived when the block is
written); anything unusual takes the slow path, which reads each value on its own and notes
what is odd, never raising into the training loop. How: ``docs/recording.md``.
"""

from __future__ import annotations

import operator
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..format.columns import PLAIN_NUMBERS
from .episodes import EpisodeStream, StreamFile
from .notes import add_notes, append_noted, note
from .values import kept_info, reward_and_terms, step_result, truth_flags

__all__ = ["Stream", "StreamFile"]


class Stream(EpisodeStream):
    """One stream of episodes in an evidence file (make it with ``EvidenceFile.add_stream``).

    A recorder drives it: :meth:`begin` then the env's reset then :meth:`record_reset`; then
    :meth:`step` per step. Episodes end by their flags (classified by the file's ending rules),
    by :meth:`end_open` (``incomplete``) or by :meth:`end_error`.
    """

    __slots__ = ()

    # ------------------------------------------------------------------ steps

    def step(self, action: Any, result: Any) -> None:
        """Record one step: ``result`` is what ``env.step(action)`` returned. Never raises."""
        # The hot path: appends only; lengths, returns and term totals are derived at flush.
        # Anything unusual goes to _record_step_slow.
        try:
            obs, reward, terminated, truncated, info = result
            episode = self.episode
            if episode is None or episode.ended or self._track_info or not isinstance(info, dict):
                raise LookupError  # not the common case (or an info to note): the slow path
            # both flags' truth values, here: one without any (an array) takes the slow path
            running = (not terminated) & (not truncated)
            block = self.block
            names: tuple[str, ...] | None = ()
            terms = None
            if info:
                keys = tuple(info)
                if keys != self._terms_keys:
                    self._plan_terms(keys)
                names = self._terms_names
                if names:
                    # the values, straight into the block: array("d") takes numbers only (a
                    # str such as "1.5" raises: slow path, which drops what this added)
                    if self._terms_one:
                        value = self._terms_get(info)
                        if type(value) not in PLAIN_NUMBERS:  # (an array: number() decides)
                            raise LookupError
                        block.term_vals.append(value)
                    else:
                        several = self._terms_get(info)
                        if not PLAIN_NUMBERS.issuperset(map(type, several)):
                            raise LookupError
                        block.term_vals.extend(several)
                elif names is None:
                    terms = self._extract_terms(info)
                    if terms is not None:
                        # __float__, not float(): a str is not a number (slow path)
                        if not PLAIN_NUMBERS.issuperset(map(type, terms.values())):
                            raise LookupError
                        values = [v.__float__() for v in terms.values()]
            if block.obs.append(obs) is not None or block.act.append(action) is not None:
                raise LookupError  # a value was cast: note it on the slow path
            if type(reward) not in PLAIN_NUMBERS:
                raise LookupError  # (an array, a tensor: number() decides)
            block.rewards.append(reward)  # may raise: slow path
        except Exception:
            self._record_step_slow(result, action)
            return
        row = len(block.times)
        if names:
            block.term_rows.append(row)
            block.term_counts.append(len(names))
            block.term_keys.extend(names)
        elif terms is not None:
            block.add_terms(row, terms, values)
        now = self._clock()
        block.times.append(now)  # commits the row
        if not running:
            self._end_by_flags(episode, block, row, terminated, truncated, info)
        if row + 1 >= self._block_steps or now >= self.flush_at:
            self.file.auto_flush()

    def _plan_terms(self, keys: tuple[Any, ...]) -> None:
        """Say how the terms of infos with these keys are read, until the keys change."""
        plan = self._terms_plans.get(keys)
        if plan is None:
            names = self._terms_rule.names_for(keys)
            # names: one itemgetter reads them all; None: extract() step by step; (): none
            get = operator.itemgetter(*names) if names else tuple
            plan = (keys, names, get, names is not None and len(names) == 1)
            if len(self._terms_plans) < 64:  # bounded: an env with ever-new keys re-plans
                self._terms_plans[keys] = plan
        self._terms_keys, self._terms_names, self._terms_get, self._terms_one = plan

    def term_names(self, keys: tuple[Any, ...]) -> tuple[str, ...] | None:
        """The reward terms :meth:`step` reads by name from an info with these keys, in order.

        ``()``: none; ``None``: it reads them step by step (``RewardTerms.names_for``).
        """
        if keys != self._terms_keys:
            self._plan_terms(keys)
        names: tuple[str, ...] | None = self._terms_names
        return names

    def note_next_row(self, notes: list[str]) -> None:
        """Put ``notes`` on the row the next :meth:`step` writes (a caller's own accounting)."""
        if notes and self.episode is not None:
            add_notes(self.episode, self.block.notes, len(self.block.times), notes)

    def extend(self, obs: Any, actions: Any, rewards: Any, times: Any) -> None:
        """Hand over all rows taken in a batch since the last call (numpy arrays, a row each).

        A batching recorder (the vector recorder) counts the rows it takes in ``block.pending``
        so episode boundaries and endings (:meth:`begin`, :meth:`end_step`) land on the right
        rows, and hands them over before the block is written. Values are already checked to
        need no coercion; a buffer that cannot take them at once gets them row by row.
        """
        block = self.block
        for buffer, values in ((block.obs, obs), (block.act, actions)):
            if not buffer.extend(values):
                for value in values:
                    buffer.append(value)
        block.rewards.frombytes(np.ascontiguousarray(rewards, dtype=np.float64).tobytes())
        block.times.frombytes(np.ascontiguousarray(times, dtype=np.int64).tobytes())
        block.pending = 0

    def _record_step_slow(self, result: Any, action: Any) -> None:
        """Record a step the fast path declined, value by value; never raises into the loop."""
        try:
            self._record_step(result, action)
        except Exception as exc:
            self.file.trouble(exc)

    def _record_step(self, result: Any, action: Any) -> None:
        block = self.block
        rows = block.roll_back()
        notes: list[str] = []
        obs, reward, terminated, truncated, info = step_result(result, notes)
        episode = self.episode
        if episode is None:
            episode = self._implicit_episode(notes)
        raw_flags = terminated, truncated  # _end_by_flags notes a true one that is not a bool
        flags = truth_flags(terminated, truncated, notes)
        if flags is None:
            raw_flags = flags = False, False
        terminated, truncated = flags
        r, terms = reward_and_terms(self._terms_rule, reward, info, notes)
        append_noted(block.obs, obs, "observation", notes)
        append_noted(block.act, action, "action", notes)
        if self._track_info:
            kept = kept_info(info, self._keep_all_info, self._info_keys, notes)
            if kept:
                block.info[rows] = kept
        if episode.ended:
            notes.append(note("step_after_end", f"episode {episode.index} had already ended"))
            block.add_after_end(rows, episode)
        block.rewards.append(r)
        if terms is not None:
            block.add_terms(rows, terms, list(terms.values()))
        if terminated or truncated:
            block.flags[rows] = (terminated, truncated)
        file = self.file
        now = file.clock()
        block.times.append(now)  # commits the row
        if notes:  # beside those an AEC recorder's turn accounting put on the row, if any
            add_notes(episode, block.notes, rows, notes)
        if (terminated or truncated) and not episode.ended:
            self._end_by_flags(
                episode, block, rows, *raw_flags, info if isinstance(info, Mapping) else {}
            )
        if len(block.times) >= self._block_steps or now >= self.flush_at:
            file.auto_flush()
