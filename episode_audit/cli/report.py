"""``episode-audit report``: rates side by side, term breakdown, warnings and gates."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ..read.inputs import evidence_files
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    FormatOption,
    JobsOption,
    PathsArgument,
    RayOption,
    _error_line,
    _format,
    app,
    emit,
    fail,
    interruptible,
    jobs_for,
    warn,
)


@app.command()
def report(
    paths: PathsArgument,
    by: Annotated[
        str,
        typer.Option(
            help="Group by: file, env, env_index, agent, label, all, or tag:NAME (e.g. tag:policy)."
        ),
    ] = "file",
    games: Annotated[
        bool,
        typer.Option(
            "--games",
            help="PettingZoo files: count whole games (outcome derived from the agents') "
            "instead of agent-episodes.",
        ),
    ] = False,
    min_success_rate: Annotated[
        float | None, typer.Option(help="Gate: fail (exit 1) if a group's success rate is lower.")
    ] = None,
    max_failure_rate: Annotated[
        list[str] | None,
        typer.Option(
            help="Gate: RATE overall, or LABEL=RATE for one failure label (repeatable).",
            metavar="<[label=]rate>",
        ),
    ] = None,
    max_truncation_rate: Annotated[
        float | None, typer.Option(help="Gate: fail if a group's truncation rate is higher.")
    ] = None,
    max_error_rate: Annotated[
        float | None,
        typer.Option(
            help="Gate: fail if a group's error rate (episodes whose env raised, of all its "
            "episodes; the other rates leave them out) is higher."
        ),
    ] = None,
    fail_on_incentive_warning: Annotated[
        bool,
        typer.Option("--fail-on-incentive-warning", help="Gate: fail on any incentive warning."),
    ] = False,
    output: FormatOption = "table",
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Success / failure / truncation rates side by side, term breakdown, warnings, gates."""
    from ..report.inputs import report_inputs
    from .render import report_output

    fmt = _format(output)
    try:
        with interruptible():
            result = report_inputs(
                paths,
                by=by,
                games=games,
                min_success_rate=min_success_rate,
                max_failure_rate=max_failure_rate or (),
                max_truncation_rate=max_truncation_rate,
                max_error_rate=max_error_rate,
                fail_on_incentive_warning=fail_on_incentive_warning,
                on_error=_error_line,
                jobs=_jobs(jobs, paths),
                ray_address=ray,
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    if not result.readable and fmt != "json":  # (JSON is still one document: its unreadable list)
        raise typer.Exit(EXIT_USAGE)
    emit(report_output(result.report, fmt, unreadable=result.unreadable))
    for line in result.report.notes:
        warn(line)
    if result.unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not result.report.passed:
        raise typer.Exit(EXIT_FINDINGS)


def _jobs(jobs: int | None, paths: list[Path]) -> int | None:
    """``--jobs`` for ``paths`` (a path that cannot be listed: the report says so itself)."""
    if jobs is not None:
        return jobs
    try:
        return jobs_for(jobs, evidence_files(paths))
    except EpisodeAuditError:
        return None
