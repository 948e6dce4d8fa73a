"""The public API's arguments that name files, columns and episodes, checked once.

:func:`path_list` takes one path or many (a bare ``str`` is one path, never its characters;
each is a path argument, :func:`~episode_audit.format.paths.path_argument`);
:func:`name_list` refuses a bare ``str`` where a list of names is expected; :func:`episode_index`
and :func:`episode_indices` refuse what is not an episode index; :func:`non_negative` what is not
a finite number >= 0 (a tolerance, a limit). Each raises
:class:`~episode_audit.errors.ConfigurationError` naming the argument as the caller calls it.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterable
from typing import Any, TypeVar

from ..errors import ConfigurationError
from ..format.paths import path_argument
from ..format.records import episode_index_problem

__all__ = ["episode_index", "episode_indices", "name_list", "non_negative", "path_list"]

_P = TypeVar("_P", bound="str | os.PathLike[str]")


def path_list(paths: _P | Iterable[_P], name: str = "paths") -> list[_P]:
    """``paths`` as a list: one ``str`` or path-like is one path, an iterable is its paths.

    Each path is checked (:func:`~episode_audit.format.paths.path_argument`); errors name the
    argument ``name`` (an item as ``name[i]``).

    >>> path_list("runs/run.mcap"), path_list(["a.mcap", "b.mcap"])
    (['runs/run.mcap'], ['a.mcap', 'b.mcap'])
    >>> path_list(["a.mcap", None], "baseline")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: baseline[1]: expected a path (a str or \
pathlib.Path), got None (NoneType); pass a file's path, e.g. 'runs/run.mcap'
    """
    if isinstance(paths, (str, os.PathLike)):
        return [path_argument(name, paths)]
    if isinstance(paths, bytes) or not isinstance(paths, Iterable):
        raise ConfigurationError(
            f"{name}: expected a path or a list of paths, got {type(paths).__name__}; "
            "pass e.g. ['runs/run.mcap']"
        )
    return [path_argument(f"{name}[{i}]", path) for i, path in enumerate(paths)]


def name_list(name: str, names: Iterable[str]) -> list[str]:
    """``names`` as a list of ``str``; a bare ``str`` is refused, not split into characters.

    >>> name_list("columns", ("reward", "action"))
    ['reward', 'action']
    >>> try:
    ...     name_list("columns", "reward")
    ... except ConfigurationError as exc:
    ...     print(exc)
    columns: expected a list of names, got the string 'reward'; pass ['reward']
    """
    if isinstance(names, (str, bytes)):
        raise ConfigurationError(
            f"{name}: expected a list of names, got the string {names!r}; pass [{names!r}]"
        )
    if not isinstance(names, Iterable):
        raise ConfigurationError(
            f"{name}: expected a list of names, got {type(names).__name__}; pass e.g. ['reward']"
        )
    out = list(names)
    for i, item in enumerate(out):
        if not isinstance(item, str):
            raise ConfigurationError(
                f"{name}[{i}]: expected a name (a str), got {item!r} ({type(item).__name__})"
            )
    return out


def episode_index(name: str, index: Any) -> int:
    """``index`` if it is an episode index: an ``int`` (not a ``bool``) in ``0 .. 2**63 - 1``.

    >>> episode_index("episode", 3)
    3
    >>> try:
    ...     episode_index("episode", "3")
    ... except ConfigurationError as exc:
    ...     print(exc)
    episode: expected an episode index >= 0 (an int), got '3' (str)
    """
    if not isinstance(index, numbers.Integral) or isinstance(index, bool):
        raise ConfigurationError(
            f"{name}: expected an episode index >= 0 (an int), got {index!r} "
            f"({type(index).__name__})"
        )
    problem = episode_index_problem(int(index))
    if problem is not None:
        raise ConfigurationError(f"{name}: {problem}")
    return int(index)


def episode_indices(name: str, indices: Iterable[Any]) -> list[int]:
    """``indices`` as a list of episode indices (:func:`episode_index`), in the order given.

    >>> episode_indices("episodes", (3, 1))
    [3, 1]
    >>> try:
    ...     episode_indices("episodes", "1")
    ... except ConfigurationError as exc:
    ...     print(exc)
    episodes: expected a list of episode indices, got '1'; pass e.g. [0, 3]
    """
    if isinstance(indices, (str, bytes)) or not isinstance(indices, Iterable):
        raise ConfigurationError(
            f"{name}: expected a list of episode indices, got {indices!r}; pass e.g. [0, 3]"
        )
    return [episode_index(name, index) for index in indices]


def non_negative(name: str, value: Any) -> float:
    """``value`` when it is a finite number >= 0 (a bool is not one), else raise.

    >>> non_negative("atol", 0.5)
    0.5
    >>> non_negative("--atol", float("nan"))
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: --atol: expected a finite number >= 0, got nan
    """
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (number and math.isfinite(value) and value >= 0):
        raise ConfigurationError(f"{name}: expected a finite number >= 0, got {value!r}")
    return value  # type: ignore[no-any-return]
