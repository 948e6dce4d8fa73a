"""Export evidence for other tools: Parquet tables, Foxglove MCAP, Rerun recordings.

:func:`export` picks the target by ``to``: ``"parquet"`` (:mod:`.parquet`: a directory of
tables for pandas / polars / DuckDB), ``"foxglove"`` (:mod:`.foxglove`: one viewer-ready MCAP
file) or ``"rerun"`` (:mod:`.rerun`: one ``.rrd`` recording). Viewers: ``docs/viewers.md``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Final, Literal, overload

from ..errors import ConfigurationError, EvidenceError
from ..format.paths import path_argument
from ..read.arguments import path_list
from ._output import ViewerExport, local_file
from .parquet import ExportResult
from .parquet import export as _export_parquet

__all__ = ["TARGETS", "ExportResult", "ViewerExport", "export", "viewer_output"]

TARGETS: Final = ("parquet", "foxglove", "rerun")
"""What :func:`export` writes, by its ``to``."""


def viewer_output(to: str, out: str | os.PathLike[str]) -> Path:
    """The local file ``to="foxglove"`` / ``to="rerun"`` writes for ``out``, or why not.

    A URL is refused (the viewer file is written locally: export, then copy), and so is an
    ``.mcap`` name for a Rerun recording (it would read as an evidence file).
    """
    path = local_file(out, to)
    if to == "rerun" and path.suffix.lower() == ".mcap":
        raise ConfigurationError(
            f"--out {out}: --to rerun writes an .rrd recording, not MCAP; name it "
            f"{path.with_suffix('.rrd').name} (an .mcap name reads as an evidence file to "
            "check, replay and report)"
        )
    return path


@overload
def export(
    paths: Iterable[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    to: Literal["parquet"] = "parquet",
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ExportResult: ...
@overload
def export(
    paths: Iterable[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    to: Literal["foxglove", "rerun"],
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ViewerExport: ...
@overload
def export(
    paths: Iterable[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    to: str,
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ExportResult | ViewerExport: ...
def export(
    paths: Iterable[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    to: str = "parquet",
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ExportResult | ViewerExport:
    """Export the evidence files ``paths`` to ``out``, as ``to`` says.

    ``to="parquet"`` (default): ``out`` is a directory, see :func:`.parquet.export`.
    ``to="foxglove"`` / ``to="rerun"``: ``out`` is the one file to write (an MCAP file for
    Foxglove, an ``.rrd`` recording for Rerun) from exactly one input; ``on_error`` is not used
    (an unreadable input raises :class:`~episode_audit.errors.EvidenceError`); the input may
    be a URL, ``out`` is a local path. An existing ``out`` is replaced only with
    ``overwrite=True``; a failed export leaves no ``out``. ``overwrite_option``: how the error
    for an existing output names that option (``--overwrite`` on the command line).
    ``jobs`` / ``ray_address`` (workers) are the Parquet export's (:func:`.parquet.export`);
    ``filesystem`` / ``storage_options`` reach URLs (``docs/storage.md``).
    """
    out = path_argument("out", out)
    if to == "parquet":
        return _export_parquet(
            paths,
            out,
            overwrite=overwrite,
            overwrite_option=overwrite_option,
            progress=progress,
            on_error=on_error,
            jobs=jobs,
            ray_address=ray_address,
            filesystem=filesystem,
            storage_options=storage_options,
        )
    if to not in TARGETS:
        raise ConfigurationError(f"--to: expected one of {', '.join(TARGETS)}, got {to!r}")
    viewer_output(to, out)
    sources = path_list(paths)
    if len(sources) != 1:
        raise ConfigurationError(
            f"--to {to}: writes one file from one input, got {len(sources)} inputs; "
            "export them one at a time"
        )
    if to == "foxglove":
        from .foxglove import export_foxglove as write
    else:
        from .rerun import export_rerun as write
    return write(
        sources[0],
        out,
        overwrite=overwrite,
        overwrite_option=overwrite_option,
        progress=progress,
        filesystem=filesystem,
        storage_options=storage_options,
    )
