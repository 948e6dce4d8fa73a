"""``episode-audit recover``: rewrite a torn or damaged file as a finished one."""

from __future__ import annotations

from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ._app import EXIT_FINDINGS, app, existing, fail, interruptible, said


@app.command()
def recover(
    path: Annotated[
        str,
        typer.Argument(
            help="A torn evidence file (left by a killed recorder) or a damaged one; or its URL.",
            metavar="FILE",
        ),
    ],
    out: Annotated[
        str,
        typer.Option(
            "--out", "-o", help="The finished file to write (a path or a URL).", metavar="<file>"
        ),
    ],
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Replace an existing output file (never the input).")
    ] = False,
) -> None:
    """Rewrite a torn or damaged file as a finished, indexed one.

    Every complete, intact chunk is kept; damaged chunks are skipped and the episodes that lost
    evidence named. Exit 1 if anything was or may have been lost.
    """
    from ..recover import recover as run_recover

    existing(path, "recover")
    if not out:  # (an empty path is the current folder)
        fail("--out: expected a path, got an empty string")
    with interruptible():  # (a URL's recovery downloads into a temporary folder)
        try:
            result = run_recover(path, out, overwrite=overwrite, overwrite_option="--overwrite")
        except EpisodeAuditError as exc:
            fail(str(exc))
    said(result.summary(), [result.source, result.output])
    if result.lost:
        raise typer.Exit(EXIT_FINDINGS)
