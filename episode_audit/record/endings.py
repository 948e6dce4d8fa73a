"""How a stream's episodes end: by their flags (read by the ending rules), or cut short.

:class:`EpisodeEndings` is the part of :class:`~.episodes.EpisodeStream` (which builds on it)
that ends episodes: by a step's flags, classified by the file's
:class:`~.rules.EndingRules` (``success``, ``failure`` with a label, ``truncated`` with a
reason, ``time_limit`` when one of the env's ``TimeLimit``s says so), as ``incomplete`` (the next
reset, ``close()``) or as ``error`` (the env raised). An ended episode's record waits in the
file's ``pending`` list for the next flush. The compiled step calls ``_end_by_flags`` and
``_limit_hit`` by name (``csrc/step.c``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
from gymnasium.wrappers import TimeLimit

from ..format import names as fmt
from ..format.columns import error_message, text
from ..format.spaces import SpaceCodec
from .block import Block, Episode
from .native import untrack
from .notes import add_notes, note, short
from .rules import Ending, EndingRules
from .time_limits import time_limit_hit

__all__ = ["NO_ACTION", "EndingFile", "EpisodeEndings"]

NO_ACTION: Any = object()
"""``end_error``'s ``action`` when the recorder does not know the action that raised."""

_BOOLS = frozenset({bool, np.bool_})


class EndingFile(Protocol):
    """What ending episodes uses of the evidence file (:class:`~.file.EvidenceFile`)."""

    clock: Callable[[], int]
    counts: dict[str, int]
    pending: list[tuple[Episode, dict[str, Any]]]  # ended episodes, their records not written


