"""``episode-audit report``: rates side by side, term breakdown, warnings and gates."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ..errors import EpisodeAuditError
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
    emit,
    exports_note,
    fail,
    failure_document,
    interruptible,
    listed_count,
    listed_jobs,
    lister,
    note,
    progress_bar,
    warn,
)
from ._summary import NoStepSummaryOption, append_step_summary

if TYPE_CHECKING:
    from ..report.inputs import InputsReport


_ByOption = Annotated[
    str,
    typer.Option(
        help="Group by: file, env, env_index, agent, label, all, or tag:NAME (e.g. tag:policy).",
        metavar="<grouping>",
    ),
]

_GamesOption = Annotated[
    bool,
    typer.Option(
        "--games",
        help="PettingZoo files: count whole games (outcome derived from the agents') "
        "instead of agent-episodes.",
    ),
]

_MinSuccessRateOption = Annotated[
    float | None,
    typer.Option(help="Gate: fail (exit 1) if a group's success rate is lower.", metavar="<rate>"),
]

_MaxFailureRateOption = Annotated[
    list[str] | None,
    typer.Option(
        help="Gate: RATE overall, or LABEL=RATE for one failure label (repeatable).",
        metavar="<[label=]rate>",
    ),
]

_MaxTruncationRateOption = Annotated[
    float | None,
    typer.Option(help="Gate: fail if a group's truncation rate is higher.", metavar="<rate>"),
]

_MaxErrorRateOption = Annotated[
    float | None,
    typer.Option(
        help="Gate: fail if a group's error rate (episodes whose env raised, of all its "
        "episodes; the other rates leave them out) is higher.",
        metavar="<rate>",
    ),
]

_FailOnIncentiveWarningOption = Annotated[
    bool,
    typer.Option("--fail-on-incentive-warning", help="Gate: fail on any incentive warning."),
]

_HtmlOption = Annotated[
    Path | None,
    typer.Option(
        "--html",
        help="Also write the report as one self-contained HTML page (charts, episodes "
        "with their replay commands) to this file.",
        metavar="<file.html>",
    ),
]


@app.command(cls=DocumentedCommand)
def report(
    paths: PathsArgument,
    by: _ByOption = "file",
    games: _GamesOption = False,
    min_success_rate: _MinSuccessRateOption = None,
    max_failure_rate: _MaxFailureRateOption = None,
    max_truncation_rate: _MaxTruncationRateOption = None,
    max_error_rate: _MaxErrorRateOption = None,
    fail_on_incentive_warning: _FailOnIncentiveWarningOption = False,
    output: CIFormatOption = "table",
    no_step_summary: NoStepSummaryOption = False,
    html: _HtmlOption = None,
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Success / failure / truncation rates side by side, term breakdown, warnings, gates."""
    from ..report.inputs import report_inputs
    from .render import report_output

    fmt = _format(output, junit=True)
    with failure_document("report", fmt):
        if html is not None:  # (before the work: a path it would refuse after)
            from ..report.html import check_html_path

            try:
                check_html_path(html, paths)
            except EpisodeAuditError as exc:
                fail(str(exc))
        try:
            files = lister(paths)
            with interruptible(), progress_bar("reading", partial(listed_count, files)) as advance:
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
                    jobs=listed_jobs(jobs, files),
                    ray_address=ray,
                    progress=advance,
                )
        except EpisodeAuditError as exc:
            fail(str(exc))
        exports_note(result.exports)
        if not result.readable and fmt not in ("json", "junit"):  # (still one document: the errors)
            raise typer.Exit(EXIT_USAGE)
        emit(report_output(result.report, fmt, unreadable=result.unreadable))
        if html is not None:
            _write_html(result, html, games)
        if result.readable:
            markdown = lambda: str(  # noqa: E731
                report_output(result.report, "markdown", unreadable=result.unreadable)
            )
            append_step_summary(markdown, off=no_step_summary)
        for line in result.report.notes:
            warn(line)
        if result.unreadable:
            raise typer.Exit(EXIT_USAGE)
        if not result.report.passed:
            raise typer.Exit(EXIT_FINDINGS)


def _write_html(result: InputsReport, path: Path, games: bool) -> None:
    """Write the HTML report and say where on stderr (stdout keeps its format)."""
    from ..report.html import write_report_html

    try:
        written = write_report_html(result.report, result.parts, path, games=games)
    except EpisodeAuditError as exc:
        fail(str(exc))
    except OSError as exc:  # no such directory, permission denied
        fail(f"--html: cannot write {path}: {exc.strerror or exc}")
    note(f"HTML report written to {written}")
