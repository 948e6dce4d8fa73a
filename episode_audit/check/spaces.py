"""The rules over observations and actions: are they inside their spaces.

:class:`SpaceChecks` checks a whole column at a time with the spaces' codecs, for
``observation_out_of_space``, ``action_out_of_space``, ``observation_space_unchecked`` and
``action_space_unchecked``.
"""

from __future__ import annotations

import pyarrow as pa

from ..format import names as fmt
from ..format.spaces import SpaceCodec, unknown_spaces
from ._state import FileState, Hit, HitMessage, IntArray, first_per_episode, short, steps_of
from .registry import (
    ACTION_OUT_OF_SPACE,
    ACTION_SPACE_UNCHECKED,
    OBSERVATION_OUT_OF_SPACE,
    OBSERVATION_SPACE_UNCHECKED,
)

__all__ = ["SpaceChecks"]


class SpaceChecks:
    """The space rules of one file: observations (steps and resets) and actions."""

    def __init__(self, state: FileState) -> None:
        self.state = state
        self.obs_codec: SpaceCodec | None = state.ev.observation_codec
        self.act_codec: SpaceCodec | None = state.ev.action_codec

    def messages(self) -> dict[str, HitMessage]:
        """The messages of this group's per-episode findings."""
        return {
            OBSERVATION_OUT_OF_SPACE: _observation_message,
            ACTION_OUT_OF_SPACE: _action_message,
        }

    def unrebuildable(self) -> None:
        """Before the steps: a note for each space that is not checked.

        A space the file's description cannot rebuild, or a sub-space of a class episode-audit
        does not know (stored as JSON, its values unchecked).
        """
        run = self.state.ev.run
        for column, code, codec in (
            ("observation", OBSERVATION_SPACE_UNCHECKED, self.obs_codec),
            ("action", ACTION_SPACE_UNCHECKED, self.act_codec),
        ):
            if codec is not None:
                for where in unknown_spaces(getattr(run, f"{column}_space"), column):
                    self.state.finding(code, f"{where}; its values were not checked against it")
        if self.obs_codec is None:
            self.state.finding(
                OBSERVATION_SPACE_UNCHECKED,
                "the observation space cannot be rebuilt from the file; observations "
                "were not checked against it",
            )
        if self.act_codec is None:
            self.state.finding(
                ACTION_SPACE_UNCHECKED,
                "the action space cannot be rebuilt from the file; actions were not checked "
                "against it",
            )

    def column(
        self, column: str, array: pa.Array, episode: IntArray, step: IntArray | None
    ) -> None:
        """Check a column against its space (``step`` is ``None`` for reset observations)."""
        codec = self.obs_codec if column == fmt.COL_OBSERVATION else self.act_codec
        if codec is None:
            return
        try:
            inside = codec.contains(array)
        except (TypeError, ValueError, pa.ArrowException) as exc:
            self._unchecked(column, f"{type(exc).__name__}: {exc}")
            return
        outside = ~inside
        if not outside.any():
            return
        code = OBSERVATION_OUT_OF_SPACE if column == fmt.COL_OBSERVATION else ACTION_OUT_OF_SPACE
        eps, first, counts, _ = first_per_episode(episode, outside)
        details = []
        for row in first.tolist():
            try:
                value = codec.decode(array.slice(row, 1))[0]
            except Exception as exc:  # a value contains() judged but decode cannot show
                value = f"<{type(exc).__name__}>"
            details.append(short(value))
        self.state.hits.add(code, eps, steps_of(step, first), counts, details=details)

    def _unchecked(self, column: str, why: str) -> None:
        """Checking ``column`` failed: say so, and check it no further."""
        code = (
            OBSERVATION_SPACE_UNCHECKED if column == fmt.COL_OBSERVATION else ACTION_SPACE_UNCHECKED
        )
        if column == fmt.COL_OBSERVATION:
            self.obs_codec = None
        else:
            self.act_codec = None
        self.state.finding(code, f"{column}s were not checked against their space: {why}")


def _observation_message(hit: Hit, where: str) -> str:
    return f"observation outside its space {where}: {hit.detail}; {hit.count} row(s) of the episode"


def _action_message(hit: Hit, where: str) -> str:
    return f"action outside its space {where}: {hit.detail}; {hit.count} row(s) of the episode"
