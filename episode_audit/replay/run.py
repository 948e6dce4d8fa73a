"""Replay evidence files: each file's episodes go to the replay its layout needs.

:func:`replay` opens the files and gathers the results (the library versions that differ from
the recorded ones and, with ``keep_going``, the inputs that could not be read);
:func:`replay_evidence` replays one open file, single-env and vector files through
:mod:`.single`, PettingZoo files through :mod:`.pettingzoo`; :func:`replay_options` checks the
options as the command line names them.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial

from .._jobs import check_jobs, map_ordered, pooled, unpicklable, workers
from .._usercode import import_modules
from ..errors import ConfigurationError, EpisodeAuditError
from ..format import names as fmt
from ..format.columns import prepare_pyarrow
from ..format.records import unstarted
from ..read import Evidence, open_evidence
from ..read.arguments import episode_indices, name_list, non_negative, path_list
from ..read.inputs import skipped
from ..read.liveness import Holder, still_written
from ..record.gym import STEP_LIBRARIES, library_versions
from .envs import EnvFactory, replay_notes
from .pettingzoo import replay_agents_evidence
from .results import EpisodeReplay, ReplayResult, not_told_from_versions
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
    prepare_pyarrow()  # (before the env steps, and not in its context)
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
    jobs: int | None = 1,
    ray_address: str | None = None,
) -> ReplayResult:
    """Replay every (or the selected) episode of each file and compare it with the evidence.

    Raises :class:`~episode_audit.errors.EvidenceError` for an unreadable file and
    :class:`~episode_audit.errors.ConfigurationError` for a module in ``imports`` (a list of
    module names) that cannot be imported. With ``keep_going`` a file that cannot be read (or
    replayed: any error but a ``ConfigurationError``) does not stop the others: none of its
    episodes is in the result, it is listed in :attr:`ReplayResult.unreadable`, and
    ``on_error`` is told of it as it is found. :attr:`ReplayResult.missing` lists the selected
    ``episodes`` no file had.

    ``jobs`` worker processes (``None``: one per usable core) or Ray tasks on ``ray_address``
    replay a file, or a batch of a large single-env file's episodes, each (see
    :mod:`episode_audit._jobs`); a batch starts in a fresh env, as ``episodes`` does, and an
    episode that then differs is replayed again after its file's earlier episodes. Each
    worker imports ``imports`` itself; ``env_factory`` must then be ``"MODULE:CALLABLE"`` or a
    module-level callable (a lambda or a local function is refused with a
    ``ConfigurationError`` before any work starts). The result is the same as with ``jobs=1``.
    """
    selected = replay_options(atol, episodes)
    imports = name_list("imports", imports)
    import_modules(imports)
    files = path_list(paths)
    one = partial(
        _replay_batch,
        atol=atol,
        env_factory=env_factory,
        imports=tuple(imports),
        trust_entry_points=trust_entry_points,
    )
    parallel = ray_address is not None or check_jobs(jobs) > 1
    batches, costs = _batches(files, selected, ray_address, jobs) if parallel else ([], [])
    if not batches:
        batches = [(k, path, selected) for k, path in enumerate(files)]
    if callable(env_factory) and pooled(len(batches), jobs, ray_address):
        _refuse_unsendable(env_factory, jobs)
    done = map_ordered(
        one, batches, jobs=jobs, ray_address=ray_address, progress=progress, costs=costs or None
    )
    result = ReplayResult()
    found: set[int] = set()  # the selected episodes unstarted, found too
    for k, parts in _by_file(batches, done):
        path = files[k]
        errors = [part for part in parts if isinstance(part, EpisodeAuditError)]
        if errors:
            result.unreadable.append(
                skipped(path, errors[0], keep_going=keep_going, on_error=on_error)
            )
            continue
        replayed = [p for p in parts if not isinstance(p, EpisodeAuditError)]
        selections = [b[2] for b in batches if b[0] == k]
        _add_file(_in_recorded_order(one, (k, path, selected), selections, replayed), result)
        found.update(*(part.unstarted for part in replayed))
    if selected is not None:
        found.update(e.episode for e in result.episodes)
        result.missing = sorted(set(selected) - found)
    return result


def _refuse_unsendable(env_factory: EnvFactory, jobs: int | None) -> None:
    """Refuse an ``env_factory`` the worker processes cannot be sent (a lambda, a local one)."""
    problem = unpicklable(env_factory)
    if problem is not None:
        name = getattr(env_factory, "__qualname__", type(env_factory).__name__)
        raise ConfigurationError(
            f"env_factory {name}: cannot be sent to the worker processes of jobs={jobs} "
            f"({problem}); pass a function defined at the top level of a module, or "
            '"MODULE:CALLABLE", or jobs=1'
        )


@dataclass(frozen=True)
class _Replayed:
    """A batch of a file's episodes replayed, and what the result says of the file."""

    file: str
    episodes: list[EpisodeReplay]
    notes: list[str]
    live: str | None
    versions: dict[str, tuple[str, str]]
    unstarted: frozenset[int] = frozenset()
    """The batch's episodes reset and never stepped, left out of :attr:`episodes`."""


