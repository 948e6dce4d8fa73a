"""Replay evidence files: each file's episodes go to the replay its layout needs.

:func:`replay` opens the files and gathers the results (the library versions that differ from
the recorded ones and, with ``keep_going``, the inputs that could not be read);
:func:`replay_evidence` replays one open file, single-env and vector files through
:mod:`.single`, PettingZoo files through :mod:`.pettingzoo`; :func:`replay_options` checks the
options as the command line names them.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace

from .._usercode import import_modules
from ..errors import ConfigurationError, EpisodeAuditError
from ..read import Evidence, open_evidence
from ..read.inputs import skipped
from ..read.liveness import Holder, still_written
from ..record.gym import library_versions
from .envs import EnvFactory, replay_notes
from .pettingzoo import replay_agents_evidence
from .results import EpisodeReplay, ReplayResult
from .single import replay_single_evidence

__all__ = ["replay", "replay_evidence", "replay_options"]


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
    results = run(
        ev,
        episodes=episodes,
        atol=atol,
        env_factory=env_factory,
        trust_entry_points=trust_entry_points,
        progress=progress,
    )
    return results if ev.writer is None else _still_recorded(ev, ev.writer, results)


def _still_recorded(
    ev: Evidence, writer: Holder, results: list[EpisodeReplay]
) -> list[EpisodeReplay]:
    """A live file's episodes still being recorded say so: only their flushed steps replayed."""
    table = ev.episodes()
    ended = table.column("ended").to_pylist()
    episodes = table.column("episode").to_pylist()
    running = {e for e, done in zip(episodes, ended, strict=True) if not done}
    why = f"still being recorded (the file is {still_written(writer)}): its flushed steps replayed"
    return [replace(r, reason=r.reason or why) if r.episode in running else r for r in results]


def replay(
    paths: Iterable[str | os.PathLike[str]],
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    imports: Sequence[str] = (),
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
    keep_going: bool = False,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
) -> ReplayResult:
    """Replay every (or the selected) episode of each file and compare it with the evidence.

    Raises :class:`~episode_audit.errors.EvidenceError` for an unreadable file and
    :class:`~episode_audit.errors.ConfigurationError` for a module in ``imports`` that cannot
    be imported. With ``keep_going`` a file that cannot be read (or replayed: any error but a
    ``ConfigurationError``) does not stop the others: none of its episodes is in the result,
    it is listed in :attr:`ReplayResult.unreadable`, and ``on_error`` is told of it as it is
    found. :attr:`ReplayResult.missing` lists the selected ``episodes`` no file had.
    """
    if atol < 0:
        raise ConfigurationError(f"atol: expected a number >= 0, actually: {atol!r}")
    import_modules(imports)
    selected = None if episodes is None else list(episodes)
    result = ReplayResult()
    for path in paths:
        try:
            ev = open_evidence(path)
            replayed = replay_evidence(
                ev,
                episodes=selected,
                atol=atol,
                env_factory=env_factory,
                trust_entry_points=trust_entry_points,
                progress=progress,
            )
        except EpisodeAuditError as exc:
            result.unreadable.append(skipped(path, exc, keep_going=keep_going, on_error=on_error))
            continue
        result.episodes.extend(replayed)
        if any(e.status != "not_replayable" for e in replayed):
            notes = replay_notes(
                ev.run, env_factory=env_factory, trust_entry_points=trust_entry_points
            )
            if notes:
                result.notes[str(ev.path)] = notes
        if ev.writer is not None:
            result.live.append((str(ev.path), ev.torn or still_written(ev.writer)))
        diffs = _version_differences(ev)
        if diffs:
            result.version_differences[str(ev.path)] = diffs
    if selected is not None:
        result.missing = sorted(set(selected) - {e.episode for e in result.episodes})
    return result


def replay_options(
    atol: float,
    episodes: Iterable[int] | None = None,
    *,
    atol_option: str = "atol",
    episode_option: str = "episodes",
) -> list[int] | None:
    """The ``episodes`` to replay as a list (``None``: all), once the options are checked.

    ``atol`` must be a finite number >= 0 and each episode index within ``0 .. 2**63 - 1``;
    else :class:`~episode_audit.errors.ConfigurationError` names the option as the caller calls
    it (``atol_option``, ``episode_option``: ``--atol`` and ``--episode`` on the command line).
    (:func:`replay` itself refuses only a negative ``atol``.)

    >>> replay_options(0.5, (3, 1))
    [3, 1]
    >>> replay_options(float("nan"), atol_option="--atol")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: --atol: expected a finite number >= 0, got nan
    """
    if not (math.isfinite(atol) and atol >= 0):
        raise ConfigurationError(f"{atol_option}: expected a finite number >= 0, got {atol}")
    if episodes is None:
        return None
    selected = list(episodes)
    for index in selected:
        if not 0 <= index < 2**63:
            raise ConfigurationError(
                f"{episode_option}: expected an episode index >= 0, got {index}"
            )
    return selected


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
