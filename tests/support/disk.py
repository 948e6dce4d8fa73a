"""A full disk for tests: the ``small_disk`` fixture's tmpfs (``tests/conftest.py``), filled."""

from __future__ import annotations

import os
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
