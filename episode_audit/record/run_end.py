"""The run-end record an evidence file ends with: what it holds, and the recorder's trouble."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Protocol

from ..format import names as fmt
from ..format.columns import text
from .episode_records import EpisodeRecords
from .stream import Stream
from .writer import EvidenceWriter

__all__ = ["run_end_record"]


class _File(Protocol):
    """What the record is made of (an :class:`~.file.EvidenceFile`'s)."""

    @property
    def writer(self) -> EvidenceWriter: ...
    @property
    def streams(self) -> Sequence[Stream]: ...
    @property
    def records(self) -> EpisodeRecords: ...
    @property
    def counts(self) -> dict[str, int]: ...
    @property
    def troubles(self) -> int: ...
    @property
    def first_trouble(self) -> str | None: ...


def run_end_record(file: _File) -> dict[str, str]:
    """The run-end record: counts of what is in the file, and the recorder's trouble."""
    lost, lost_messages = file.writer.lost, file.writer.lost_messages
    steps = sum(lost[s.channels.steps] for s in file.streams)
    resets = sum(lost[s.channels.resets] for s in file.streams)
    blocks = sum(lost_messages[s.channels.steps] for s in file.streams)
    run_end = {
        "status": "finished",
        "episodes": str(file.counts["episodes"]),
        "steps": str(file.counts["steps"] - steps),
        "blocks": str(file.counts["blocks"] - blocks),
        "end_time": datetime.now(timezone.utc).isoformat(),
        fmt.RUN_END_SUCCESS_REPORTED: str(file.counts["success_reported"]),
    }
    if file.troubles:
        run_end[fmt.RUN_END_TROUBLE] = str(file.troubles)
        run_end[fmt.RUN_END_FIRST_TROUBLE] = text(file.first_trouble or "")
    episodes = lost[file.records.block_channel]
    if steps or resets or episodes:
        run_end[fmt.RUN_END_LOST_STEPS] = str(steps)
        run_end[fmt.RUN_END_LOST_RESETS] = str(resets)
        run_end[fmt.RUN_END_LOST_EPISODES] = str(episodes)
    return run_end
