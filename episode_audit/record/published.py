"""A file written whole, then published under its name: never half a file under that name.

:class:`Temporary` is the file to write: where the OS has them (Linux, ``O_TMPFILE``), an
unnamed file in the output's folder, linked into place once finished, so that a writer killed
midway (even by SIGKILL) leaves nothing behind; elsewhere a hidden named file next to the
output, removed on any error. A kill leaves that one behind and nothing removes it later: no
lock can mark it live (``recover``'s evidence writer takes the file's one ``flock`` itself), so
a sweep could not tell a killed writer's file from a live one's (docs/cli.md). Making one
creates the output's folder if it is missing and checks, before anything is written, that a
file can be created there: an output that cannot be written is one
:class:`~episode_audit.errors.ConfigurationError` naming it, not a failure after the work.
``recover`` and the viewer exports write their output through it.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigurationError
from .lock import make_folder, remove_empty

__all__ = ["Temporary", "fsync", "no_space", "publish"]

_EXISTS = "exists; pass overwrite=True to replace it"
"""What an existing output is told (after its path), by default."""

_NO_UNNAMED_FILES = frozenset({errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL})
"""``O_TMPFILE`` refused because the file system (``EOPNOTSUPP``) or the kernel (``EISDIR``,
``EINVAL``) has no unnamed files: a named temporary file instead."""


def fsync(path: Path) -> None:
    """Flush ``path``'s data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def publish(tmp: Path, dst: Path, overwrite: bool, exists: str = _EXISTS) -> None:
    """Move the finished ``tmp`` to ``dst`` atomically; never over a file unless asked.

    ``exists``: what the error for an existing ``dst`` says after its path.
    """
    link: Callable[[Path, Path], None] = os.replace if overwrite else os.link
    try:
        link(tmp, dst)
    except FileExistsError:
        raise ConfigurationError(f"{dst}: {exists}") from None
    except OSError as exc:
        if overwrite or dst.exists():
            raise ConfigurationError(f"{dst}: cannot write: {exc.strerror}") from None
        os.replace(tmp, dst)  # a file system without hard links
    _sync_dir(dst.parent)


def _sync_dir(directory: Path) -> None:
    """Flush a directory's entries to the disk, where the OS allows it."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})
"""A write refused because the disk is full, or the user's quota used up."""


def no_space(dst: Path, exc: BaseException) -> ConfigurationError | None:
    """The error naming ``dst`` for ``exc``, raised writing it, when its disk has no space left.

    ``exc`` says so by its ``errno`` (``OSError``, pyarrow's too); one without (a library's
    own I/O error, as foxglove-sdk's) does when the disk ``dst`` is on has no block left for
    this user. ``None``: ``exc`` is something else.
    """
    code = getattr(exc, "errno", None)
    if code is None and _disk_full(dst.parent):
        code = errno.ENOSPC
    if code not in _NO_SPACE:
        return None
    return ConfigurationError(
        f"{dst}: cannot write it: {os.strerror(code)}; free some space there or choose "
        "another output path"
    )


def _disk_full(folder: Path) -> bool:
    """Whether the disk ``folder`` is on has no block left for this user."""
    try:
        return os.statvfs(folder).f_bavail == 0
    except (OSError, AttributeError):  # (AttributeError: no statvfs, Windows)
        return False


def _unwritable(dst: Path, exc: OSError) -> ConfigurationError:
    return ConfigurationError(
        f"{dst}: cannot create a file in {dst.parent}: {exc.strerror or exc}; give a path in a "
        "folder you can write to"
    )


class Temporary:
    """The file written before it is published as ``dst``.

    Made before the work starts: ``dst``'s folder is created if missing, and a file that cannot
    be created there raises :class:`~episode_audit.errors.ConfigurationError` naming ``dst``.
    ``exists``: what the error for an existing ``dst`` says after its path; ``suffix``: the
    end of a named temporary file's name (``.NAME.XXXXXXXX<suffix>``, hidden).

    Attributes:
        path: Where to write and read it (``/proc/self/fd/N`` for an unnamed file); it exists,
            empty.
        unnamed: Whether it has no name yet (nothing to clean up if the process dies).
    """

    def __init__(self, dst: Path, *, exists: str = _EXISTS, suffix: str = ".partial") -> None:
        self.dst, self._exists, self._suffix = dst, exists, suffix
        self._made = make_folder(dst)  # (removed again by discard() unless published)
        self._published = False
        self._fd: int | None = None
        flag = getattr(os, "O_TMPFILE", 0)
        if flag and Path("/proc/self/fd").is_dir():
            try:  # (the mode as for any new file: the umask applies)
                self._fd = os.open(dst.parent, flag | os.O_RDWR | os.O_CLOEXEC, 0o666)
            except OSError as exc:
                if exc.errno not in _NO_UNNAMED_FILES:
                    raise _unwritable(dst, exc) from None
        self.unnamed = self._fd is not None
        if self._fd is not None:
            self.path = Path(f"/proc/self/fd/{self._fd}")
        else:  # created now, so that an output folder that refuses files is said before the work
            self.path = self._named()
            try:
                os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            except OSError as exc:
                raise _unwritable(dst, exc) from None

    def _named(self) -> Path:
        return self.dst.with_name(f".{self.dst.name}.{secrets.token_hex(4)}{self._suffix}")

    def publish(self, overwrite: bool) -> None:
        """Flush the finished file to the disk and give it its name, ``dst``, atomically.

        A disk with no space left is a :class:`~episode_audit.errors.ConfigurationError`
        naming ``dst`` (:func:`no_space`).
        """
        try:
            fsync(self.path)
        except OSError as exc:
            raise no_space(self.dst, exc) or exc from None
        self._publish(overwrite)
        self._published = True

    def _publish(self, overwrite: bool) -> None:
        if self._fd is None:
            publish(self.path, self.dst, overwrite, self._exists)
            return
        if not overwrite:
            try:
                self._link(self.dst)
            except FileExistsError:
                raise ConfigurationError(f"{self.dst}: {self._exists}") from None
            except OSError:
                pass  # linking an unnamed file is refused here: through a named one
            else:
                _sync_dir(self.dst.parent)
                return
        # (no call links an unnamed file over an existing one: a name first, renamed at once)
        named = self._named()
        try:
            try:
                self._link(named)
            except OSError:
                shutil.copyfile(self.path, named)
                fsync(named)
            publish(named, self.dst, overwrite, self._exists)
        except OSError as exc:
            raise ConfigurationError(f"{self.dst}: cannot write: {exc.strerror}") from None
        finally:
            named.unlink(missing_ok=True)

    def _link(self, target: Path) -> None:
        """Give the unnamed file the name ``target`` (``linkat`` following its /proc link)."""
        proc = os.open("/proc/self/fd", os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.link(str(self._fd), target, src_dir_fd=proc, follow_symlinks=True)
        finally:
            os.close(proc)

    def discard(self) -> None:
        """Remove the file (published or not: its name is ``dst`` then).

        Unpublished, the folders made for ``dst`` go too when nothing else is in them.
        """
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        elif not self.unnamed:
            self.path.unlink(missing_ok=True)
        if not self._published:
            remove_empty(self._made)
