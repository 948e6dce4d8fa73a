"""Replay evidence files: each file's episodes go to the replay its layout needs.

:func:`replay` opens the files and gathers the results (and the library versions that differ
from the recorded ones); :func:`replay_evidence` replays one open file, single-env and vector
files through :mod:`.single`, PettingZoo files through :mod:`.pettingzoo`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence

from .._usercode import import_modules
from ..errors import ConfigurationError
from ..read import Evidence, open_evidence
from ..record.gym import library_versions
from .envs import EnvFactory
from .pettingzoo import replay_agents_evidence
from .results import EpisodeReplay, ReplayResult
from .single import replay_single_evidence

__all__ = ["replay", "replay_evidence"]


def replay_evidence(
    ev: Evidence,
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[EpisodeReplay]:
    """Replay the episodes of one open evidence file (see :func:`replay`)."""
    run = (
        replay_agents_evidence
        if str(ev.run.layout.get("kind", "")).startswith("pettingzoo_")
        else replay_single_evidence
    )
    return run(
        ev,
        episodes=episodes,
        atol=atol,
        env_factory=env_factory,
        trust_entry_points=trust_entry_points,
        progress=progress,
    )


def replay(
    paths: Iterable[str | os.PathLike[str]],
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    imports: Sequence[str] = (),
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> ReplayResult:
    """Replay every (or the selected) episode of each file and compare it with the evidence.

    Raises :class:`~episode_audit.errors.EvidenceError` for an unreadable file and
    :class:`~episode_audit.errors.ConfigurationError` for a module in ``imports`` that cannot
    be imported.
    """
    if atol < 0:
        raise ConfigurationError(f"atol: expected a number >= 0, actually: {atol!r}")
    import_modules(imports)
    selected = None if episodes is None else list(episodes)
    result = ReplayResult()
    for path in paths:
        ev = open_evidence(path)
        result.episodes.extend(
            replay_evidence(
                ev,
                episodes=selected,
                atol=atol,
                env_factory=env_factory,
                trust_entry_points=trust_entry_points,
                progress=progress,
            )
        )
        diffs = _version_differences(ev)
        if diffs:
            result.version_differences[str(ev.path)] = diffs
    return result


def _version_differences(ev: Evidence) -> dict[str, tuple[str, str]]:
    """The libraries whose version now differs from the recorded one: (recorded, current)."""
    current = library_versions()
    return {
        lib: (str(recorded), now)
        for lib, recorded in ev.run.versions.items()
        if (now := current.get(lib) or _installed_version(lib)) != recorded
        and lib != "episode_audit"
    }


def _installed_version(distribution: str) -> str:
    """The installed version of a library this process has not imported, or "not installed"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except (PackageNotFoundError, ValueError):
        return "not installed"
