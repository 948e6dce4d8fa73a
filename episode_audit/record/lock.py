"""The recorder's output file: one writer per file, and path templates.

:func:`claim_output` resolves a path template (:class:`PathTemplate`: ``{index}``, ``{pid}``,
``{time}``), creates the file and takes its writer's lock (:mod:`episode_audit.format.locking`)
before a byte is written. A path another live recorder holds, in this process or another, is
refused with a :class:`~episode_audit.errors.ConfigurationError` naming the holder;
``overwrite`` truncates only once the lock is held, and is refused with ``{index}``; a caller
that checks before recording and names ``overwrite`` otherwise (``--overwrite``) has
:func:`refuse_indexed_overwrite` and :func:`refuse_existing`. Where the
filesystem has no locks the recorder records anyway and warns once. :class:`LockedStream` is
the file the writer writes; closing it releases the lock.
"""

from __future__ import annotations

import os
import stat
import string
import time
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import IO

from ..errors import ConfigurationError, RecorderTroubleWarning
from ..format.locking import Holder, holder, probe, try_lock, unlock
from ..format.paths import path_argument

__all__ = [
    "LockedStream",
    "Output",
    "PathTemplate",
    "check_output_path",
    "claim_output",
    "make_folder",
    "output_kind",
    "refuse_existing",
    "refuse_indexed_overwrite",
    "remove_empty",
]

FIELDS = ("index", "pid", "time")
"""The fields a path template may hold."""

MAX_INDEX = 1_000_000
"""``{index}`` takes the lowest free value below this."""

_TRIES, _PAUSE_S = 20, 0.005  # a reader's probe holds a shared lock for microseconds
_CREATE = os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
_LITERAL_BRACES = "a literal brace is written '{{' or '}}'"

# (st_dev, st_ino) of each file this process writes -> (pid, fd) of its lock: a forked child
# inherits the table and the open file, not the right to unlock it
_HELD_HERE: dict[tuple[int, int], tuple[int, int]] = {}
_warned_no_locks = False


class PathTemplate:
    """A recorder's path, with ``{index}``, ``{pid}`` and ``{time}`` fields (or none).

    ``{index}`` is the lowest non-negative integer whose path is free (claimed by
    :func:`claim_output`; it must be in the file name), ``{pid}`` the recording process's id,
    ``{time}`` the UTC time of construction (``20261105T142301Z``: sortable, safe in file
    names). Format specs are allowed (``{index:03d}``); ``{{`` and ``}}`` are literal braces.

    >>> PathTemplate("runs/train-{index:02d}.mcap").render(7)
    'runs/train-07.mcap'
    >>> PathTemplate("a{{b}}.mcap").render(0)
    'a{b}.mcap'
    >>> PathTemplate("run-{seed}.mcap")
    Traceback (most recent call last):
    episode_audit.errors.ConfigurationError: path 'run-{seed}.mcap': unknown field {seed}; \
a path template knows {index}, {pid} and {time} (a literal brace is written '{{' or '}}')

    Raises:
        ConfigurationError: An unknown field, a field with a conversion (``!r``), a lone brace,
            a bad format spec, or ``{index}`` outside the file name.
    """

    def __init__(self, text: str) -> None:
        self.text = text
        self.fields = _fields(text)
        self.time = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        self.pid = os.getpid()
        try:
            first = self.render(0)
        except (ValueError, TypeError) as exc:
            raise ConfigurationError(f"path {text!r}: {exc}") from None
        if "index" in self.fields and os.path.dirname(first) != os.path.dirname(self.render(1)):
            raise ConfigurationError(
                f"path {text!r}: {{index}} must be in the file name, not in a directory"
            )

    def render(self, index: int) -> str:
        """The path with ``index`` for ``{index}``."""
        return self.text.format(index=index, pid=self.pid, time=self.time)


