"""``episode-audit check``: integrity and consistency findings, exit 1 on errors."""

from __future__ import annotations

from typing import Annotated

import typer

from ..errors import ConfigurationError, EpisodeAuditError
from ..read.inputs import Unreadable, steps_total
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    FormatOption,
    PathsArgument,
    _format,
    _unreadable,
    app,
    collect,
    emit,
    fail,
    progress_bar,
)


@app.command()
def check(
    paths: PathsArgument,
    atol: Annotated[float, typer.Option(help="Absolute tolerance of the terms-sum check.")] = 1e-6,
    rtol: Annotated[
        float, typer.Option(help="Relative tolerance (times |reward|) of the terms-sum check.")
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
    output: FormatOption = "table",
) -> None:
    """Check integrity and consistency: terms sum to reward, endings labelled, nothing missing."""
    from ..check.core import FILE_UNREADABLE, CheckResult, Finding, ignored_codes, is_ignored
    from ..check.core import check as run_check
    from .render import check_output

    fmt = _format(output)
    try:
        ignored = ignored_codes(ignore or (), option="--ignore")
    except ConfigurationError as exc:
        fail(str(exc))
    files = collect(paths)
    merged = CheckResult(findings=[], files=[], episodes=0, steps=0)
    unreadable: list[Unreadable] = []
    with progress_bar("checking", steps_total(files)) as advance:
        for path in files:
            try:
                result = run_check(
                    [path],
                    atol=atol,
                    rtol=rtol,
                    require_terms=require_terms,
                    ignore=ignored,
                    progress=advance,
                )
            except ConfigurationError as exc:
                fail(str(exc))
            except EpisodeAuditError as exc:
                _unreadable(path, exc, unreadable)
                # in the result too, so a JSON consumer does not read "ok" over a skipped file
                if is_ignored(FILE_UNREADABLE, ignored):
                    merged.ignored += 1
                else:
                    merged.findings.append(
                        Finding("error", FILE_UNREADABLE, str(exc), str(path), None, None)
                    )
                merged.files.append(str(path))
                continue
            merged.findings.extend(result.findings)
            merged.files.extend(result.files)
            merged.episodes += result.episodes
            merged.steps += result.steps
            merged.ignored += result.ignored
    emit(check_output(merged, fmt, unreadable=unreadable))
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if merged.errors or (strict and merged.warnings):
        raise typer.Exit(EXIT_FINDINGS)
