"""A path argument: what the API takes as the name of a file, checked once.

:func:`path_argument` takes a non-empty ``str`` or ``os.PathLike`` of ``str`` (a
``pathlib.Path``, a URL string) and refuses anything else with a
:class:`~episode_audit.errors.ConfigurationError` naming the argument as the caller calls it:
``bytes``, ``None``, a number, a list where one path is expected, and ``""`` (which
``pathlib.Path`` would take as the current folder). The recorders and every reading function
call it on each path they are given.
"""

from __future__ import annotations

import os
import reprlib
from typing import TypeVar

from ..errors import ConfigurationError

__all__ = ["path_argument"]

_P = TypeVar("_P", bound="str | os.PathLike[str]")

_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxother = 60
_PASS = "pass a file's path, e.g. 'runs/run.mcap'"


def path_argument(name: str, path: _P) -> _P:
    """``path`` when it names a file: a non-empty ``str`` or ``os.PathLike`` of ``str``.

    >>> path_argument("path", "runs/run.mcap")
    'runs/run.mcap'
    >>> path_argument("paths[1]", b"runs/run.mcap")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: paths[1]: expected a path (a str or pathlib.Path), \
got b'runs/run.mcap' (bytes); pass a file's path, e.g. 'runs/run.mcap'
    >>> path_argument("paths", "")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: paths: expected a path, got an empty string; pass \
a file's path, e.g. 'runs/run.mcap'
    """
    given: object = path  # (typed as a path; at run time, whatever the caller passed)
    text = os.fspath(given) if isinstance(given, (str, os.PathLike)) else None
    if not isinstance(text, str):
        raise ConfigurationError(
            f"{name}: expected a path (a str or pathlib.Path), got {_SHOWN.repr(path)} "
            f"({type(path).__name__}); {_PASS}"
        )
    if not text:
        raise ConfigurationError(f"{name}: expected a path, got an empty string; {_PASS}")
    return path
