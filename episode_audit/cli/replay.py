"""``episode-audit replay``: re-run episodes and compare them step by step."""

from __future__ import annotations

import math
from typing import Annotated

import typer

from ..errors import ConfigurationError, EpisodeAuditError
from ..read.inputs import Unreadable, steps_total
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    FormatOption,
    PathsArgument,
    _episode_index,
    _format,
    _unreadable,
    app,
    collect,
    emit,
    fail,
    progress_bar,
)


@app.command()
def replay(
    paths: PathsArgument,
    episode: Annotated[
        list[int] | None,
        typer.Option(
            "--episode", "-e", help="Replay only this episode (repeatable).", metavar="<int>"
        ),
    ] = None,
    atol: Annotated[
        float, typer.Option(help="Tolerance for numeric comparisons (0: exact, the default).")
    ] = 0.0,
    env_factory: Annotated[
        str | None,
        typer.Option(help="MODULE:CALLABLE that returns the environment to replay in."),
    ] = None,
    import_: Annotated[
        list[str] | None,
        typer.Option(
            "--import",
            help="Import MODULE first (e.g. a package that registers envs; repeatable).",
            metavar="<module>",
        ),
    ] = None,
    trust_entry_points: Annotated[
        bool,
        typer.Option(
            "--trust-entry-points",
            help="Allow importing the entry point named inside the file (trusted files only).",
        ),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Re-run episodes from their recorded seed / RNG state and compare them step by step."""
    from ..replay import ReplayResult
    from ..replay import replay as run_replay
    from .render import replay_output

    fmt = _format(output)
    if not (math.isfinite(atol) and atol >= 0):
        fail(f"--atol: expected a finite number >= 0, got {atol}")
    for index in episode or []:
        _episode_index(index)
    files = collect(paths)
    merged = ReplayResult()
    unreadable: list[Unreadable] = []
    with progress_bar("replaying", steps_total(files) if episode is None else None) as advance:
        for path in files:
            try:
                result = run_replay(
                    [path],
                    episodes=episode,
                    atol=atol,
                    env_factory=env_factory,
                    imports=import_ or (),
                    trust_entry_points=trust_entry_points,
                    progress=advance,
                )
            except ConfigurationError as exc:
                fail(str(exc))
            except EpisodeAuditError as exc:
                _unreadable(path, exc, unreadable)
                continue
            merged.episodes.extend(result.episodes)
            merged.version_differences.update(result.version_differences)
    emit(replay_output(merged, fmt, unreadable=unreadable))
    missing = sorted(set(episode or ()) - {e.episode for e in merged.episodes})
    if missing and not unreadable:
        listed = ", ".join(map(str, missing))
        fail(
            f"--episode: no episode {listed} in the file(s) given "
            "(`episode-audit show FILE` says how many there are)"
        )
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not merged.ok:
        raise typer.Exit(EXIT_FINDINGS)
