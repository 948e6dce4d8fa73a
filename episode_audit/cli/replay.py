"""``episode-audit replay``: re-run episodes and compare them step by step."""

from __future__ import annotations

from typing import Annotated

import typer

from ..errors import ConfigurationError
from ..read.inputs import steps_total
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    FormatOption,
    PathsArgument,
    _error_line,
    _format,
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
    allow_unverified: Annotated[
        bool,
        typer.Option(
            "--allow-unverified",
            help="Exit 0 even when no episode could be verified (every one not replayable).",
        ),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Re-run episodes from their recorded seed / RNG state and compare them step by step."""
    from ..replay import replay as run_replay
    from ..replay import replay_options
    from .render import replay_output

    fmt = _format(output)
    try:
        episodes = replay_options(atol, episode, atol_option="--atol", episode_option="--episode")
    except ConfigurationError as exc:
        fail(str(exc))
    files = collect(paths)
    with progress_bar("replaying", steps_total(files) if episode is None else None) as advance:
        try:
            result = run_replay(
                files,
                episodes=episodes,
                atol=atol,
                env_factory=env_factory,
                imports=import_ or (),
                trust_entry_points=trust_entry_points,
                progress=advance,
                keep_going=True,
                on_error=_error_line,
            )
        except ConfigurationError as exc:
            fail(str(exc))
    emit(replay_output(result, fmt))
    if result.missing and not result.unreadable:
        listed = ", ".join(map(str, result.missing))
        fail(
            f"--episode: no episode {listed} in the file(s) given "
            "(`episode-audit show FILE` says how many there are)"
        )
    if result.unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not result.ok:
        raise typer.Exit(EXIT_FINDINGS)
    if not result.verified and not allow_unverified:
        fail(_unverified(result.count("not_replayable")), EXIT_FINDINGS)


def _unverified(not_replayable: int) -> str:
    """Why a replay that compared no episode fails."""
    what = (
        f"all {not_replayable} episode(s) are not replayable (the output says why)"
        if not_replayable
        else "the file(s) hold no episode"
    )
    return f"replay verified no episode: {what}; pass --allow-unverified when that is expected"