class EpisodeEndings:
    """A stream's episode endings, over its open ``episode``, ``block`` and ``file``.

    The stream sets every attribute declared here (:class:`~.episodes.EpisodeStream`).
    """

    __slots__ = ()

    episode: Episode | None
    block: Block
    file: EndingFile
    _rules: EndingRules
    _flag_endings: dict[tuple[bool, bool, bool], Ending]
    _ending_keys: frozenset[str]
    _time_limit: TimeLimit[Any, Any] | None
    _time_limits: tuple[TimeLimit[Any, Any], ...]
    _max_steps: int | None
    _act_codec: SpaceCodec

    def end_open(self, outcome: str = fmt.OUTCOME_INCOMPLETE) -> None:
        """End the open episode, if any, with ``outcome`` (``incomplete`` by default)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self.end_episode(episode, outcome)

    def end_error(self, exc: BaseException, during: str, action: Any = NO_ACTION) -> None:
        """End the open episode as ``error`` (the env raised ``exc`` during reset or step).

        ``action``: the action of the step that raised, when the recorder knows it (a single
        env's); kept in the episode block's ``error_action`` column (null when it does not fit
        the action column), for replay to step it again.
        """
        episode = self.episode
        if episode is None or episode.ended:
            return
        raised = None if action is NO_ACTION else self._error_action(action)
        self.end_episode(episode, fmt.OUTCOME_ERROR, error=(exc, during), error_action=raised)

    def _error_action(self, action: Any) -> pa.Array:
        """``action`` as a one-row column of the stream's action type (null if it does not fit)."""
        buffer = self._act_codec.new_buffer()
        try:
            buffer.append(action)
        except Exception:  # (an action the column cannot hold: what made the env raise, maybe)
            buffer = self._act_codec.new_buffer()
            buffer.append_null()
        return buffer.finish()

    def end_episode(
        self,
        episode: Episode,
        outcome: str,
        *,
        failure_label: str | None = None,
        truncation_reason: str | None = None,
        terminated: bool = False,
        truncated: bool = False,
        error: tuple[BaseException, str] | None = None,
        error_action: pa.Array | None = None,
    ) -> None:
        """Mark the episode ended; its record is written at the next flush."""
        episode.ended = True
        ending: dict[str, Any] = {
            "outcome": outcome,
            "failure_label": failure_label,
            "truncation_reason": truncation_reason,
            "terminated": terminated,
            "truncated": truncated,
            "error": None,
        }
        if error is not None:
            ending["error"] = _error_record(*error)
            ending["error_ns"] = self.file.clock()
            if error_action is not None:
                ending["error_action"] = error_action
        file = self.file
        pair = (episode, ending)
        file.pending.append(pair)
        untrack(pair)
        file.counts["episodes"] += 1

    def end_step(
        self, row: int, terminated: bool, truncated: bool, info: Mapping[str, Any]
    ) -> None:
        """End the open episode by the flags of its step at ``row`` (a batched row)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self._end_by_flags(episode, self.block, row, terminated, truncated, info)

    def end_batched(
        self, pending: int, terminated: bool, truncated: bool, info: dict[str, Any]
    ) -> None:
        """A batched vector step ended the episode (:meth:`end_step`).

        ``pending`` rows are batched for the stream (its block counts them); the last is that
        step's.
        """
        block = self.block
        block.pending = pending
        self.end_step(block.rows() - 1, terminated, truncated, info)

    def _limit_hit(self, block: Block) -> bool:
        if self._time_limits:
            return time_limit_hit(self._time_limits)
        limit = self._max_steps
        # The step's row is committed: the next step index is the episode's length so far.
        return limit is not None and block.segments != [] and block.next_step_index() >= limit

    def _end_by_flags(
        self,
        episode: Episode,
        block: Block,
        row: int,
        terminated: bool,
        truncated: bool,
        info: Mapping[str, Any],
    ) -> None:
        hit = self._limit_hit(block)
        if (
            type(info) is dict
            and type(terminated) is bool
            and type(truncated) is bool
            and info.keys().isdisjoint(self._ending_keys)
        ):  # the common case: nothing to note, no success reported
            plain = self._flag_endings.get((terminated, truncated, hit))
            if plain is not None:
                self._end_as(episode, block, row, plain, terminated, truncated)
                return
        ending, read = _read_ending(self._rules, terminated, truncated, info, hit)
        if self._rules.reports_success(info):
            self.file.counts["success_reported"] += 1
        if read:
            add_notes(episode, block.notes, row, read)
        self._end_as(episode, block, row, ending, bool(terminated), bool(truncated))

    def _end_as(
        self,
        episode: Episode,
        block: Block,
        row: int,
        ending: Ending,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """End ``episode`` at its step ``row`` as ``ending`` says."""
        label = ending.failure_label if terminated else ending.truncation_reason
        untrack(ends := (ending.outcome, label))
        untrack(flags := (terminated, truncated))
        block.ends[row] = ends
        block.flags[row] = flags
        self.end_episode(
            episode,
            ending.outcome,
            failure_label=ending.failure_label,
            truncation_reason=ending.truncation_reason,
            terminated=terminated,
            truncated=truncated,
        )


def _read_ending(
    rules: EndingRules, terminated: Any, truncated: Any, info: Mapping[str, Any], hit: bool
) -> tuple[Ending, list[str]]:
    """The ending of a step whose flags or info are not the plain case, and what to note.

    Flags that are not bools are taken by their truth value (the text ``"False"`` is true:
    the episode ends, and the step says why); an ending the rules cannot read is the flags'.
    """
    read: list[str] = []
    if type(terminated) not in _BOOLS or type(truncated) not in _BOOLS:
        odd = f"terminated={short(terminated)}, truncated={short(truncated)}"
        read.append(note("flags_not_bool", f"{odd} (taken by their truth value)"))
    ending, why = rules.classify_or_note(
        bool(terminated), bool(truncated), info, time_limit_hit=hit, notes=read
    )
    if why is not None:  # the ending by the flags alone; say why
        read.append(note("ending_unreadable", why))
    return ending, read


def _error_record(exc: BaseException, during: str) -> dict[str, str]:
    """The ``error`` of an episode the env's exception ``exc`` ended, ``during`` reset or step."""
    return {
        "type": text(type(exc).__qualname__),
        "message": error_message(exc)[:2000],
        "during": during,
    }
