"""``episode-audit export``: steps and episodes as Parquet."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ..read.inputs import steps_total
from ._app import (
    EXIT_USAGE,
    PathsArgument,
    _error_line,
    _readable,
    _stderr,
    app,
    collect,
    emit,
    fail,
    progress_bar,
)
from .render import safe


@app.command()
def export(
    paths: PathsArgument,
    out: Annotated[Path, typer.Option("--out", "-o", help="Directory for the Parquet files.")],
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Replace the export in --out (its *.steps.parquet files this export does not "
            "write are removed).",
        ),
    ] = False,
) -> None:
    """Write steps and episodes as Parquet (pandas / polars / DuckDB), with a file column."""
    from ..export import export as run_export

    readable, skipped = _readable(collect(paths))
    if not readable:
        raise typer.Exit(EXIT_USAGE)
    files = [path for path, _ in readable]
    try:
        with progress_bar("exporting", steps_total(files)) as advance:
            result = run_export(
                files, out, overwrite=overwrite, progress=advance, on_error=_error_line
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    unreadable = len(skipped) + len(result.failed)
    for path, ev in readable:
        if not ev.finished and path not in result.failed:
            why = ev.torn or "no run-end record"
            _stderr().print(
                f"episode-audit: note: {safe(str(path))} is unfinished ({safe(why)}): "
                "exported what it holds, its cut-off episode as incomplete",
                markup=False,
                soft_wrap=True,
            )
    removed = f"; removed {len(result.removed)} from an earlier export" if result.removed else ""
    emit(
        f"wrote {result.episodes} episodes to {result.episodes_file} and {result.steps} steps "
        f"to {len(result.steps_files)} *.steps.parquet file(s) in {out}{removed}"
    )
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
