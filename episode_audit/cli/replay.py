"""``episode-audit replay``: re-run episodes and compare them step by step."""

from __future__ import annotations

from functools import partial
from typing import Annotated

import typer

from ..errors import ConfigurationError, EpisodeAuditError
from ..read.inputs import steps_total
from ._app import (
    EXIT_FINDINGS,
    EXIT_USAGE,
    SMALL_INPUTS,
    CIFormatOption,
    DocumentedCommand,
    ImportOption,
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
    imported,
    interruptible,
    jobs_for,
    progress_bar,
)
from ._summary import NoStepSummaryOption, append_step_summary

_EpisodeOption = Annotated[
    list[int] | None,
    typer.Option(
        "--episode", "-e", help="Replay only this episode (repeatable).", metavar="<index>"
    ),
]

_AtolOption = Annotated[
    float,
    typer.Option(
        help="Tolerance for numeric comparisons (0: exact, the default).", metavar="<tolerance>"
    ),
]

_EnvFactoryOption = Annotated[
    str | None,
    typer.Option(
        help="MODULE:CALLABLE that returns the environment to replay in.",
        metavar="<module:callable>",
    ),
]

_TrustEntryPointsOption = Annotated[
    bool,
    typer.Option(
        "--trust-entry-points",
        help="Allow importing the entry point named inside the file (trusted files only).",
    ),
]

_AllowUnverifiedOption = Annotated[
    bool,
    typer.Option(
        "--allow-unverified",
        help="Exit 0 even when no episode could be verified (every one not replayable).",
    ),
]


@app.command(cls=DocumentedCommand)
def replay(
    paths: PathsArgument,
    episode: _EpisodeOption = None,
    atol: _AtolOption = 0.0,
    env_factory: _EnvFactoryOption = None,
    import_: ImportOption = None,
    trust_entry_points: _TrustEntryPointsOption = False,
    allow_unverified: _AllowUnverifiedOption = False,
    output: CIFormatOption = "table",
    no_step_summary: NoStepSummaryOption = False,
    jobs: JobsOption = None,
    ray: RayOption = None,
) -> None:
    """Re-run episodes from their recorded seed / RNG state and compare them step by step."""
    from ..replay import replay as run_replay
    from ..replay import replay_options
    from .render import replay_output
    from .render.replay import unverified

    fmt = _format(output, junit=True)
    with failure_document("replay", fmt):
        try:
            episodes = replay_options(
                atol, episode, atol_option="--atol", episode_option="--episode"
            )
        except ConfigurationError as exc:
            fail(str(exc))
        files = collect(paths)
        total = partial(steps_total, files) if episode is None else None
        with interruptible(), progress_bar("replaying", total) as advance:
            try:
                result = run_replay(
                    files,
                    episodes=episodes,
                    atol=atol,
                    env_factory=env_factory,
                    imports=imported(import_),
                    trust_entry_points=trust_entry_points,
                    progress=advance,
                    keep_going=True,
                    on_error=_error_line,
                    jobs=jobs_for(jobs, files, SMALL_INPUTS // 8),
                    ray_address=ray,
                )
            except EpisodeAuditError as exc:  # (a setting; a worker that ended: WorkerError)
                fail(str(exc))
        emit(replay_output(result, fmt, allow_unverified=allow_unverified))
        append_step_summary(lambda: str(replay_output(result, "markdown")), off=no_step_summary)
        if result.missing and not result.unreadable:
            listed = ", ".join(map(str, result.missing))
            fail(
                f"--episode: no episode {listed} in the file(s) given "
                "(`episode-audit show FILE` says how many there are)"
            )
        if result.unreadable:
            raise typer.Exit(EXIT_USAGE)
        if result.count("diverged"):
            raise typer.Exit(EXIT_FINDINGS)
        if not result.verified and not allow_unverified:
            fail(unverified(result), EXIT_FINDINGS)
