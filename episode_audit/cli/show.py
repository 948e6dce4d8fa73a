"""``episode-audit show``: a file's summary, or one episode's steps."""

from __future__ import annotations

from typing import Annotated

import typer

from ..errors import EpisodeAuditError
from ._app import FormatOption, _episode_index, _format, app, emit, existing, fail


def _parse_slice(value: str | None) -> tuple[int | None, int | None]:
    if value is None:
        return None, None
    start, sep, stop = value.partition(":")
    try:
        a = int(start) if start else None
        b = int(stop) if stop else None
    except ValueError:
        fail(f"--steps: expected A:B (e.g. 0:50), got {value!r}")
    if not sep:
        fail(f"--steps: expected A:B (e.g. 0:50), got {value!r}")
    return a, b


def _steps(
    episode: int | None, steps: str | None, all_episodes: bool
) -> tuple[int | None, int | None]:
    """The ``--steps`` slice, once ``--episode``, ``--steps`` and ``--all-episodes`` agree."""
    if episode is not None:
        _episode_index(episode)
    start, stop = _parse_slice(steps)
    if steps is not None and episode is None:
        fail("--steps needs --episode N")
    if all_episodes and episode is not None:
        fail("--all-episodes lists the episodes of the file summary; not with --episode N")
    return start, stop


@app.command()
def show(
    path: Annotated[
        str,
        typer.Argument(help="An evidence file, or its URL (s3://, https:// …).", metavar="FILE"),
    ],
    episode: Annotated[
        int | None,
        typer.Option("--episode", "-e", help="Show this episode's steps.", metavar="<index>"),
    ] = None,
    steps: Annotated[
        str | None,
        typer.Option(help="Slice of steps A:B (with --episode), e.g. 0:50.", metavar="<A:B>"),
    ] = None,
    all_episodes: Annotated[
        bool,
        typer.Option(
            "--all-episodes",
            help="List every episode in the summary (default: all up to 12, else the first "
            "and last 5).",
        ),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Summarize a file (run metadata, spaces, versions, env spec, episodes), or one episode.

    \b
    e.g. episode-audit show runs/run.mcap
         episode-audit show runs/run.mcap --episode 3 --steps 0:20
    """  # noqa: D301 (\b: Click keeps the lines of the paragraph that follows as they are)
    from ..read import open_evidence
    from .render.show import episode_output, summary_output

    fmt = _format(output)
    start, stop = _steps(episode, steps, all_episodes)
    existing(path, "show")
    try:
        ev = open_evidence(path)
        if episode is None:
            emit(summary_output(ev, fmt, all_episodes=all_episodes))
        else:
            emit(episode_output(ev, episode, start, stop, fmt))
    except EpisodeAuditError as exc:
        fail(str(exc))
