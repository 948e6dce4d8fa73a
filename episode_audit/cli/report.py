"""``episode-audit report``: rates side by side, term breakdown, warnings and gates."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    FormatOption,
    PathsArgument,
    _format,
    _readable,
    _stderr,
    app,
    collect,
    emit,
    fail,
)
from .render import safe


def _parse_failure_rates(values: Sequence[str]) -> tuple[float | None, dict[str, float]]:
    overall: float | None = None
    by_label: dict[str, float] = {}
    for value in values:
        label, sep, rate = value.rpartition("=")
        try:
            number = float(rate)
        except ValueError:
            fail(f"--max-failure-rate: expected RATE or LABEL=RATE, got {value!r}")
        if not 0.0 <= number <= 1.0:
            fail(f"--max-failure-rate: expected a rate between 0 and 1, got {rate!r}")
        if sep and not label:
            fail(f"--max-failure-rate: expected RATE or LABEL=RATE, got {value!r} (no label)")
        if sep:
            by_label[label] = number
        else:
            overall = number
    return overall, by_label


def _rate_option(name: str, value: float | None) -> float | None:
    if value is not None and not 0.0 <= value <= 1.0:
        fail(f"{name}: expected a rate between 0 and 1, got {value}")
    return value


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
) -> None:
    """Success / failure / truncation rates side by side, term breakdown, warnings, gates."""
    from ..read import Evidence
    from ..report.core import BY_KEYS, Gates, report_tables
    from .render import report_output

    fmt = _format(output)
    if by not in BY_KEYS and not (by.startswith("tag:") and len(by) > 4):
        fail(f"--by: expected file, env, env_index, agent, label, all or tag:NAME, got {by!r}")
    if games and by == "agent":
        fail("--games cannot be grouped --by agent: a game has many agents")
    overall, by_label = _parse_failure_rates(max_failure_rate or [])
    gates = Gates(
        min_success_rate=_rate_option("--min-success-rate", min_success_rate),
        max_failure_rate=overall,
        max_failure_rate_by_label=by_label,
        max_truncation_rate=_rate_option("--max-truncation-rate", max_truncation_rate),
        max_error_rate=_rate_option("--max-error-rate", max_error_rate),
        fail_on_incentive_warning=fail_on_incentive_warning,
    )
    # Reading each file's episodes here (they are cached) puts a file damaged past its start
    # with the unreadable ones instead of stopping the report of the others.
    readable, unreadable = _readable(collect(paths), Evidence.episodes)
    if not readable and fmt != "json":  # (JSON is still one document: its unreadable list)
        raise typer.Exit(EXIT_USAGE)
    if games:  # a file without games would count nothing, and every gate would pass
        for path, ev in readable:
            kind = str((ev.run.layout or {}).get("kind", "single"))
            if not kind.startswith("pettingzoo"):
                what = "single-env" if kind == "single" else kind
                fail(f"--games counts PettingZoo games; {path} is a {what} file (drop --games)")
    try:
        result = report_tables(
            [(str(path), ev) for path, ev in readable], by=by, gates=gates, games=games
        )
    except EpisodeAuditError as exc:
        fail(str(exc))
    emit(report_output(result, fmt, unreadable=unreadable))
    for line in result.notes:
        _stderr().print(f"episode-audit: warning: {safe(line)}", markup=False, soft_wrap=True)
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not result.passed:
        raise typer.Exit(EXIT_FINDINGS)
