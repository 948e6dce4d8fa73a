"""The run-end record read back: each value typed, whatever the file holds.

A file's run-end record (metadata ``episode_audit.run_end``, ``docs/format.md``, "Run end") is
text keys and values, written by the recorder's ``close()`` (``status`` ``finished``) or by
``episode-audit recover`` (``status`` ``recovered``). :class:`RunEnd` is what every reader takes
from it. A value that is absent, garbled or made to trip a reader (not a number, not JSON, JSON
nested a hundred thousand deep) reads as "not said": never an exception.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from . import names as fmt
from .records import EpisodeRanges, from_json

__all__ = ["RunEnd"]


@dataclass(frozen=True)
class RunEnd:
    """What a run-end record says (see :meth:`of`); defaults: not said.

    >>> end = RunEnd.of({"status": "recovered", "steps": "120", "cut_off_episodes": "[4]"})
    >>> end.recovered, end.steps, end.cut_off_episodes, end.episodes
    (True, 120, frozenset({4}), None)
    >>> RunEnd.of({"damaged": "[" * 100_000, "recorder_trouble": "x"}).damaged_stretches
    0
    >>> RunEnd.of(None) == RunEnd()
    True
    """

    status: str | None = None
    """``finished`` (the recorder's ``close()``) or ``recovered`` (``episode-audit recover``)."""
    episodes: int | None = None
    """The episodes the file holds (a recovery counts the cut-off ones)."""
    steps: int | None = None
    """The step rows the file holds."""
    troubles: int = 0
    """How many times the recorder failed inside itself while recording."""
    first_trouble: str | None = None
    """The first of those failures (``Type: message``)."""
    success_reported: int | None = None
    """How many ended episodes' final infos said anything about success (0: no such signal)."""
    dropped: str | None = None
    """A recovery's account of what it dropped, in words."""
    cut_off_episodes: frozenset[int] = frozenset()
    """The episodes a recovery found cut off by the torn end."""
    damaged_stretches: int = 0
    """How many damaged stretches of the original file a recovery skipped."""
    damaged_episodes: EpisodeRanges = field(default_factory=EpisodeRanges)
    """The episodes that lost part or all of their evidence in those stretches."""
    lost_steps: int = 0
    """The step rows the recorder dropped: flushes the OS refused (a full disk), not retried."""
    lost_resets: int = 0
    """The reset rows the recorder dropped so."""
    lost_episode_records: int = 0
    """The episode records (starts and ends) the recorder dropped so."""

    @property
    def lost(self) -> str | None:
        """What the recorder dropped, in words (``None``: nothing).

        >>> RunEnd.of({"recorder_lost_steps": "600", "recorder_lost_episode_records": "1"}).lost
        '600 step rows and 1 episode record'
        """
        counts = (
            (self.lost_steps, "step row"),
            (self.lost_resets, "reset row"),
            (self.lost_episode_records, "episode record"),
        )
        parts = [f"{n} {what}{'' if n == 1 else 's'}" for n, what in counts if n]
        if not parts:
            return None
        return parts[0] if len(parts) == 1 else f"{', '.join(parts[:-1])} and {parts[-1]}"

    @property
    def recovered(self) -> bool:
        """Whether ``episode-audit recover`` wrote the file."""
        return self.status == fmt.RUN_STATUS_RECOVERED

    @classmethod
    def of(cls, record: Mapping[str, str] | None) -> RunEnd:
        """Read a run-end record's values (``None``: the file has none, or it is garbled).

        A count that is not a whole number of digits is not said (``troubles``: a record
        that names trouble without a readable count says it happened once at least).
        """
        if not record:
            return cls()
        get = record.get
        troubles = get(fmt.RUN_END_TROUBLE)
        damaged = _json_value(get("damaged"), "damaged")
        cut_off = _json_value(get("cut_off_episodes"), "cut_off_episodes")
        return cls(
            status=_text(get("status")),
            episodes=_count(get("episodes")),
            steps=_count(get("steps")),
            troubles=_count(troubles) or (1 if troubles else 0),
            first_trouble=_text(get(fmt.RUN_END_FIRST_TROUBLE)),
            success_reported=_count(get(fmt.RUN_END_SUCCESS_REPORTED)),
            dropped=_text(get("dropped")),
            cut_off_episodes=frozenset(
                e for e in (cut_off if isinstance(cut_off, list) else []) if type(e) is int
            ),
            damaged_stretches=len(damaged) if isinstance(damaged, list) else 0,
            damaged_episodes=EpisodeRanges.from_json(_text(get("damaged_episodes"))),
            lost_steps=_count(get(fmt.RUN_END_LOST_STEPS)) or 0,
            lost_resets=_count(get(fmt.RUN_END_LOST_RESETS)) or 0,
            lost_episode_records=_count(get(fmt.RUN_END_LOST_EPISODES)) or 0,
        )


def _text(value: Any) -> str | None:
    return value if isinstance(value, str) and value else None


def _count(value: Any) -> int | None:
    """A count written as digits (``"12"``); ``None`` for anything else."""
    return int(value) if isinstance(value, str) and value.isascii() and value.isdigit() else None


def _json_value(value: Any, key: str) -> Any:
    """A value written as JSON, parsed within the reader's bounds; ``None`` if it does not."""
    if not isinstance(value, str) or not value:
        return None
    try:
        return from_json(value, key)
    except ValueError:
        return None
