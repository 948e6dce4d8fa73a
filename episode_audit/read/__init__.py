"""The read wing: open evidence files (finished or torn) as Arrow tables.

Public: :func:`open_evidence`, :class:`Evidence`, :class:`EpisodeEvidence`,
:data:`EPISODE_COLUMNS`; a command's inputs: :func:`evidence_files`, :func:`open_all`,
:class:`Unreadable`, :func:`steps_total`; for recovery, :func:`iter_records` and its items.
"""

from .inputs import Unreadable, evidence_files, open_all, steps_total
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
    "Unreadable",
    "evidence_files",
    "iter_records",
    "open_all",
    "open_evidence",
    "steps_total",
    "summary_definitions",
]
