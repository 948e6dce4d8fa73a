"""PettingZoo's env ids, modules and registries: how a recorded env is named and rebuilt.

:func:`env_id_of` finds the registry id of an env (``classic/tictactoe-v3``), :func:`env_module_of`
its module (``pettingzoo.classic.tictactoe_v3``); replay rebuilds the env with
:func:`make_registered` when :func:`is_registered`, or imports the module only when
:func:`is_pettingzoo_module` (``docs/format.md``, "PettingZoo files"; ``docs/security.md``).
"""

from __future__ import annotations

import importlib.util
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pettingzoo

from ...errors import ConfigurationError

__all__ = [
    "KIND_AEC",
    "KIND_PARALLEL",
    "checked_env_id",
    "env_id_of",
    "env_module_of",
    "is_pettingzoo_module",
    "is_registered",
    "make_registered",
    "wrappers_of",
]

KIND_PARALLEL = "pettingzoo_parallel"
KIND_AEC = "pettingzoo_aec"
_MODULE_PATTERN = re.compile(r"^pettingzoo\.[a-z_]+\.[a-z0-9_]+_v\d+$")


def is_pettingzoo_module(name: str) -> bool:
    """Whether ``name`` is one of PettingZoo's own versioned env modules (safe to import).

    It must look like ``pettingzoo.<family>.<name>_v<N>`` and resolve to a file inside the
    installed ``pettingzoo`` package.

    >>> is_pettingzoo_module("pettingzoo.classic.tictactoe_v3")
    True
    >>> is_pettingzoo_module("os.path"), is_pettingzoo_module("pettingzoo.classic.nope_v1")
    (False, False)
    """
    if not _MODULE_PATTERN.match(name):
        return False
    try:
        spec = importlib.util.find_spec(name)
        root = importlib.util.find_spec("pettingzoo")
    except (ImportError, ValueError):
        return False
    if spec is None or spec.origin is None or root is None or root.origin is None:
        return False
    package = Path(root.origin).resolve().parent
    return package in Path(spec.origin).resolve().parents


def env_module_of(env: Any) -> str | None:
    """The PettingZoo env module (``pettingzoo.classic.tictactoe_v3``) ``env`` was made by.

    Found from the unwrapped env's class module (the family) and ``metadata["name"]``
    (``tictactoe_v3``); ``None`` when that does not name one of PettingZoo's own modules.
    """
    base = getattr(env, "unwrapped", env)
    name = (getattr(base, "metadata", None) or {}).get("name")
    parts = type(base).__module__.split(".")
    if not isinstance(name, str) or len(parts) < 2 or parts[0] != "pettingzoo":
        return None
    module = f"pettingzoo.{parts[1]}.{name}"
    return module if is_pettingzoo_module(module) else None


_MOST_WRAPPERS = 64


def wrappers_of(env: Any) -> list[str] | None:
    """The wrappers around ``env``'s unwrapped env, outermost first (``module.QualName`` each).

    PettingZoo's wrappers, its API conversions and a user's own alike: each layer down to
    ``env.unwrapped``, through ``env`` (``BaseWrapper``, ``BaseParallelWrapper``,
    ``parallel_to_aec_wrapper``) or ``aec_env`` (``aec_to_parallel_wrapper``). ``None`` when the
    chain cannot be read to its end (a layer that names no inner env, or past 64 layers).
    Never raises.

    >>> import pettingzoo
    >>> wrappers_of(pettingzoo.make("aec", "classic/tictactoe-v3"))[0]
    'pettingzoo.utils.wrappers.order_enforcing.OrderEnforcingWrapper'
    """
    try:
        base = env.unwrapped
        layers: list[str] = []
        while env is not base:
            if len(layers) >= _MOST_WRAPPERS:
                return None
            layers.append(f"{type(env).__module__}.{type(env).__qualname__}")
            inner = getattr(env, "env", None)
            env = inner if inner is not None else getattr(env, "aec_env", None)
            if env is None:
                return None
    except Exception:  # the env's own attributes
        return None
    return layers


