"""The run-end record an evidence file ends with: what it holds, and the recorder's trouble."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import TYPE_CHECKING

from ..format import names as fmt
from ..format.columns import text

if TYPE_CHECKING:
    from .file import EvidenceFile

__all__ = ["run_end_record"]


def run_end_record(file: EvidenceFile) -> dict[str, str]:
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