def _fields(text: str) -> set[str]:
    """The fields of ``text`` (checked: known names only, no conversion)."""
    try:
        parsed = list(string.Formatter().parse(text))
    except ValueError as exc:
        raise ConfigurationError(f"path {text!r}: {exc} ({_LITERAL_BRACES})") from None
    found: set[str] = set()
    for _, name, _, conversion in parsed:
        if name is None:
            continue
        if name not in FIELDS:
            raise ConfigurationError(
                f"path {text!r}: unknown field {{{name}}}; a path template knows {{index}}, "
                f"{{pid}} and {{time}} ({_LITERAL_BRACES})"
            )
        if conversion is not None:
            raise ConfigurationError(f"path {text!r}: {{{name}!{conversion}}}: no conversions")
        found.add(name)
    return found


@dataclass
class Output:
    """An output file claimed and locked: its resolved ``path`` and open descriptor ``fd``."""

    path: Path
    fd: int
    key: tuple[int, int]
    locked: bool
    indexed: bool = False  # the path is the one ``{index}`` claimed

    def release(self) -> None:
        """Release the writer's lock (only in the process that took it); the fd stays open."""
        if _HELD_HERE.get(self.key) != (os.getpid(), self.fd):
            return
        del _HELD_HERE[self.key]
        if self.locked:
            unlock(self.fd)


