"""The inputs of a command: evidence files named directly or found in directories.

:func:`evidence_files` expands paths (directories searched for ``*.mcap``, viewer exports left
out; :func:`listed_inputs` also says which were); :func:`open_all`
opens them, keeping going past the ones that cannot be read (each an :class:`Unreadable`), so
one bad file costs the others nothing; :func:`steps_total` sums the steps finished files
declare (a torn file's estimated from its size), for progress bars.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigurationError, EpisodeAuditError, EvidenceError
from .arguments import path_list
from .evidence import Evidence
from .opening import (
    broken_link,
    declared_steps,
    open_evidence,
    remote_viewer_exports,
    viewer_export,
)
from .storage import RemoteFile, Source, as_source, list_remote

__all__ = [
    "Inputs",
    "Unreadable",
    "evidence_files",
    "listed_inputs",
    "open_all",
    "skipped",
    "steps_total",
]


@dataclass(frozen=True)
class Unreadable:
    """An input that could not be read: the file and why (the error's problem)."""

    file: str
    why: str

    @classmethod
    def of(cls, path: str | os.PathLike[str], exc: EpisodeAuditError) -> Unreadable:
        """The input ``path`` that failed with ``exc``."""
        return cls(str(path), exc.problem if isinstance(exc, EvidenceError) else str(exc))


def skipped(
    path: str | os.PathLike[str],
    exc: EpisodeAuditError,
    *,
    keep_going: bool,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
) -> Unreadable:
    """The input ``path`` that failed with ``exc``, skipped: when the caller keeps going.

    ``on_error`` is told first; without ``keep_going`` ``exc`` is raised again. A
    ``ConfigurationError`` (the caller's options, not the input) is always raised.
    """
    if not keep_going or isinstance(exc, ConfigurationError):
        raise exc
    if on_error is not None:
        on_error(exc)
    return Unreadable.of(os.fspath(path), exc)


@dataclass(frozen=True)
class Inputs:
    """A command's input files (:func:`listed_inputs`), and the viewer exports left out."""

    files: list[Source]
    exports: list[Source]
    """The viewer exports (``episode-audit export --to foxglove``) found in the directories
    given: not evidence, so not inputs (one named as a file is an input, and unreadable)."""

    def exports_note(self) -> str | None:
        """One line saying how many viewer exports were left out, and the first; else ``None``.

        >>> print(Inputs([], [Path("runs/a.foxglove.mcap"), Path("b.mcap")]).exports_note())
        left out 2 viewer export(s) found in the directories given (runs/a.foxglove.mcap, ...)
        """
        if not self.exports:
            return None
        more = ", ..." if len(self.exports) > 1 else ""
        return (
            f"left out {len(self.exports)} viewer export(s) found in the directories given "
            f"({self.exports[0]}{more})"
        )


def evidence_files(
    paths: Sequence[str | os.PathLike[str]],
    *,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> list[Source]:
    """Files as given and ``*.mcap`` files under directories (recursively, sorted).

    The files of :func:`listed_inputs` (which also says which viewer exports it left out).
    """
    return listed_inputs(paths, filesystem=filesystem, storage_options=storage_options).files


def listed_inputs(
    paths: Sequence[str | os.PathLike[str]],
    *,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> Inputs:
    """Files as given and ``*.mcap`` files under directories (recursively, sorted).

    A file reached twice (named twice, or also found in a directory given) counts once. A
    viewer export found in a directory (:func:`~.opening.viewer_export`: what ``export --to
    foxglove`` writes) is left out, and listed in :attr:`Inputs.exports`; one named as a file
    is kept (opening it says it is an export). URLs (``s3://bucket/prefix`` …) are listed the
    same way, through ``filesystem`` or one made with ``storage_options`` (see
    :func:`open_evidence`); each is a :class:`~episode_audit.read.storage.RemoteFile` that
    carries its filesystem; a prefix's viewer exports are left out as a directory's are
    (the first bytes of its files read together, the summary only of MCAP files of another
    profile: :func:`~.opening.remote_viewer_exports`).
    Raises :class:`~episode_audit.errors.ConfigurationError` for a path that does not exist,
    a directory without evidence files, or one that cannot be listed.
    """
    out: list[Source] = []
    exports: list[Source] = []
    seen: set[object] = set()
    for given in path_list(paths):
        path = as_source(given, filesystem=filesystem, storage_options=storage_options)
        if isinstance(path, RemoteFile):
            for remote in _remote_not_exports(path, exports):
                if remote.url not in seen:
                    seen.add(remote.url)
                    out.append(remote)
            continue
        try:
            if path.is_dir():
                found = _not_exports(sorted(_searched(path)), exports)
                if not found:
                    raise ConfigurationError(f"{path}: {_nothing_in(path, exports)}")
            else:
                os.stat(path)  # (a link that leads nowhere: said below)
                found = [path]
        except (FileNotFoundError, NotADirectoryError) as exc:
            why = broken_link(path, exc) or "no such file or directory"
            raise ConfigurationError(f"{path}: {why}") from None
        except OSError as exc:  # e.g. a directory on the way without search permission
            why = broken_link(path, exc) or f"cannot read: {exc.strerror or exc}"
            raise ConfigurationError(f"{exc.filename or path}: {why}") from None
        for file in found:
            real = os.path.realpath(file)  # (a link's loop: as it is)
            if real not in seen:
                seen.add(real)
                out.append(file)
    return Inputs(out, exports)


def _not_exports(found: list[Path], exports: list[Source]) -> list[Path]:
    """``found`` (a directory's files) but its viewer exports, which go to ``exports`` (once)."""
    kept = []
    listed = {os.path.realpath(e) for e in exports}
    for file in found:
        if not viewer_export(file):
            kept.append(file)
        elif os.path.realpath(file) not in listed:
            exports.append(file)
    return kept


def _remote_not_exports(path: RemoteFile, exports: list[Source]) -> list[RemoteFile]:
    """The files of URL ``path`` (:func:`~.storage.list_remote`), a prefix's but its exports.

    Its viewer exports (:func:`~.opening.remote_viewer_exports`) go to ``exports`` (once).
    """
    found = list_remote(path)
    if found == [path]:  # (a file named: kept, as a local one)
        return found
    listed = {e.url for e in exports if isinstance(e, RemoteFile)}
    kept = []
    for file, export in zip(found, remote_viewer_exports(found), strict=True):
        if not export:
            kept.append(file)
        elif file.url not in listed:
            exports.append(file)
    if not kept:
        raise ConfigurationError(f"{path}: {_nothing_in(path, exports)}")
    return kept


def _nothing_in(directory: Source, exports: Sequence[Source]) -> str:
    """Why ``directory`` (or a URL prefix) gives no input: no ``*.mcap`` file, or only exports."""
    if isinstance(directory, RemoteFile):
        where = "under this prefix"
        prefix = directory.url.rstrip("/") + "/"
        held: list[Source] = [
            e for e in exports if isinstance(e, RemoteFile) and e.url.startswith(prefix)
        ]
    else:
        where = "in this directory"
        held = [e for e in exports if Path(e).is_relative_to(directory)]
    if not held:
        return f"no *.mcap files {where}"
    return (
        f"no evidence files {where}: its {len(held)} *.mcap file(s) are viewer "
        f"exports (episode-audit export --to foxglove), not evidence (e.g. {held[0]})"
    )


def _searched(directory: Path) -> list[Path]:
    """Every entry named ``*.mcap`` under ``directory`` that is not a directory.

    Symbolic links to directories are followed, each real directory searched once (in sorted
    order, so which path reaches it does not depend on the file system's order; a link back
    up is no loop). An entry that cannot be opened (a broken link, a link loop) or is not a
    regular file is listed all the same: opening it says why it is unreadable.
    """
    found: list[Path] = []
    searched = {os.path.realpath(directory)}
    folders = [directory]
    while folders:
        folder = folders.pop()
        with os.scandir(folder) as scanned:
            entries = sorted(scanned, key=lambda entry: entry.name)
        for entry in entries:
            if _is_dir(entry):
                real = os.path.realpath(entry.path)
                if real not in searched:
                    searched.add(real)
                    folders.append(Path(entry.path))
            elif entry.name.endswith(".mcap"):
                found.append(Path(entry.path))
    return found


def _is_dir(entry: os.DirEntry[str]) -> bool:
    """Whether ``entry`` is a directory, or a link to one (a link loop is not)."""
    try:
        return entry.is_dir()
    except OSError:
        return False


def open_all(
    files: Sequence[Source],
    load: Callable[[Evidence], object] | None = None,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
) -> tuple[list[tuple[Source, Evidence]], list[Unreadable]]:
    """The files that open as evidence (and whose ``load`` reads), opened; and the others.

    ``on_error`` is told of each file that does not, as it is found.
    """
    readable: list[tuple[Source, Evidence]] = []
    unreadable: list[Unreadable] = []
    for path in files:
        try:
            ev = open_evidence(path)
            if load is not None:
                load(ev)
            readable.append((path, ev))
        except EpisodeAuditError as exc:
            if on_error is not None:
                on_error(exc)
            unreadable.append(Unreadable.of(path, exc))
    return readable, unreadable


def steps_total(paths: Sequence[Source]) -> int | None:
    """The steps the files hold, for a progress bar: as their run-end records declare them.

    A file without a declared count (torn, or still being written) is counted at the steps
    per byte of the files that declare theirs, times its size: an estimate, read from its end
    only (:func:`~.opening.declared_steps`; a torn file is not scanned). A file that cannot be
    read counts nothing (no step of it is done). ``None`` when no file declares its steps.
    """
    known_steps = known_bytes = unknown_bytes = 0
    for path in paths:
        try:
            steps, size = declared_steps(path)
        except EvidenceError:
            continue
        if steps is None:
            unknown_bytes += size
        else:
            known_steps += steps
            known_bytes += size
    if not unknown_bytes:
        return known_steps
    if not known_bytes:
        return None
    return known_steps + round(unknown_bytes * known_steps / known_bytes)