def _replay_batch(
    batch: _Batch,
    progress: Callable[[int], None] | None,
    *,
    atol: float,
    env_factory: str | EnvFactory | None,
    imports: Sequence[str],
    trust_entry_points: bool,
) -> _Replayed | EpisodeAuditError:
    """Open a file and replay a batch of its episodes (in a worker, maybe)."""
    _, path, selected = batch
    import_modules(imports)
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
    except ConfigurationError:
        raise
    except EpisodeAuditError as exc:
        return exc
    notes = replay_notes(ev.run, env_factory=env_factory, trust_entry_points=trust_entry_points)
    live = None if ev.writer is None else ev.torn or still_written(ev.writer)
    versions = _version_differences(ev)
    replayed = not_told_from_versions(replayed, _env_libraries(versions))
    replayed, idle = _without_unstarted(ev, replayed)
    return _Replayed(str(ev.path), replayed, notes, live, versions, idle)


def _without_unstarted(
    ev: Evidence, replayed: list[EpisodeReplay]
) -> tuple[list[EpisodeReplay], frozenset[int]]:
    """``replayed`` without the file's unstarted episodes, and those left out.

    An unstarted episode (reset and never stepped: :func:`~episode_audit.format.records.
    unstarted`) is no episode to verify, as ``check`` and ``report`` count them; its reset
    was replayed, in order, for the episodes after it. One whose reset differed stays.
    """
    table = ev.episodes()
    if not table.num_rows:
        return replayed, frozenset()
    idle = frozenset(table.column(fmt.COL_EPISODE).filter(unstarted(table)).to_pylist())
    if not idle:
        return replayed, idle
    left = frozenset(e.episode for e in replayed if e.episode in idle and e.divergence is None)
    return [e for e in replayed if e.episode not in left], left


def _in_recorded_order(
    one: Callable[[_Batch, None], _Replayed | EpisodeAuditError],
    batch: _Batch,
    selections: Sequence[list[int] | None],
    parts: list[_Replayed],
) -> list[_Replayed]:
    """A file's replayed batches; a difference met after other episodes than recorded, redone.

    A batch, or an ``episodes`` selection, begins in a fresh env: an episode after one it
    skipped meets an env that has begun fewer episodes than the recorded one had. An env that
    keeps state across resets (a curriculum, a counter) then differs from its recording with
    nothing wrong, so such a difference is no verdict. The file's episodes up to the last of
    them are replayed again in one env per sub-env, in recorded order (as one batch of the
    whole file would), and their verdicts replace the batches': the result is the same
    whatever the batches. A difference is one whatever its verdict: ``diverged``, or
    ``not_replayable`` keeping it (after calls replay does not repeat, other library
    versions). ``batch``: the file's (place, path, selection).
    """
    differed = {e.episode for part in parts for e in part.episodes if e.divergence is not None}
    if not differed or all(s is None for s in selections):
        return parts
    order = _episodes_in_order(batch[1])
    if order is None:
        return parts
    after_a_gap: set[int] = set()
    for chosen in selections:
        if chosen is not None:
            after_a_gap |= _after_a_gap(order, set(chosen))
    suspect = differed & after_a_gap
    if not suspect:
        return parts
    last = max(suspect)
    prefix = sorted(e for episodes in order.values() for e in episodes if e <= last)
    again = one((batch[0], batch[1], prefix), None)
    if isinstance(again, EpisodeAuditError):
        return parts  # (the batches' own verdicts: the file could not be read again)
    redone = {e.episode: e for e in again.episodes}
    return [
        replace(part, episodes=[redone.get(e.episode, e) for e in part.episodes]) for part in parts
    ]


def _episodes_in_order(path: str | os.PathLike[str]) -> dict[int, list[int]] | None:
    """The episodes of a single-env or vector file, by sub-env, in order; else ``None``."""
    try:
        ev = open_evidence(path)
        if str(ev.run.layout.get("kind", "")).startswith("pettingzoo_"):
            return None
        table = ev.episodes()
    except EpisodeAuditError:
        return None
    envs = (
        table.column(fmt.COL_ENV_INDEX).to_pylist()
        if fmt.COL_ENV_INDEX in table.column_names
        else [0] * table.num_rows
    )
    order: dict[int, list[int]] = {}
    for episode, env_index in zip(table.column(fmt.COL_EPISODE).to_pylist(), envs, strict=True):
        order.setdefault(int(env_index or 0), []).append(int(episode))
    return {k: sorted(v) for k, v in order.items()}


def _after_a_gap(order: dict[int, list[int]], chosen: set[int]) -> set[int]:
    """The ``chosen`` episodes replayed without an earlier episode of their sub-env before them.

    >>> sorted(_after_a_gap({0: [0, 1, 2, 3], 1: [4, 5]}, {0, 1, 3, 5}))
    [3, 5]
    """
    out: set[int] = set()
    for episodes in order.values():
        gap = False
        for episode in episodes:
            if episode not in chosen:
                gap = True
            elif gap:
                out.add(episode)
    return out


