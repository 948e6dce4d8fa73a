"""Values of an env spec that JSON cannot hold, and the placeholder a file keeps for each.

A wrapper made with a function (``TransformReward(env, lambda r: ...)``) or an env made with an
object argument has a spec ``EnvSpec.to_json`` refuses. The recorder then keeps the spec with
each such value replaced by a placeholder, ``{"episode_audit.unrecorded": DESCRIPTION}``
(:func:`placeholder`), so the file still says the env id, its other arguments, its time limit
and its wrappers; replay refuses to build anything from a placeholder (:func:`unrecorded`).

>>> held = placeholder(lambda r: r * 2)
>>> held
{'episode_audit.unrecorded': 'function episode_audit.format.unrecorded:<lambda>'}
>>> unrecorded(held), unrecorded(3)
('function episode_audit.format.unrecorded:<lambda>', None)
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Final

import numpy as np

__all__ = ["UNRECORDED", "placeholder", "placeholders", "spec_placeholders", "unrecorded"]

UNRECORDED: Final = "episode_audit.unrecorded"
"""The key of a placeholder: its value describes what was not recorded."""


def placeholder(value: Any) -> dict[str, str]:
    """The placeholder of ``value``: its type and, for a function or class, its name.

    No memory address (an object's ``repr`` has one): two runs of the same code give the same
    placeholder, so ``compare`` finds their arguments alike.
    """
    kind = type(value).__qualname__
    name = getattr(value, "__qualname__", None)
    module = getattr(value, "__module__", None)
    described = f"{kind} {module}:{name}" if isinstance(name, str) and module else kind
    return {UNRECORDED: described[:200]}


def placeholders(
    kwargs: Mapping[str, Any], *, dtype_names: bool = False
) -> tuple[dict[str, Any], list[str]]:
    """``kwargs`` with each value JSON cannot hold replaced by its :func:`placeholder`.

    Also returns the names of the arguments replaced. With ``dtype_names``, a numpy dtype
    (``np.float32``, ``np.dtype("uint8")``) is its name instead, which a wrapper of
    Gymnasium's takes as well (``DtypeObservation(env, "float32")``).

    >>> held, replaced = placeholders({"gamma": 0.99, "func": lambda r: r})
    >>> held["gamma"], unrecorded(held["func"]), replaced
    (0.99, 'function episode_audit.format.unrecorded:<lambda>', ['func'])
    >>> placeholders({"dtype": np.float32}, dtype_names=True)
    ({'dtype': 'float32'}, [])
    """
    out: dict[str, Any] = {}
    replaced: list[str] = []
    for name, value in kwargs.items():
        if dtype_names and (
            isinstance(value, np.dtype)
            or (isinstance(value, type) and issubclass(value, np.generic))
        ):
            out[name] = np.dtype(value).name
            continue
        try:
            json.dumps(value, allow_nan=False)
        except (TypeError, ValueError, RecursionError):
            out[name] = placeholder(value)
            replaced.append(str(name))
        else:
            out[name] = value
    return out, replaced


def unrecorded(value: Any) -> str | None:
    """What ``value`` stands for when it is a placeholder, else ``None``."""
    if isinstance(value, Mapping) and len(value) == 1 and UNRECORDED in value:
        return str(value[UNRECORDED])
    return None


def spec_placeholders(spec: Any) -> list[str]:
    """The arguments a recorded env spec (JSON) holds placeholders for, named for a person.

    >>> spec = {"kwargs": {"size": 3}, "additional_wrappers": [
    ...     {"name": "TransformReward", "kwargs": {"func": placeholder(len)}}]}
    >>> spec_placeholders(spec)
    ["TransformReward's argument 'func'"]
    """
    if not isinstance(spec, Mapping):
        return []
    kwargs = spec.get("kwargs")
    named = [
        f"the env's argument {name!r}"
        for name, value in (kwargs.items() if isinstance(kwargs, Mapping) else ())
        if unrecorded(value) is not None
    ]
    wrappers = spec.get("additional_wrappers")
    for wrapper in wrappers if isinstance(wrappers, list) else ():
        held = wrapper.get("kwargs") if isinstance(wrapper, Mapping) else None
        if isinstance(held, Mapping):
            named += [
                f"{str(wrapper.get('name'))[:80]}'s argument {str(name)[:80]!r}"
                for name, value in held.items()
                if unrecorded(value) is not None
            ]
    return named
