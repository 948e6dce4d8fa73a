"""A pipe a viewer library's file writer writes into, copied to the output file by a thread.

rerun-sdk's file writer ends its thread when a write fails (a full disk), and a flush asked
for at that moment can then wait forever (rerun-sdk 0.41: one export in about ten on a disk
that fills midway). A pipe is never full for good, so the library's writes do not fail; this
module's thread copies what comes out of it to the file, and a failed write of its own is
raised by :meth:`CopiedPipe.check` and :meth:`CopiedPipe.close`, as an ``OSError``.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

__all__ = ["CopiedPipe"]

_CHUNK = 1 << 20


class CopiedPipe:
    """What is written to :attr:`path` ends up in ``out``, an existing file (from its start).

    Where the OS has no ``/proc/self/fd`` (macOS, Windows), :attr:`path` is ``out`` itself, and
    nothing is copied.

    >>> import tempfile
    >>> out = Path(tempfile.mkdtemp()) / "out.bin"
    >>> out.touch()  # (an existing file: the export's temporary one)
    >>> copy = CopiedPipe(out)
    >>> with open(copy.path, "wb") as library:  # (a library's file writer)
    ...     _ = library.write(b"rrd bytes")
    >>> copy.close()
    >>> out.read_bytes()
    b'rrd bytes'
    """

    def __init__(self, out: Path) -> None:
        self.path = str(out)
        """Where the library writes."""
        self.error: OSError | None = None
        """The copy's failed write (the copy then only drains the pipe)."""
        self._thread: threading.Thread | None = None
        if not Path("/proc/self/fd").is_dir():
            return
        self._out = os.open(out, os.O_WRONLY | os.O_TRUNC | os.O_CLOEXEC)
        self._read, self._write = os.pipe()
        self.path = f"/proc/self/fd/{self._write}"
        self._thread = threading.Thread(target=self._copy, name="episode-audit copy", daemon=True)
        self._thread.start()

    def opened(self) -> None:
        """Say that the library opened :attr:`path`: the pipe's end then is the library's alone.

        The copy ends when the library closes its end (a pipe's reader sees its end only when
        every writer closed theirs).
        """
        if self._thread is not None and self._write >= 0:
            os.close(self._write)
            self._write = -1

    def check(self) -> None:
        """Raise the copy's failed write, if there was one."""
        if self.error is not None:
            raise self.error

    def close(self) -> None:
        """Wait for the copy to finish (the library closed its end), then :meth:`check`."""
        if self._thread is None:
            return
        self.opened()  # (if the library never opened it: its end is closed now)
        self._thread.join()
        self._thread = None
        os.close(self._read)
        os.close(self._out)
        self.check()

    def _copy(self) -> None:
        while chunk := os.read(self._read, _CHUNK):
            view = memoryview(chunk)
            while self.error is None and view:
                try:
                    view = view[os.write(self._out, view) :]
                except OSError as exc:  # (kept for check(); the pipe is drained still)
                    self.error = exc
