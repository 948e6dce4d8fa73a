"""The writer's lock: how an evidence file says a recorder is still writing it.

A recorder holds an exclusive ``flock`` on its file from before its first byte until
``close()``; the lock dies with the process, so a crashed writer leaves an unlocked file
(``docs/format.md``, "Crash safety and the writer's lock"). ``flock`` locks belong to an open
file, not a process: two opens conflict even within one process.

- :func:`try_lock` — take the lock (or a reader's shared probe) without waiting.
- :func:`probe` — a reader's look: who writes the file now, if anyone; never blocks.
- :class:`Holder` — the process holding a lock, named where the OS says (Linux: /proc/locks).
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - no flock on this platform (Windows)
    fcntl = None  # type: ignore[assignment]

__all__ = ["Holder", "holder", "probe", "try_lock", "unlock"]

_HELD = frozenset({errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES})
_PROC_LOCKS = Path("/proc/locks")


@dataclass(frozen=True)
class Holder:
    """The process holding a file's writer lock: ``pid`` when the OS says, else ``None``."""

    pid: int | None

    def __str__(self) -> str:
        if self.pid is None:
            return "another process (the OS does not say which)"
        if self.pid == os.getpid():
            return f"this process (pid {self.pid})"
        return f"pid {self.pid}"


def try_lock(fd: int, *, shared: bool = False) -> bool:
    """Take the lock on the file open as ``fd`` without waiting; ``False`` if another holds it.

    Raises:
        OSError: The platform or the filesystem has no such locks (e.g. ``ENOLCK``).
    """
    if fcntl is None:  # pragma: no cover - Windows
        raise OSError(errno.ENOSYS, "this platform has no flock")
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in _HELD:
            return False
        raise
    return True


def unlock(fd: int) -> None:
    """Release the lock on ``fd`` (for every copy of it a fork made); never raises."""
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        except OSError:
            pass


def probe(fd: int) -> Holder | None:
    """Who holds the writer lock of the file open as ``fd``; ``None`` if nobody (or unknown).

    A shared lock taken without waiting and released at once: it never blocks, and a writer
    already holding its lock never notices it.
    """
    try:
        if try_lock(fd, shared=True):
            unlock(fd)
            return None
    except OSError:
        return None
    return holder(fd)


def holder(fd: int) -> Holder:
    """The process holding an exclusive ``flock`` on the file open as ``fd``, from /proc/locks.

    Lines read ``1: FLOCK  ADVISORY  WRITE 4242 fe:00:2146482 0 EOF`` (device major and minor
    in hex, inode in decimal). The device must match too unless only the inode does (an
    overlay filesystem reports its own device).
    """
    try:
        st = os.fstat(fd)
        text = _PROC_LOCKS.read_text()
    except OSError:
        return Holder(None)
    device = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}"
    exact: set[int] = set()
    inode_only: set[int] = set()
    for line in text.splitlines():
        parts = line.split()
        if len(parts) < 6 or parts[1:4] != ["FLOCK", "ADVISORY", "WRITE"]:
            continue  # (a waiter's line reads "-> FLOCK ...")
        where = parts[5].rsplit(":", 1)
        if len(where) != 2 or where[1] != str(st.st_ino) or not parts[4].isdigit():
            continue
        (exact if where[0] == device else inode_only).add(int(parts[4]))
    pids = (exact or inode_only) - {0}  # (0: a process outside this pid namespace)
    return Holder(pids.pop() if len(pids) == 1 else None)
