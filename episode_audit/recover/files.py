"""The output of a recovery: its path checked first, then moved into place atomically.

It is written to a :class:`Temporary` (:mod:`episode_audit.record.published`): where the OS
has them (Linux, ``O_TMPFILE``), an unnamed file in the output's directory, linked into place
once finished, so that a recovery killed midway (even by SIGKILL) leaves nothing behind;
elsewhere a hidden named file next to the output (``.NAME.XXXXXXXX.recovering``), removed on any
error. :func:`temporary` makes it.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import ConfigurationError
from ..record.published import Temporary

__all__ = ["Temporary", "check_paths", "exists", "temporary"]


def exists(option: str) -> str:
    """What the error for an existing output says after its path.

    ``option`` names ``overwrite`` as the caller calls it (``--overwrite`` on the command line).
    """
    return f"file exists; recovery never overwrites it — choose another path or pass {option}"


def check_paths(src: Path, dst: Path, overwrite: bool, option: str = "overwrite=True") -> None:
    """Refuse an output that is the input, a directory or device, or exists.

    ``overwrite`` allows an existing output; the error names it ``option``.
    """
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
        raise ConfigurationError(f"{dst}: {exists(option)}")


def temporary(dst: Path, option: str = "overwrite=True") -> Temporary:
    """The file a recovery into ``dst`` writes before it is published (``dst``'s folder made)."""
    return Temporary(dst, exists=exists(option), suffix=".recovering")