def _registry(kind: str) -> Mapping[str, Any] | None:
    """PettingZoo's env registry for a layout ``kind`` (``None`` before PettingZoo 1.27)."""
    name = "parallel_registry" if kind == KIND_PARALLEL else "aec_registry"
    registry = getattr(pettingzoo, name, None)
    return registry if isinstance(registry, Mapping) else None


def _entry_module(spec: Any) -> str | None:
    entry = getattr(spec, "entry_point", None)
    if isinstance(entry, str):
        return entry.partition(":")[0]
    module = getattr(entry, "__module__", None)
    return module if isinstance(module, str) else None


def env_id_of(env: Any, kind: str) -> str | None:
    """The id under which PettingZoo's registry makes ``env`` (``classic/tictactoe-v3``).

    ``kind`` picks the registry (``pettingzoo_aec``: ``pettingzoo.aec_registry``, else
    ``parallel_registry``). The id is that of the one registered spec whose entry point lives in
    the module of the unwrapped env's class and whose name and version are the env's
    ``metadata["name"]`` (``tictactoe_v3``); ``None`` when there is no such spec, or more than
    one, or PettingZoo has no registry (before 1.27).

    >>> import pettingzoo
    >>> env = pettingzoo.make("aec", "classic/tictactoe-v3")
    >>> env_id_of(env, "pettingzoo_aec"), env_id_of(env, "pettingzoo_parallel")
    ('classic/tictactoe-v3', None)
    """
    registry = _registry(kind)
    base = getattr(env, "unwrapped", env)
    name = (getattr(base, "metadata", None) or {}).get("name")
    if registry is None or not isinstance(name, str):
        return None
    wanted = re.sub(r"_v(?=\d+$)", "-v", name)
    module = type(base).__module__
    found = [
        str(env_id)
        for env_id, spec in registry.items()
        if str(env_id).rpartition("/")[2] == wanted and _entry_module(spec) == module
    ]
    return found[0] if len(found) == 1 else None


def is_registered(kind: str, env_id: str) -> bool:
    """Whether ``env_id`` is registered, exactly, in this process's PettingZoo ``kind`` registry.

    A dictionary lookup: nothing is imported. ``False`` before PettingZoo 1.27 (no registry).

    >>> is_registered("pettingzoo_parallel", "classic/rps-v2")
    True
    >>> is_registered("pettingzoo_parallel", "classic/tictactoe-v3")  # an AEC-only env
    False
    """
    registry = _registry(kind)
    return registry is not None and env_id in registry


def make_registered(kind: str, env_id: str, kwargs: Mapping[str, Any]) -> Any:
    """``pettingzoo.make("parallel" | "aec", env_id, **kwargs)`` (PettingZoo 1.27+)."""
    return pettingzoo.make("parallel" if kind == KIND_PARALLEL else "aec", env_id, **kwargs)


def checked_env_id(env_id: str, kind: str) -> str:
    """The registered id ``env_id`` names (``classic/tictactoe`` -> ``classic/tictactoe-v3``)."""
    find = getattr(pettingzoo, "spec", None)
    if _registry(kind) is None or find is None:
        raise ConfigurationError(
            f"env_id={env_id!r}: this PettingZoo ({getattr(pettingzoo, '__version__', '?')}) "
            "has no env registry (PettingZoo 1.27+); leave env_id out"
        )
    try:
        spec = find("parallel" if kind == KIND_PARALLEL else "aec", env_id)
    except Exception as exc:
        api = "parallel" if kind == KIND_PARALLEL else "AEC"
        raise ConfigurationError(
            f"env_id={env_id!r} is not registered in PettingZoo's {api} registry "
            f"({type(exc).__name__}); register it with pettingzoo.register() first, "
            "or leave env_id out"
        ) from None
    return str(spec.id)
