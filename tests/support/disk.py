"""A full disk for tests: the ``small_disk`` fixture's tmpfs (``tests/conftest.py``), filled."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def fill_disk(folder: Path) -> Path:
    """Fill the disk ``folder`` is on (the ``small_disk`` fixture's); the filler file, to unlink."""
    filler = folder / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b"\0" * 4096):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)
    return filler


def export_stderr(source: Path, to: str, out: Path) -> tuple[int, str]:
    """``episode-audit export SOURCE --to TO -o OUT`` in a process of its own: exit code, stderr.

    Its own process: a viewer library's lines on the process's stderr are in it too. Wide
    (``COLUMNS``): the error is one line however long its path.
    """
    command = [sys.executable, "-m", "episode_audit", "export", str(source), "--to", to]
    done = subprocess.run(
        [*command, "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
        env={**os.environ, "COLUMNS": "1000"},
    )
    return done.returncode, done.stderr
