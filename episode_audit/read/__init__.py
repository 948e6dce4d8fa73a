"""The read wing: open evidence files (finished or torn) as Arrow tables.

Public: :func:`open_evidence`, :class:`Evidence`, :class:`EpisodeEvidence`,
:data:`EPISODE_COLUMNS`; for recovery, :func:`iter_records` and its items.
"""

from .reader import (
    EPISODE_COLUMNS,
    ChunkContents,
    ChunkRecords,
    DamagedRegion,
    EpisodeEvidence,
    Evidence,
    FileEnd,
    iter_records,
    open_evidence,
    summary_definitions,
)

__all__ = [
    "EPISODE_COLUMNS",
    "ChunkContents",
    "ChunkRecords",
    "DamagedRegion",
    "EpisodeEvidence",
    "Evidence",
    "FileEnd",
    "iter_records",
    "open_evidence",
    "summary_definitions",
]
