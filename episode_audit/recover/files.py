"""The output of a recovery: its path checked first, then moved into place atomically.

It is written to a :class:`Temporary`: where the OS has them (Linux, ``O_TMPFILE``), an
unnamed file in the output's directory, linked into place once finished, so that a recovery
killed midway (even by SIGKILL) leaves nothing behind; elsewhere a hidden named file next to
the output, removed on any error.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigurationError

__all__ = ["Temporary", "check_paths", "fsync", "publish"]

_EXISTS = (
    "file exists; recovery never overwrites it — choose another path or pass overwrite=True "
    "(--overwrite)"
)


def check_paths(src: Path, dst: Path, overwrite: bool) -> None:
    """Refuse an output that is the input, a directory or device, or exists (``overwrite``)."""
    same = src.resolve() == dst.resolve()
    if not same and dst.exists() and src.exists():
        same = os.path.samefile(src, dst)
    if same:
        raise ConfigurationError(
            f"{dst}: the output is the input; recovery never rewrites a file in place — "
            "choose another output path"
        )
    if dst.is_dir():
        raise ConfigurationError(f"{dst}: is a directory; give the output file's path")
    if dst.exists() and not dst.is_file():
        raise ConfigurationError(
            f"{dst}: not a regular file (a device or a pipe); give the output file's path"
        )
    if dst.exists() and not overwrite:
        raise ConfigurationError(f"{dst}: {_EXISTS}")


def fsync(path: Path) -> None:
    """Flush ``path``'s data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def publish(tmp: Path, dst: Path, overwrite: bool) -> None:
    """Move the finished ``tmp`` to ``dst`` atomically; never over a file unless asked."""
    link: Callable[[Path, Path], None] = os.replace if overwrite else os.link
    try:
        link(tmp, dst)
    except FileExistsError:
        raise ConfigurationError(f"{dst}: {_EXISTS}") from None
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


class Temporary:
    """The file a recovery writes before it is published as ``dst``.

    Attributes:
        path: Where to write and read it (``/proc/self/fd/N`` for an unnamed file).
        unnamed: Whether it has no name yet (nothing to clean up if the process dies).
    """

    def __init__(self, dst: Path) -> None:
        self.dst = dst
        self._fd: int | None = None
        flag = getattr(os, "O_TMPFILE", 0)
        if flag and Path("/proc/self/fd").is_dir():
            try:  # (the mode as for any new file: the umask applies)
                self._fd = os.open(dst.parent, flag | os.O_RDWR, 0o666)
            except OSError:  # a file system without unnamed files: a named one instead
                self._fd = None
        self.unnamed = self._fd is not None
        self.path = (
            Path(f"/proc/self/fd/{self._fd}")
            if self._fd is not None
            else dst.with_name(f".{dst.name}.{secrets.token_hex(4)}.recovering")
        )

    def publish(self, overwrite: bool) -> None:
        """Flush the finished file to the disk and give it its name, ``dst``, atomically."""
        fsync(self.path)
        if self._fd is None:
            publish(self.path, self.dst, overwrite)
            return
        if not overwrite:
            try:
                self._link(self.dst)
            except FileExistsError:
                raise ConfigurationError(f"{self.dst}: {_EXISTS}") from None
            except OSError:
                pass  # linking an unnamed file is refused here: through a named one
            else:
                _sync_dir(self.dst.parent)
                return
        # (no call links an unnamed file over an existing one: a name first, renamed at once)
        named = self.dst.with_name(f".{self.dst.name}.{secrets.token_hex(4)}.recovering")
        try:
            try:
                self._link(named)
            except OSError:
                shutil.copyfile(self.path, named)
                fsync(named)
            publish(named, self.dst, overwrite)
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
        """Remove the file (published or not: its name is ``dst`` then)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        elif not self.unnamed:
            self.path.unlink(missing_ok=True)
