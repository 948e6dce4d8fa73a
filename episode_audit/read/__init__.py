"""The read wing: open evidence files (finished or torn) as Arrow tables.

Public: :func:`open_evidence`, :class:`Evidence`, :class:`EpisodeEvidence`,
:class:`ChunkContents`, :data:`EPISODE_COLUMNS`; a command's inputs: :func:`evidence_files`,
:func:`open_all`, :class:`Unreadable`, :func:`steps_total`; for recovery, :func:`iter_records`
and its items, :func:`summary_definitions` and :func:`step_block_rows`.

Modules, lowest first: ``layout`` (the MCAP record layout), ``chunks`` (reading, decompressing
and splitting chunks; read-ahead), ``blocks`` (one Arrow block, checked), ``passes`` (the chunk
loop, what a pass keeps), ``episodes`` (the episodes table), ``episode_tables`` and
``evidence`` (the API: resets, episodes and single episodes; passes and steps), ``opening``
(indexed and linear opening), ``records`` (recovery's record walk), ``inputs``;
``arguments`` (the API's path, column-name and episode arguments, checked) sits under all;
``storage`` (URLs through fsspec) sits under ``chunks``.
"""

from .blocks import step_block_rows
from .chunks import RECOVER_HINT
from .episode_tables import EpisodeEvidence
from .episodes import EPISODE_COLUMNS
from .evidence import ChunkContents, Evidence
from .inputs import Unreadable, evidence_files, open_all, skipped, steps_total
from .opening import open_evidence
from .records import ChunkRecords, DamagedRegion, FileEnd, iter_records, summary_definitions

__all__ = [
    "RECOVER_HINT",
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
    "skipped",
    "step_block_rows",
    "steps_total",
    "summary_definitions",
]