def claim_output(
    path: str | os.PathLike[str], *, overwrite: bool = False, template: bool = True
) -> Output:
    """Create (or, with ``overwrite``, open) the evidence file and take its writer's lock.

    With ``template`` the path is a :class:`PathTemplate`. ``{index}`` always claims a free
    path (``O_CREAT | O_EXCL``, atomic across processes), so it never overwrites anything:
    ``overwrite=True`` with it is refused. Without ``{index}``, an existing file is refused
    unless ``overwrite``; then it is truncated only once its lock is held.

    A missing folder is created, with its parents.

    Raises:
        ConfigurationError: The path is not one (``bytes``, ``None``, ``""``:
            :func:`~episode_audit.format.paths.path_argument`), a bad template, a directory,
            exists (without ``overwrite``), is being written by another live recorder, or
            cannot be created.
    """
    text = os.fspath(path_argument("path", path))
    if not template:
        make_folder(Path(text))
        return _open_path(Path(text), overwrite)
    tmpl = PathTemplate(text)
    make_folder(Path(tmpl.render(0)))
    if "index" not in tmpl.fields:
        return _open_path(Path(tmpl.render(0)), overwrite)
    if overwrite:
        raise _indexed_overwrite(text, "overwrite=True")
    taken = _names_in(os.path.dirname(tmpl.render(0)) or ".")
    for index in range(MAX_INDEX):
        text = tmpl.render(index)
        if os.path.basename(text) in taken:
            continue
        candidate = Path(text)
        try:
            fd = os.open(candidate, _CREATE | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise ConfigurationError(f"{candidate}: cannot create: {exc.strerror}") from None
        output = _lock(candidate, fd, truncate=False)
        output.indexed = True
        return output
    raise ConfigurationError(f"path {text!r}: every {{index}} below {MAX_INDEX} is taken")


def refuse_indexed_overwrite(
    path: str | os.PathLike[str], *, overwrite_option: str = "overwrite=True"
) -> None:
    """Refuse to overwrite with a path template holding ``{index}``, as :func:`claim_output` does.

    For a caller that takes ``overwrite`` under another name and checks before recording:
    the error names it ``overwrite_option`` (``--overwrite`` on the command line).

    Raises:
        ConfigurationError: The path holds ``{index}``, or is a bad template.
    """
    text = os.fspath(path_argument("path", path))
    if "index" in PathTemplate(text).fields:
        raise _indexed_overwrite(text, overwrite_option)


def refuse_existing(
    path: str | os.PathLike[str], *, overwrite_option: str = "overwrite=True"
) -> None:
    """Refuse a path that is taken, as :func:`claim_output` does without ``overwrite``.

    For a caller that takes ``overwrite`` under another name and checks before recording:
    the error names it ``overwrite_option`` (``--overwrite`` on the command line). A path
    template with fields is left to :func:`claim_output` (its path is known only then).

    Raises:
        ConfigurationError: The path exists (a file, or a directory or device:
            :func:`check_output_path`), or is a bad template.
    """
    text = os.fspath(path_argument("path", path))
    template = PathTemplate(text)
    if template.fields:
        return
    resolved = Path(template.render(0))
    check_output_path(resolved)
    if os.path.lexists(resolved):
        raise _exists(resolved, overwrite_option)


def _indexed_overwrite(text: str, overwrite_option: str) -> ConfigurationError:
    """The error for ``overwrite`` with ``{index}``, naming the option ``overwrite_option``."""
    option = overwrite_option.split("=")[0]
    return ConfigurationError(
        f"path {text!r}: {overwrite_option} with {{index}}: the index always takes a free "
        f"path and never overwrites one; drop {option}, or use a path without {{index}}"
    )


def make_folder(path: Path) -> list[Path]:
    """Create the folder ``path`` goes in, with its parents, when it is missing.

    Returns the folders made (outermost first; :func:`remove_empty` takes them away again).
    A :class:`~episode_audit.errors.ConfigurationError` names ``path`` when it cannot be: one
    of the folders it is in is a file, or the OS refuses.
    """
    folder = path.parent
    if folder.is_dir():
        return []
    for above in (folder, *folder.parents):
        if above.is_dir():
            break
        if os.path.lexists(above):
            kind = output_kind(above) or ("a file" if above.is_file() else "a broken link")
            raise ConfigurationError(
                f"{path}: {above} is {kind}, not a folder; give a path in a folder"
            )
    made = [above for above in (folder, *folder.parents) if not above.exists()][::-1]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigurationError(
            f"{path}: cannot create its folder {folder}: {exc.strerror or exc}"
        ) from None
    return made


def remove_empty(made: list[Path]) -> None:
    """Remove the folders ``made`` (outermost first) that are empty, innermost first.

    What a failed command does with the folders it made for its output (:func:`make_folder`).
    """
    for folder in reversed(made):
        try:
            folder.rmdir()
        except OSError:  # not empty (something else was written there), or gone
            return


def _names_in(directory: str) -> frozenset[str]:
    """The names in ``directory`` now (skipped without a try; the claim itself is atomic)."""
    try:
        return frozenset(os.listdir(directory))
    except OSError:
        return frozenset()


_KINDS = {
    stat.S_IFDIR: "a directory",
    stat.S_IFIFO: "a FIFO (named pipe)",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFSOCK: "a socket",
}


def output_kind(path: str | os.PathLike[str]) -> str | None:
    """What ``path`` is if it exists and is not a regular file; ``None`` if it is one, or is not.

    >>> output_kind("/dev/null"), output_kind("/no/such/file")
    ('a character device', None)
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # no such file (opening it says why if it cannot be made)
        return None
    return None if stat.S_ISREG(mode) else _KINDS.get(stat.S_IFMT(mode), "a special file")


def check_output_path(path: str | os.PathLike[str]) -> None:
    """Refuse an evidence path that exists and is not a regular file.

    Opening a FIFO for writing waits for a reader (``--overwrite`` would hang), a device such as
    ``/dev/null`` swallows the evidence: a :class:`ConfigurationError` names the path instead.
    """
    kind = output_kind(path)
    if kind == "a directory":
        raise ConfigurationError(f"{path}: is a directory; give the evidence file's path")
    if kind is not None:
        raise ConfigurationError(
            f"{path}: is {kind}, not a regular file; give the evidence file's path"
        )


def _open_path(path: Path, overwrite: bool) -> Output:
    check_output_path(path)
    try:
        fd = os.open(path, _CREATE if overwrite else _CREATE | os.O_EXCL, 0o666)
    except FileExistsError:
        raise _exists(path) from None
    except OSError as exc:
        raise ConfigurationError(f"{path}: cannot create: {exc.strerror}") from None
    return _lock(path, fd, truncate=overwrite)


def _lock(path: Path, fd: int, *, truncate: bool) -> Output:
    """Lock the file open as ``fd`` (closed on failure), then truncate it if asked."""
    try:
        st = os.fstat(fd)
        key = (st.st_dev, st.st_ino)
        if _held_here(key):
            raise _held(path, Holder(os.getpid()))
        locked = _take(path, fd)
        if truncate and stat.S_ISREG(st.st_mode):
            os.ftruncate(fd, 0)
    except OSError as exc:
        os.close(fd)
        raise ConfigurationError(f"{path}: cannot open for writing: {exc.strerror}") from None
    except BaseException:
        os.close(fd)
        raise
    _HELD_HERE[key] = (os.getpid(), fd)
    return Output(path, fd, key, locked)


def _held_here(key: tuple[int, int]) -> bool:
    """Whether a recorder of this process writes the file ``key`` (its fd still open on it).

    The OS's lock says so too, except where the filesystem emulates it per process (NFS) or
    has none.
    """
    pid, fd = _HELD_HERE.get(key, (0, -1))
    if pid != os.getpid():
        return False
    try:
        st = os.fstat(fd)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == key


def _take(path: Path, fd: int) -> bool:
    """Take the lock (``False``: the OS has none here); a file another holds is refused.

    A reader probing the file holds a shared lock for microseconds: that is waited out.
    """
    for _ in range(_TRIES):
        try:
            if try_lock(fd):
                return True
        except OSError as exc:
            _warn_no_locks(path, exc)
            return False
        time.sleep(_PAUSE_S)
    raise _held(path, holder(fd))


def _warn_no_locks(path: Path, exc: OSError) -> None:
    global _warned_no_locks
    if not _warned_no_locks:
        _warned_no_locks = True
        warnings.warn(
            f"episode-audit: {path}: the filesystem cannot lock files ({exc.strerror}); "
            "recording anyway, but nothing stops a recorder in another process from writing "
            "the same file",
            RecorderTroubleWarning,
            stacklevel=2,
        )


def _held(path: Path, who: Holder) -> ConfigurationError:
    return ConfigurationError(
        f"{path}: another live recorder is writing this file ({who} holds its lock); a file "
        "has one writer — "
        "give each recorder its own path, e.g. the template 'runs/train-{index}.mcap'"
    )


def _exists(path: Path, overwrite_option: str = "overwrite=True") -> ConfigurationError:
    """The error for an existing file: held by a live recorder, or just there.

    ``overwrite_option`` is how the caller names ``overwrite`` (``--overwrite`` on the command
    line: :func:`refuse_existing`).
    """
    who = None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        pass
    else:
        try:
            who = probe(fd)
        finally:
            os.close(fd)
    if who is not None:
        return _held(path, who)
    template = f"{path.stem}-{{index}}{path.suffix}"
    option = overwrite_option
    if option == "overwrite=True":
        option += " (--overwrite on the command line)"
    return ConfigurationError(
        f"{path}: file exists; evidence is never overwritten — choose another path (the "
        f"template '{template}' takes the first free one), or pass {option}"
    )


class LockedStream:
    """The evidence file the writer writes: a binary file whose ``close()`` unlocks it first.

    Unlocking explicitly (not just closing) also releases the copies of the file a fork made.
    """

    def __init__(self, file: IO[bytes], output: Output) -> None:
        self._file = file
        self._output = output
        self.write = file.write
        self.tell = file.tell
        self.flush = file.flush
        self.fileno = file.fileno

    @property
    def closed(self) -> bool:
        """Whether the file is closed."""
        return self._file.closed

    def close(self) -> None:
        """Release the writer's lock, then close the file."""
        self._output.release()
        self._file.close()

    def close_copy(self) -> None:
        """Close this process's copy of the file, keeping the lock: a forked child's.

        The lock belongs to the open file the parent and the child share; closing the child's
        descriptor leaves it with the parent (unlocking would release it for both).
        """
        self._file.close()