def _add_file(parts: Sequence[_Replayed], result: ReplayResult) -> None:
    """One file's replayed batches into ``result``."""
    first = parts[0]
    replayed = [e for part in parts for e in part.episodes]
    result.episodes.extend(replayed)
    result.unstarted += len(frozenset().union(*(part.unstarted for part in parts)))
    if any(e.status != "not_replayable" for e in replayed) and first.notes:
        result.notes[first.file] = first.notes
    if first.live is not None:
        result.live.append((first.file, first.live))
    if first.versions:
        result.version_differences[first.file] = first.versions


_Batch = tuple[int, "str | os.PathLike[str]", "list[int] | None"]
"""(the file's place among the inputs, the file, its episodes to replay or ``None``: all)."""


def _by_file(
    batches: Sequence[_Batch], done: Iterable[_Replayed | EpisodeAuditError]
) -> Iterator[tuple[int, list[_Replayed | EpisodeAuditError]]]:
    """The batches' results grouped by file, in order (a file's batches are next to each other)."""
    current: list[_Replayed | EpisodeAuditError] = []
    index = -1
    for (k, _, _), part in zip(batches, done, strict=True):
        if current and k != index:
            yield index, current
            current = []
        index = k
        current.append(part)
    if current:
        yield index, current


MIN_BATCH_BYTES = 128 << 10
"""A file is cut into batches of its episodes no smaller than this (each starts a fresh env)."""


def _batches(
    files: Sequence[str | os.PathLike[str]],
    selected: list[int] | None,
    ray_address: str | None,
    jobs: int | None,
) -> tuple[list[_Batch], list[float]]:
    """One batch per file, a large single-env file's episodes in several; and their sizes.

    A share is an eighth of a process's part of all the bytes (at least
    :data:`MIN_BATCH_BYTES`): a file larger is cut into batches of about a share, so the
    processes take a large file's batches first and end together. A batch's size (its share
    of its file's bytes) is its cost for :func:`~episode_audit._jobs.map_ordered`.
    """
    sizes = []
    for path in files:
        try:
            sizes.append(os.path.getsize(path))
        except OSError:
            sizes.append(0)
    share = max(MIN_BATCH_BYTES, sum(sizes) // (8 * workers(jobs, ray_address)))
    out: list[_Batch] = []
    costs: list[float] = []
    for k, (path, size) in enumerate(zip(files, sizes, strict=True)):
        pieces = -(-size // share)
        episodes = _single_env_episodes(path, selected) if pieces > 1 else None
        if episodes is None or len(episodes) < 2:
            out.append((k, path, selected))
            costs.append(max(1, size))
            continue
        step = -(-len(episodes) // min(pieces, len(episodes)))
        for i in range(0, len(episodes), step):
            out.append((k, path, episodes[i : i + step]))
            costs.append(max(1, size * len(out[-1][2] or ()) / len(episodes)))
    return out, costs


def _single_env_episodes(
    path: str | os.PathLike[str], selected: list[int] | None
) -> list[int] | None:
    """The (selected) episodes of a finished single-env file, in order; else ``None``."""
    try:
        ev = open_evidence(path)
        if ev.writer is not None or str(ev.run.layout.get("kind", "single")) != "single":
            return None
        listed = ev.episodes().column("episode").to_pylist()
    except EpisodeAuditError:
        return None  # its worker says why
    wanted = None if selected is None else set(selected)
    return [e for e in listed if wanted is None or e in wanted]


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
    :func:`replay` checks its own with it.

    >>> replay_options(0.5, (3, 1))
    [3, 1]
    >>> replay_options(float("nan"), atol_option="--atol")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: --atol: expected a finite number >= 0, got nan
    """
    non_negative(atol_option, atol)
    return None if episodes is None else episode_indices(episode_option, episodes)


def _version_differences(ev: Evidence) -> dict[str, tuple[str, str]]:
    """The libraries whose version now differs from the recorded one: (recorded, current)."""
    current = library_versions()
    return {
        lib: (str(recorded), now)
        for lib, recorded in ev.run.versions.items()
        if (now := current.get(lib) or _installed_version(lib)) != recorded
        and lib != "episode_audit"
    }


def _env_libraries(versions: dict[str, tuple[str, str]]) -> dict[str, tuple[str, str]]:
    """Of the differing ``versions``, those that can have changed the replay's steps.

    Python, and the ``STEP_LIBRARIES`` loaded in this process after replaying (numpy,
    Gymnasium, MuJoCo when the env used it…); not one that is not loaded here, which the rebuilt
    env did not use, nor a name no recorder writes (a hand-edited file's).
    """
    return {
        lib: pair
        for lib, pair in versions.items()
        if lib in STEP_LIBRARIES and (lib == "python" or lib in sys.modules)
    }


def _installed_version(distribution: str) -> str:
    """The installed version of a library this process has not imported, or "not installed"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except (PackageNotFoundError, ValueError):
        return "not installed"
