"""``episode-audit export``: steps and episodes as Parquet, or a file for Foxglove or Rerun."""

from __future__ import annotations

from functools import partial
from typing import Annotated, Literal, cast

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
    fail,
    interruptible,
    jobs_for,
    note,
    progress_bar,
    said,
)


@app.command()
def export(
    paths: PathsArgument,
    out: Annotated[
        str,
        typer.Option(
            "--out",
            "-o",
            help="Directory for the Parquet files (or a URL prefix: s3://b/p); with --to foxglove "
            "or rerun, the file to write.",
            metavar="<out>",
        ),
    ],
    to: Annotated[
        str,
        typer.Option(
            "--to",
            help="parquet (tables), foxglove (an MCAP file for Foxglove) or rerun (an .rrd "
            "recording for Rerun).",
            metavar="<target>",
        ),
    ] = "parquet",
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Replace the export in --out (its *.steps.parquet files this export does not "
            "write are removed); never an evidence file or a live recorder's.",
        ),
    ] = False,
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Write steps and episodes as Parquet (pandas / polars / DuckDB), or for a viewer.

    \b
    e.g. episode-audit export runs/ -o tables/
         episode-audit export run.mcap --to rerun -o run.rrd
         episode-audit export run.mcap --to foxglove -o run.foxglove.mcap
    and a layout for it (Foxglove: Layouts > Import from file…):
         python -m episode_audit.export.layout run.foxglove.mcap > layout.json
    """  # noqa: D301 (\b: Click keeps the lines of the paragraph that follows as they are)
    from ..export import TARGETS
    from ..export import export as run_export

    if to not in TARGETS:
        fail(f"--to: expected one of {', '.join(TARGETS)}, got {to!r}")
    if not out:  # (an empty path is the current folder)
        fail("--out: expected a path, got an empty string")
    if to != "parquet":
        _export_for_viewer(paths, out, to, overwrite)
        return

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
                overwrite_option="--overwrite",
                progress=advance,
                on_error=_error_line,
                jobs=jobs_for(jobs, files),
                ray_address=ray,
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    for line in result.notes:
        note(line)
    said(result.summary(), [result.episodes_file, result.episodes_file.parent])
    if unreadable or result.failed:
        raise typer.Exit(EXIT_USAGE)


def _export_for_viewer(paths: list[str], out: str, to: str, overwrite: bool) -> None:
    """``--to foxglove`` / ``--to rerun``: one input, one output file (a local one)."""
    from ..export import export as run_export
    from ..export import viewer_output

    try:
        target = viewer_output(to, out)  # (refused before the input is read)
    except EpisodeAuditError as exc:
        fail(str(exc))

    readable, unreadable = _readable(collect(paths))
    if unreadable or not readable:
        raise typer.Exit(EXIT_USAGE)
    files = [path for path, _ in readable]
    if len(files) != 1:
        fail(
            f"--to {to}: writes one file from one input, got {len(files)} inputs; "
            "export them one at a time"
        )
    try:
        with interruptible(), progress_bar("exporting", steps_total(files)) as advance:
            viewer = cast(Literal["foxglove", "rerun"], to)
            result = run_export(
                files,
                target,
                to=viewer,
                overwrite=overwrite,
                overwrite_option="--overwrite",
                progress=advance,
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    for line in result.notes:
        note(line)
    said(result.summary(), [result.source, result.path])
