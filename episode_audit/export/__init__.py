"""Export evidence for other tools: Parquet tables, Foxglove MCAP, Rerun recordings.

:func:`export` picks the target by ``to``: ``"parquet"`` (:mod:`.parquet`, a directory of
tables for pandas / polars / DuckDB), ``"foxglove"`` (:mod:`.foxglove`, one viewer-ready MCAP
file) or ``"rerun"`` (:mod:`.rerun`, one ``.rrd`` file). Viewers: ``docs/viewers.md``.
"""

from __future__ import annotations

from .parquet import ExportResult, export

__all__ = ["ExportResult", "export"]
