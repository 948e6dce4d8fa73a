"""``episode-audit check``: integrity and consistency findings, exit 1 on errors."""

from __future__ import annotations

from functools import partial
from typing import Annotated

import typer

from ..errors import ConfigurationError, EpisodeAuditError
from ..read.inputs import steps_total
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    CIFormatOption,
    DocumentedCommand,
    JobsOption,
    PathsArgument,
    RayOption,
    _error_line,
    _format,
    app,
    collect,
    emit,
    fail,
    failure_document,
    interruptible,
    jobs_for,
    progress_bar,
    warn,
)
from ._summary import NoStepSummaryOption, append_step_summary


@app.command(cls=DocumentedCommand)
def check(
    paths: PathsArgument,
    atol: Annotated[
        float,
        typer.Option(help="Absolute tolerance of the terms-sum check.", metavar="<tolerance>"),
    ] = 1e-6,
    rtol: Annotated[
        float,
        typer.Option(
            help="Relative tolerance (times |reward|) of the terms-sum check.",
            metavar="<tolerance>",
        ),
    ] = 1e-6,
    require_terms: Annotated[
        bool, typer.Option("--require-terms", help="Steps without reward terms are errors.")
    ] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Warnings also fail (exit 1).")] = False,
    ignore: Annotated[
        list[str] | None,
        typer.Option(
            "--ignore",
            help="Leave out findings with this code, from the output and the exit code "
            "(repeatable; recorder_note ignores every recorder note).",
            metavar="<code>",
        ),
    ] = None,
    group: Annotated[
        bool | None,
        typer.Option(
            "--group/--no-group",
            help="Show the findings of a code as one entry: its counts and the first places "
            "(default: the codes found in more than 5 files; table and Markdown only).",
            show_default=False,
        ),
    ] = None,
    output: CIFormatOption = "table",
    no_step_summary: NoStepSummaryOption = False,
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Check integrity and consistency: terms sum to reward, endings labelled, nothing missing."""
    from ..check import check as run_check
    from ..check import ignored_codes
    from .render import check_output

    fmt = _format(output, junit=True)
    with failure_document("check", fmt):
        try:
            ignored = ignored_codes(ignore or (), option="--ignore")
        except ConfigurationError as exc:
            fail(str(exc))
        files = collect(paths)
        total = partial(steps_total, files)
        with interruptible(), progress_bar("checking", total) as advance:
            try:
                result = run_check(
                    files,
                    atol=atol,
                    rtol=rtol,
                    require_terms=require_terms,
                    ignore=ignored,
                    progress=advance,
                    keep_going=True,
                    on_error=_error_line,
                    jobs=jobs_for(jobs, files),
                    ray_address=ray,
                )
            except EpisodeAuditError as exc:  # (a setting; a worker that ended: WorkerError)
                fail(str(exc))
        for code, left_out in result.ignored_by.items():
            if not left_out:
                warn(f"--ignore {code}: no finding has this code (misspelt?); nothing left out")
        emit(check_output(result, fmt, strict=strict, ignored=ignored, group=group))
        append_step_summary(
            lambda: str(check_output(result, "markdown", group=group)), off=no_step_summary
        )
        if result.unreadable:
            raise typer.Exit(EXIT_USAGE)
        if result.errors or (strict and result.warnings):
            raise typer.Exit(EXIT_FINDINGS)
