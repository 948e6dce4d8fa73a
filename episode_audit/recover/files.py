"""The output of a recovery: its path checked first, then moved into place atomically."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigurationError

__all__ = ["check_paths", "fsync", "publish"]

_EXISTS = "file exists; recovery never overwrites it — choose another path or pass --overwrite"


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
    try:
        fd = os.open(dst.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
