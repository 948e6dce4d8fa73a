"""The file under the MCAP writer: bytes staged in memory, handed to the OS whole or not at all.

:class:`StagedFile` takes every write of ``mcap.Writer`` into memory; :meth:`StagedFile.commit`
writes them to the file at the end of the last good commit. When the OS refuses part of them (a
full disk, a file size limit), the file is cut back to that end with ``ftruncate``, so it always
ends on a record boundary, and the bytes stay staged for the next commit to retry.
"""

from __future__ import annotations

import errno
import os
from typing import IO

__all__ = ["StagedFile"]


class StagedFile:
    """A write-only stream for ``mcap.Writer`` over ``f`` (opened unbuffered, ``buffering=0``).

    ``tell()`` is where the next byte will land once committed, so the offsets the MCAP writer
    records (chunk and message indexes) are the file's.
    """

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f
        self._fd = f.fileno()
        self.good = 0
        """Bytes of the file known to be whole: it ends on a record boundary there."""
        self._staged: list[bytes | memoryview] = []
        self.staged_bytes = 0
        """Bytes written by the MCAP writer since the last commit."""
        self.broken = False
        """Whether the file could not be cut back after a failed write (its end is unknown)."""

    def write(self, data: bytes | memoryview) -> int:
        """Stage ``data`` (the MCAP writer's records); returns its length."""
        if data:
            self._staged.append(data)
            self.staged_bytes += len(data)
        return len(data)

    def tell(self) -> int:
        """The file offset the next staged byte will have."""
        return self.good + self.staged_bytes

    def flush(self) -> None:
        """Nothing: bytes reach the file by :meth:`commit` only."""

    def commit(self, fsync: bool) -> None:
        """Write the staged bytes (then ``fsync`` if asked); on failure cut the file back.

        Raises the ``OSError`` of the failed write or fsync; the file then ends where it ended
        before (or, if even cutting it back failed, :attr:`broken` is set) and the bytes stay
        staged.
        """
        if not self._staged:
            return
        try:
            for piece in self._staged:
                view = memoryview(piece)
                while view:
                    written = self._f.write(view)
                    if not written:  # (a regular file never does this; a full one may)
                        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                    view = view[written:]
            if fsync:
                os.fsync(self._fd)
        except OSError:
            try:
                self.restore()
            except OSError:
                self.broken = True
            raise
        self.good += self.staged_bytes
        self.drop()

    def restore(self) -> None:
        """Cut the file back to :attr:`good` and write from there (raises ``OSError``)."""
        os.ftruncate(self._fd, self.good)
        os.lseek(self._fd, self.good, os.SEEK_SET)

    def drop(self) -> None:
        """Forget the staged bytes."""
        self._staged = []
        self.staged_bytes = 0

    def close(self) -> None:
        """Close the file."""
        self._f.close()
