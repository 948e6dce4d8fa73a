"""``episode-audit compare``: whether the candidate regressed against the baseline."""

from __future__ import annotations

from functools import partial
from typing import Annotated, Any

import typer
from typer.core import TyperCommand

from ..errors import EpisodeAuditError
from ..read.inputs import Unreadable
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    CIFormatOption,
    DocumentedCommand,
    JobsOption,
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
    progress_bar,
    warn,
)
from ._summary import NoStepSummaryOption, append_step_summary

_BaselineArgument = Annotated[
    list[str],
    typer.Argument(
        help="The baseline's evidence files, or directories searched for *.mcap; or URLs "
        "(s3://, gs://, az://, https://). Given first; the candidate's follow --candidate.",
        metavar="BASELINE",
    ),
]

_CandidateOption = Annotated[
    list[str],
    typer.Option(
        "--candidate",
        help="The candidate's evidence files or directories (repeatable).",
        metavar="<file|dir>",
    ),
]

_ByOption = Annotated[
    str,
    typer.Option(
        help="Group both sides by: all, env, env_index, agent or tag:NAME; groups of the "
        "same key are compared.",
        metavar="<key>",
    ),
]

_MaxSuccessDropOption = Annotated[
    float | None,
    typer.Option(
        help="Gate: fail (exit 1) unless the success rate's drop is within this.",
        metavar="<rate>",
    ),
]

_MaxFailureIncreaseOption = Annotated[
    list[str] | None,
    typer.Option(
        help="Gate: RATE for all failures, or LABEL=RATE for one label (repeatable): fail "
        "unless the rise is within it.",
        metavar="<[label=]rate>",
    ),
]

_MaxReturnDropOption = Annotated[
    float | None,
    typer.Option(
        help="Gate: fail unless the mean return's drop is within this.", metavar="<amount>"
    ),
]

_MaxErrorIncreaseOption = Annotated[
    float | None,
    typer.Option(
        help="Gate: fail unless the error rate's rise (episodes the env raised in, of all "
        "episodes) is within this.",
        metavar="<rate>",
    ),
]

_RateMarginOption = Annotated[
    float,
    typer.Option(
        help="A rate without a gate is 'held' when its change is within this.",
        metavar="<rate>",
    ),
]

_FailOnNewWarningOption = Annotated[
    bool,
    typer.Option(
        "--fail-on-new-incentive-warning",
        help="Gate: fail on an incentive warning the baseline lacks (untested: may be chance).",
    ),
]

_DifferentTasksOption = Annotated[
    bool,
    typer.Option("--different-tasks", help="Compare even though the sides' env ids differ."),
]


class _CompareCommand(DocumentedCommand):
    """``compare``, refusing a BASELINE path after ``--candidate`` (exit 2).

    ``--candidate`` takes one path each time, so after ``--candidate runs/c-*.mcap`` the shell
    glob's other matches would be BASELINE paths, compared as the baseline, and nothing said.
    """

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        late = _after_candidate(self, args)
        if late:
            self.refuse(
                args,
                f"{late[0]} comes after --candidate, where it would be a BASELINE path: "
                "--candidate takes one path each time (a shell glob after it leaves all its "
                "matches but the first in the baseline); put BASELINE paths first, then "
                "--candidate before each candidate file, or --candidate with their directory",
            )
        return super().parse_args(ctx, args)


def _after_candidate(command: TyperCommand, args: list[str]) -> list[str]:
    """The positional arguments (BASELINE paths) that come after a ``--candidate``."""
    takes_value = {
        name
        for p in command.params
        if p.param_type_name == "option"
        and not (getattr(p, "is_flag", False) or getattr(p, "count", False))
        for name in p.opts
    }
    seen, late = False, []
    tokens: Any = iter(args)
    for token in tokens:
        if token == "--":
            late += list(tokens) if seen else []
            break
        if token.startswith("-") and token != "-":
            name = token.split("=", 1)[0]
            seen = seen or name == "--candidate"
            if name in takes_value and "=" not in token:
                next(tokens, None)
        elif seen:
            late.append(token)
    return late


@app.command(cls=_CompareCommand)
def compare(
    baseline: _BaselineArgument,
    candidate: _CandidateOption,
    by: _ByOption = "all",
    max_success_drop: _MaxSuccessDropOption = None,
    max_failure_increase: _MaxFailureIncreaseOption = None,
    max_return_drop: _MaxReturnDropOption = None,
    max_error_increase: _MaxErrorIncreaseOption = None,
    rate_margin: _RateMarginOption = 0.05,
    fail_on_new_incentive_warning: _FailOnNewWarningOption = False,
    different_tasks: _DifferentTasksOption = False,
    output: CIFormatOption = "table",
    no_step_summary: NoStepSummaryOption = False,
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Did the candidate regress? Paired on matched seeds, per-metric verdicts, CI gates.

    \b
    Each metric, each group and the whole comparison get a verdict:
      regressed     significantly worse (Holm-adjusted p < 0.05): exit 1
      improved      significantly better
      held          the interval's worse end is within the margin or gate
      underpowered  neither, and too few episodes: see "n needed"
      inconclusive  neither: not compared, or more episodes would not tell
    Exit 1 also when a gate fails; exit 0 otherwise (2: usage or input).
    Statistics and verdicts: compare.md in the project's docs.
    """  # noqa: D301 (\b: Click keeps the lines of the paragraph that follows as they are)
    from ..compare import compare_inputs
    from .render.compare import compare_output

    fmt = _format(output, junit=True)
    unread: list[Unreadable] = []

    def told(exc: EpisodeAuditError) -> None:
        _error_line(exc)
        unread.append(Unreadable.of(getattr(exc, "path", ""), exc))

    files = lister([*baseline, *candidate])
    with (
        failure_document("compare", fmt, unread),
        interruptible(),
        progress_bar("reading", partial(listed_count, files)) as advance,
    ):
        try:
            result = compare_inputs(
                baseline,
                candidate,
                by=by,
                max_success_drop=max_success_drop,
                max_failure_increase=max_failure_increase or (),
                max_return_drop=max_return_drop,
                max_error_increase=max_error_increase,
                rate_margin=rate_margin,
                fail_on_new_incentive_warning=fail_on_new_incentive_warning,
                different_tasks=different_tasks,
                on_error=told,
                jobs=listed_jobs(jobs, files),
                ray_address=ray,
                progress=advance,
            )
        except EpisodeAuditError as exc:
            fail(str(exc))
    comparison = result.comparison
    exports_note(result.exports)
    for mismatch in comparison.mismatches:
        warn(str(mismatch))
    for name, why in comparison.unfinished:
        warn(f"{name}: unfinished ({why}): compared with the episodes it holds so far")
    emit(compare_output(comparison, fmt, unreadable=result.unreadable))
    for line in comparison.notes:
        warn(line)
    markdown = lambda: str(  # noqa: E731
        compare_output(comparison, "markdown", unreadable=result.unreadable)
    )
    append_step_summary(markdown, off=no_step_summary)
    if result.unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not comparison.passed:
        raise typer.Exit(EXIT_FINDINGS)
