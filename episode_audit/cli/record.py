"""``episode-audit record``: record episodes of a registered env with a policy."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ..errors import EpisodeAuditError
from ._app import ImportOption, app, fail, imported, interruptible, progress_bar, said

if TYPE_CHECKING:
    from ..read.storage import RemoteFile


_EnvIdArgument = Annotated[
    str, typer.Argument(help="A registered Gymnasium id, e.g. CartPole-v1.", metavar="ENV_ID")
]

_OutOption = Annotated[
    Path, typer.Option("--out", "-o", help="The evidence file to write.", metavar="<file.mcap>")
]

_PolicyOption = Annotated[
    str,
    typer.Option(
        help="random, scripted or hacker (reference tasks), or MODULE:CALLABLE taking "
        "(env, seed) and returning obs -> action.",
        metavar="<policy>",
    ),
]

_EpisodesOption = Annotated[int, typer.Option(help="Number of episodes.", min=1, metavar="<n>")]

_SeedOption = Annotated[
    int, typer.Option(help="Seed of the first episode (then seed+1, ...).", metavar="<seed>")
]

_EnvKwargsOption = Annotated[
    str | None,
    typer.Option(
        help="Keyword arguments for gym.make as JSON, e.g. '{\"proxy_reward\": true}'.",
        metavar="<json>",
    ),
]

_MaxEpisodeStepsOption = Annotated[
    int | None, typer.Option(help="Override the registered time limit.", metavar="<steps>")
]

_TagOption = Annotated[
    list[str] | None,
    typer.Option(help="Run tag KEY=VALUE (repeatable), e.g. policy=ppo.", metavar="<key=value>"),
]

_OverwriteOption = Annotated[
    bool,
    typer.Option("--overwrite", help="Replace an existing file (--out, and the --upload URL)."),
]

_UploadToOption = Annotated[
    str | None,
    typer.Option(
        "--upload",
        help="Copy the finished file to this URL (s3://bucket/key.mcap, or a prefix ending in /).",
        metavar="<url>",
    ),
]


@app.command()
def record(
    env_id: _EnvIdArgument,
    out: _OutOption,
    policy: _PolicyOption = "random",
    episodes: _EpisodesOption = 10,
    seed: _SeedOption = 0,
    env_kwargs: _EnvKwargsOption = None,
    max_episode_steps: _MaxEpisodeStepsOption = None,
    tag: _TagOption = None,
    import_: ImportOption = None,
    overwrite: _OverwriteOption = False,
    upload_to: _UploadToOption = None,
) -> None:
    """Record episodes of a Gymnasium environment with a built-in or given policy."""
    from ..rollout import record_episodes

    kwargs, tags = _env_kwargs(env_kwargs), _tags(tag or [])
    target = None if upload_to is None else _upload_target(upload_to, out)
    if target is not None and not overwrite:
        _refuse_existing(target)
    try:
        with interruptible(), progress_bar(f"recording {env_id}", episodes) as advance:
            summary = record_episodes(
                env_id,
                out,
                policy=policy,
                episodes=episodes,
                seed=seed,
                env_kwargs=kwargs,
                max_episode_steps=max_episode_steps,
                tags=tags,
                imports=imported(import_),
                overwrite=overwrite,
                on_episode=lambda: advance(1),
                overwrite_option="--overwrite",
                imports_option="--import {module}",
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    said(str(summary), [out])
    if target is not None:
        from ..read.storage import upload

        try:
            upload(out, target)
        except EpisodeAuditError as exc:
            fail(f"{exc} (the recording is kept in {out})")
        said(f"uploaded {out} to {target}", [out, target])


def _upload_target(url: str, out: Path) -> RemoteFile:
    """``--upload``: the URL the file goes to (a prefix ending in ``/`` gets its name).

    Resolved before recording, so that a scheme without its filesystem fails at once.
    """
    from ..read.storage import is_url, remote_file

    if not is_url(url):
        fail(
            f"--upload: expected a URL (s3://, gs://, az://), got {url!r}; --out is the local file"
        )
    try:
        return remote_file(url + out.name if url.endswith("/") else url)
    except EpisodeAuditError as exc:
        fail(str(exc))


def _refuse_existing(target: RemoteFile) -> None:
    """``--upload`` without ``--overwrite``: refuse a URL that holds a file, before recording."""
    from ..read.storage import exists

    try:
        there = exists(target)
    except EpisodeAuditError as exc:
        fail(str(exc))
    if there:
        fail(f"--upload: {target}: exists; pass --overwrite to replace it")


def _env_kwargs(text: str | None) -> dict[str, Any]:
    """``--env-kwargs``: a JSON object (none: no keyword arguments)."""
    if not text:
        return {}
    try:
        kwargs = json.loads(text)
    except json.JSONDecodeError as exc:
        fail(f"--env-kwargs: not valid JSON ({exc.msg})")
    if not isinstance(kwargs, dict):
        fail("--env-kwargs: expected a JSON object")
    return kwargs


def _tags(items: list[str]) -> dict[str, str]:
    """``--tag KEY=VALUE`` options, as a mapping (a later value of a key wins)."""
    tags: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            fail(f"--tag: expected KEY=VALUE, got {item!r}")
        tags[key] = value
    return tags
