"""The ``episode-audit replay`` command a contract violation names, runnable as printed.

A factory case is replayed with ``--env-factory MODULE:CALLABLE``, which the CLI imports (from
the installed packages, or the current folder). A factory defined in the script being run has
the module ``__main__``, which the CLI cannot import: the command names the script's module
instead when the CLI surely finds it there (the script run as ``python -m pkg.mod``, or a
``name.py`` in the current folder that no installed module shadows), else the placeholder and
what to do.
"""

from __future__ import annotations

import keyword
import sys
from importlib.machinery import PathFinder
from pathlib import Path
from typing import Any

__all__ = ["replay_command"]

_PLACEHOLDER = "--env-factory MODULE:CALLABLE"


def replay_command(env: Any, env_kwargs: Any, path: Path) -> str:
    """The command replaying ``path``, a case's file recorded with ``env`` (an id or factory)."""
    command = f"episode-audit replay {path}"
    if isinstance(env, str):
        return command
    module = getattr(env, "__module__", None)
    name = getattr(env, "__qualname__", "")
    if env_kwargs or not module or "<" in name:
        return f"{command} {_PLACEHOLDER} (a callable building the env)"
    if module == "__main__":
        module = main_module_name()
        if module is None:
            return (
                f"{command} {_PLACEHOLDER} ({name} is defined in the script being run, which "
                "the CLI cannot import: put it in an importable module)"
            )
    return f"{command} --env-factory {module}:{name}"


def main_module_name() -> str | None:
    """The name the CLI imports the running script (``__main__``) by, if it surely can.

    ``pkg.mod`` for ``python -m pkg.mod``; ``name`` for ``python name.py`` run in the current
    folder, when ``name`` is a module name no installed module (or built-in one) shadows;
    ``None`` otherwise (``python -c``, a notebook, a script in another folder).
    """
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    if spec is not None:
        named = getattr(spec, "name", None)
        return named if isinstance(named, str) and named != "__main__" else None
    file = getattr(main, "__file__", None)
    if not isinstance(file, str):
        return None
    script = Path(file).resolve()
    stem = script.stem
    if script.suffix != ".py" or not stem.isidentifier() or keyword.iskeyword(stem):
        return None
    if script.parent != Path.cwd().resolve() or stem in sys.builtin_module_names:
        return None
    elsewhere = [p for p in sys.path if p and Path(p).resolve() != script.parent]
    return None if PathFinder.find_spec(stem, elsewhere) is not None else stem
