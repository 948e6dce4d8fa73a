"""``episode-audit export``: steps and episodes as Parquet."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ..read.inputs import steps_total
from ._app import (
    EXIT_USAGE,
    JobsOption,
    PathsArgument,
    RayOption,
    _error_line,
    _readable,
    app,
    collect,
    emit,
    fail,
    interruptible,
    jobs_for,
    note,
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
    jobs: JobsOption = None,
    ray: RayOption = None,
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
        total = partial(steps_total, files)
        with interruptible(), progress_bar("exporting", total) as advance:
            result = run_export(
                files,
                out,
                overwrite=overwrite,
                progress=advance,
                on_error=_error_line,
                jobs=jobs_for(jobs, files),
                ray_address=ray,
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    for line in result.notes:
        note(line)
    emit(safe(result.summary()))
    if unreadable or result.failed:
        raise typer.Exit(EXIT_USAGE)
