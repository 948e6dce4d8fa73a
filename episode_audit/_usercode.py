"""Import the code a user names: ``--import``, ``--env-factory``, ``--policy``.

The only place that imports by a computed name, and only names given as arguments, never
strings read from a file (see ``docs/security.md``).
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from .errors import ConfigurationError
from .format.columns import error_text

__all__ = ["import_modules", "load_callable"]


def load_callable(spec: str) -> Callable[..., Any]:
    """Import ``"module:attribute"`` (given by the user, never by a file) and return it.

    >>> import gymnasium
    >>> load_callable("gymnasium:make") is gymnasium.make
    True
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigurationError(f"expected MODULE:CALLABLE, actually: {spec!r}")
    try:
        target: Any = _import(module_name)
        for part in attr.split("."):
            target = getattr(target, part)
    except (ImportError, AttributeError) as exc:
        raise ConfigurationError(f"cannot load {spec!r}: {exc}") from None
    if not callable(target):
        raise ConfigurationError(f"{spec!r} is not callable")
    return target  # type: ignore[no-any-return]


def import_modules(modules: Sequence[str], *, option: str = "imports") -> None:
    """Import each module the user named (e.g. one that registers envs).

    Anything that goes wrong — no such module, an empty name, a module that raises on import —
    is a :class:`~episode_audit.errors.ConfigurationError` naming the module and ``option``,
    where the user named it: the library's ``imports=`` argument, the command's ``--import``.

    >>> try:
    ...     import_modules(["no_such_module_here"])
    ... except ConfigurationError as exc:
    ...     print(exc)
    imports 'no_such_module_here': ModuleNotFoundError: No module named 'no_such_module_here'
    """
    for module in modules:
        try:
            _import(module)
        except Exception as exc:
            raise ConfigurationError(f"{option} {module!r}: {error_text(exc)}") from None


def _import(name: str) -> Any:
    """Import module ``name``; one not found is looked for in the current folder too.

    As ``python -m`` and pytest do: ``episode-audit replay ... --env-factory test_reach:make``
    run beside ``test_reach.py`` finds it. The folder goes last on ``sys.path``, so it
    shadows no installed module.
    """
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        here = os.getcwd()
        if exc.name != name.partition(".")[0] or here in sys.path or "" in sys.path:
            raise
        sys.path.append(here)
        return importlib.import_module(name)
