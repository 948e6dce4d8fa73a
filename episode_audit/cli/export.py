"""``episode-audit export``: steps and episodes as Parquet."""

from __future__ import annotations

from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ..read.inputs import steps_total
from ._app import (
    EXIT_USAGE,
    PathsArgument,
    _error_line,
    _readable,
    app,
    collect,
    emit,
    fail,
    note,
    progress_bar,
)
from .render import safe


@app.command()
def export(
    paths: PathsArgument,
    out: Annotated[
        str,
        typer.Option(
            "--out", "-o", help="Directory for the Parquet files (or a URL prefix: s3://b/p)."
        ),
    ],
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

    # The inputs are opened first, so that one that cannot be is named before any output is
    # written, takes no output name, and the progress bar counts the others' steps.
    readable, unreadable = _readable(collect(paths))
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
    for line in result.notes:
        note(line)
    emit(safe(result.summary()))
    if unreadable or result.failed:
        raise typer.Exit(EXIT_USAGE)
