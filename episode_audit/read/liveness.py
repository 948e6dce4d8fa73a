"""Whether a live recorder is still writing an evidence file, from its writer's lock.

A recorder holds its file's lock until ``close()`` (:mod:`episode_audit.format.locking`); the
lock dies with the process, so a file without a summary whose lock nobody holds was torn by a
crash, and one whose lock is held is still being written. :func:`writer_of` looks without
waiting and lets go at once: reading never blocks or disturbs the writer.
"""

from __future__ import annotations

import os

from ..format.locking import Holder, probe

__all__ = ["Holder", "probe", "still_written", "writer_of"]


def writer_of(path: str | os.PathLike[str]) -> Holder | None:
    """The live recorder writing ``path`` (its process), or ``None`` (none, or no such file)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        return probe(fd)
    finally:
        os.close(fd)


def still_written(writer: Holder) -> str:
    """How a message says a file is still being written.

    >>> still_written(Holder(4242))
    'still being written by pid 4242'
    """
    return f"still being written by {writer}"
