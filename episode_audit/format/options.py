"""Reset options as data: the tagged JSON of the ``options_typed`` column (docs/format.md).

Plain JSON gives back ``None``, bools, ints, finite floats, text, lists and dicts with text keys
as they were; :func:`json_loss` says why it would give back other options than these (a tuple
comes back as a list, a numpy array as a list, ``inf`` as text, an int key as text).
:func:`encode_typed` writes options as tagged JSON that gives them back exactly, and
:func:`decode_typed` reads it:

- ``None``, a bool, an int, text, a finite float: themselves; ``inf``, ``-inf``, ``nan``,
  ``-nan`` (a NaN's sign is kept, not its payload): ``{"$float": "inf"}``;
- a list: a JSON array; a tuple: ``{"$tuple": [...]}``;
- a dict whose keys are all text, none beginning with ``$``: a JSON object of its values;
  any other dict: ``{"$dict": [[key, value], ...]}`` (keys tagged as values are);
- a numpy array: ``{"$array": {"dtype": "<f4", "shape": [2], "data": BASE64}}``, its C-order
  bytes (a Fortran-ordered array: its Fortran-order bytes and ``"order": "F"``); a numpy
  scalar: ``{"$scalar": {"dtype": "<f4", "data": BASE64}}``. Dtypes
  (:data:`TYPED_KINDS`): bool, ints, floats, complex numbers, datetimes and timedeltas in any
  byte order, and for arrays fixed-width text and bytes; ``dtype`` is numpy's ``dtype.str``.

Only these exact types are held: a subclass (an ``IntEnum``, an ``OrderedDict``, a
``numpy.matrix``), a set, bytes or any other object is not (``TypeError``); nor is a list, dict
or array found twice in the options (``ValueError``: they would come back as two copies, and an
env changing one would see the other unchanged). An array's dtype, shape, values and order (C or
Fortran) are held, not its strides or flags. :func:`decode_typed` checks every tag, dtype, shape
and size and raises ``ValueError`` naming what is wrong; it makes no object but these (nothing
is imported or unpickled), and its arrays are writable copies.

>>> import numpy as np
>>> options = {"qpos": np.array([0.5, 1.0], np.float32), "init": (1, 2), 3: float("inf")}
>>> print(json_loss(options))
JSON keeps no numpy arrays: a float32 array comes back as a list
>>> text = encode_typed(options)
>>> text
'{"$dict":[["qpos",{"$array":{"dtype":"<f4","shape":[2],"data":"AAAAPwAAgD8="}}],\
["init",{"$tuple":[1,2]}],[3,{"$float":"inf"}]]}'
>>> decode_typed(text)
{'qpos': array([0.5, 1. ], dtype=float32), 'init': (1, 2), 3: inf}
"""

from __future__ import annotations

import base64
import binascii
import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .records import MAX_JSON_TEXT, from_json
from .unrecorded import unrecorded

__all__ = [
    "LAYOUT_SPEC_KWARGS_TYPED",
    "MAX_SPEC_KWARGS_TYPED",
    "MAX_TYPED_TEXT",
    "TYPED_KINDS",
    "decode_typed",
    "encode_typed",
    "json_loss",
    "spec_kwargs",
    "typed_spec_kwargs",
]

MAX_TYPED_TEXT = MAX_JSON_TEXT
"""Largest typed options text, 1 MiB: the recorder holds no larger, a reader parses no larger."""

TYPED_KINDS = frozenset("biufcmM")
"""The numpy dtype kinds of the scalars and arrays held; arrays also of ``S`` and ``U``."""
_ARRAY_KINDS = TYPED_KINDS | frozenset("SU")
_MAX_DIMS = 32
_MAX_DTYPE_TEXT = 32
_NONFINITE = {
    "inf": math.inf,
    "-inf": -math.inf,
    "nan": math.nan,
    "-nan": math.copysign(math.nan, -1.0),
}
_SHARED = (list, dict, np.ndarray)
"""The types of mutable values the options may hold the same one of twice."""


def json_loss(value: Any) -> str | None:
    """Why plain JSON would give back other options than ``value``, or ``None`` if it would not.

    The first thing found, depth first; a list or dict found twice (JSON gives back two
    copies) is one. ``RecursionError`` for options nested too deeply.

    >>> print(json_loss({"a": [1, 2.5, None, True, "x"], "b": {}}))
    None
    >>> print(json_loss({"a": [float("nan")]}))
    JSON has no nan
    >>> print(json_loss({5: "x"}))
    JSON keys are text, not int 5
    >>> print(json_loss({"low": np.float32(0.5)}))
    JSON keeps no numpy numbers: a float32 comes back as a float
    >>> shared = [1]
    >>> print(json_loss({"a": shared, "b": shared}))
    JSON keeps no list twice: the same list is at two places in them, it comes back as two
    """
    return _loss(value, set())


def _loss(value: Any, seen: set[int]) -> str | None:
    kind = type(value)
    if value is None or kind is bool or kind is int or kind is str:
        return None
    if kind is float:
        return None if math.isfinite(value) else f"JSON has no {value}"
    if kind is list or kind is dict:
        if id(value) in seen:
            return twice("JSON keeps no", value)
        seen.add(id(value))
    if kind is list:
        for item in value:
            why = _loss(item, seen)
            if why is not None:
                return why
        return None
    if kind is dict:
        for key, item in value.items():
            if type(key) is not str:
                return f"JSON keys are text, not {type(key).__name__} {_shown(key)}"
            why = _loss(item, seen)
            if why is not None:
                return why
        return None
    if kind is tuple:
        return "JSON keeps no tuples: they come back as lists"
    if isinstance(value, np.ndarray):
        return f"JSON keeps no numpy arrays: a {value.dtype} array comes back as a list"
    if isinstance(value, np.generic):
        back = type(value.item()).__name__
        return f"JSON keeps no numpy numbers: a {value.dtype} comes back as a {back}"
    return f"JSON has no {kind.__name__} values"


def twice(prefix: str, value: Any) -> str:
    """What is wrong with options holding ``value`` (a list, dict or array) twice."""
    kind = "array" if isinstance(value, np.ndarray) else type(value).__name__
    return f"{prefix} {kind} twice: the same {kind} is at two places in them, it comes back as two"


def _shown(value: Any) -> str:
    """``repr(value)`` cut to 40 characters; the type's name if it has none (never raises)."""
    try:
        return f"{value!r:.40}"
    except Exception:  # (an int too long for text; a repr() that raises)
        return f"<{type(value).__name__}>"


def encode_typed(value: Any) -> str:
    """The tagged JSON text of ``value`` that :func:`decode_typed` gives back exactly.

    ``TypeError`` names a value of a type it does not hold; ``ValueError`` says the text would
    be larger than :data:`MAX_TYPED_TEXT` (or an int too long for JSON text);
    ``RecursionError`` for options nested too deeply. A list, dict or array found twice in
    ``value`` (the same object: it would come back as two) is a ``ValueError``.

    >>> encode_typed({"$ref": -0.0, "b": [None, float("-inf")]})
    '{"$dict":[["$ref",-0.0],["b",[null,{"$float":"-inf"}]]]}'
    >>> encode_typed({"ids": {1, 2}})
    Traceback (most recent call last):
    ...
    TypeError: options_typed holds no set values
    """
    text = json.dumps(_tagged(value, set()), separators=(",", ":"), allow_nan=False)
    if len(text) > MAX_TYPED_TEXT:
        raise ValueError(
            f"their typed form is {len(text)} bytes, more than the {MAX_TYPED_TEXT} it holds"
        )
    return text


def _tagged(value: Any, seen: set[int]) -> Any:
    kind = type(value)
    if value is None or kind is bool or kind is int or kind is str:
        return value
    if kind is float:
        if math.isfinite(value):
            return value
        return {"$float": repr(value) if value == value or math.copysign(1, value) > 0 else "-nan"}
    if kind in _SHARED:
        if id(value) in seen:
            raise ValueError(twice("options_typed holds no", value))
        seen.add(id(value))
    if kind is list:
        return [_tagged(item, seen) for item in value]
    if kind is tuple:
        return {"$tuple": [_tagged(item, seen) for item in value]}
    if kind is dict:
        if all(type(key) is str and not key.startswith("$") for key in value):
            return {key: _tagged(item, seen) for key, item in value.items()}
        return {"$dict": [[_tagged(k, seen), _tagged(item, seen)] for k, item in value.items()]}
    if kind is np.ndarray and _holds(value.dtype, _ARRAY_KINDS):
        return {"$array": _array_body(value)}
    if isinstance(value, np.generic) and kind is value.dtype.type and _holds(value.dtype):
        data = base64.b64encode(value.tobytes()).decode("ascii")
        return {"$scalar": {"dtype": value.dtype.str, "data": data}}
    raise TypeError(f"options_typed holds no {_kind_of(value)}")


def _array_body(value: np.ndarray[Any, Any]) -> dict[str, Any]:
    """An array's ``$array`` body: its C-order bytes, or its Fortran-order bytes if it has them."""
    fortran = value.ndim > 1 and value.flags.f_contiguous and not value.flags.c_contiguous
    data = base64.b64encode(value.tobytes(order="F" if fortran else "C")).decode("ascii")
    body = {"dtype": value.dtype.str, "shape": list(value.shape), "data": data}
    if fortran:
        body["order"] = "F"
    return body


def _kind_of(value: Any) -> str:
    """What ``value`` is, said in a ``TypeError`` of :func:`encode_typed` (``"set values"``)."""
    kind = type(value)
    if isinstance(value, np.ndarray) and kind is not np.ndarray:
        name = f"{kind.__module__}.{kind.__qualname__}"
        return f"{name} values: a subclass of numpy.ndarray"
    if isinstance(value, (np.ndarray, np.generic)):
        return f"numpy {value.dtype} values"
    return f"{kind.__name__} values"


def _holds(dtype: np.dtype[Any], kinds: frozenset[str] = TYPED_KINDS) -> bool:
    """Whether ``dtype`` is one whose values are their bytes (no objects, fields, subarrays)."""
    return (
        dtype.kind in kinds
        and dtype.fields is None
        and dtype.subdtype is None
        and dtype.itemsize > 0
        and not dtype.hasobject
    )


def decode_typed(text: str | bytes) -> Any:
    """The options :func:`encode_typed` wrote as ``text``, exactly.

    Raises ``ValueError`` naming what is wrong when the text is not typed options
    episode-audit wrote: too large or deeply nested, an unknown tag, a dtype it does not hold,
    a shape that does not fit the data.

    >>> first, second = decode_typed('{"$tuple":[1,{"$scalar":{"dtype":"<i2","data":"BwA="}}]}')
    >>> first, type(second).__name__, int(second)
    (1, 'int16', 7)
    >>> decode_typed('{"$set":[1]}')
    Traceback (most recent call last):
    ...
    ValueError: options_typed: unknown tag '$set'
    """
    raw = from_json(text, "options_typed", limit=MAX_TYPED_TEXT)
    try:
        return _untagged(raw)
    except RecursionError:
        raise ValueError("options_typed is nested too deeply") from None


def _untagged(item: Any) -> Any:
    if isinstance(item, list):
        return [_untagged(value) for value in item]
    if not isinstance(item, dict):
        return item  # (JSON's: None, a bool, an int, a float, text)
    if len(item) == 1:
        ((key, body),) = item.items()
        if key.startswith("$"):
            decode = _TAGS.get(key)
            if decode is None:
                raise ValueError(f"options_typed: unknown tag {key[:40]!r}")
            return decode(body)
    if any(key.startswith("$") for key in item):
        raise ValueError("options_typed: an object with a '$' key that is not a tag")
    return {key: _untagged(value) for key, value in item.items()}


def _float(body: Any) -> float:
    if not isinstance(body, str) or body not in _NONFINITE:
        raise ValueError("options_typed: $float is not 'inf', '-inf', 'nan' or '-nan'")
    return _NONFINITE[body]


def _tuple(body: Any) -> tuple[Any, ...]:
    if not isinstance(body, list):
        raise ValueError("options_typed: $tuple is not a list")
    return tuple(_untagged(value) for value in body)


def _dict(body: Any) -> dict[Any, Any]:
    if not isinstance(body, list) or not all(
        isinstance(pair, list) and len(pair) == 2 for pair in body
    ):
        raise ValueError("options_typed: $dict is not a list of [key, value] pairs")
    out: dict[Any, Any] = {}
    for key, value in body:
        decoded = _untagged(key)
        try:
            hash(decoded)
        except TypeError:  # (a list or a dict: no key)
            raise ValueError(
                f"options_typed: a $dict key is a {type(decoded).__name__}, which no dict "
                "key can be"
            ) from None
        out[decoded] = _untagged(value)
    return out


def _array(body: Any) -> np.ndarray[Any, Any]:
    ordered = isinstance(body, dict) and "order" in body
    keys = ("dtype", "shape", "data", "order") if ordered else ("dtype", "shape", "data")
    dtype, data = _dtype_and_data(body, "$array", keys, _ARRAY_KINDS)
    order = body.get("order", "C")
    if order not in ("C", "F"):
        raise ValueError(f"options_typed: an $array's order is not 'C' or 'F': {order!r:.40}")
    shape = body["shape"]
    if not (
        isinstance(shape, list)
        and len(shape) <= _MAX_DIMS
        and all(type(d) is int and 0 <= d < 2**63 for d in shape)
    ):
        raise ValueError(f"options_typed: an $array's shape is not a list of sizes: {shape!r:.80}")
    if math.prod(shape) * dtype.itemsize != len(data):
        raise ValueError(
            f"options_typed: an $array of {dtype.str} {shape} takes "
            f"{math.prod(shape) * dtype.itemsize} bytes, its data is {len(data)}"
        )
    try:
        flat = np.frombuffer(data, dtype=dtype)
        array: np.ndarray[Any, Any] = flat.reshape(shape, order=order).copy(order="K")
    except ValueError as exc:  # (a shape numpy refuses: too many elements in all)
        raise ValueError(f"options_typed: an $array of shape {shape}: {exc}") from None
    return array


def _scalar(body: Any) -> np.generic:
    dtype, data = _dtype_and_data(body, "$scalar", ("dtype", "data"), TYPED_KINDS)
    if len(data) != dtype.itemsize:
        raise ValueError(
            f"options_typed: a $scalar of {dtype.str} takes {dtype.itemsize} bytes, "
            f"its data is {len(data)}"
        )
    value: np.generic = np.frombuffer(data, dtype=dtype)[0]
    return value


def _dtype_and_data(
    body: Any, tag: str, keys: tuple[str, ...], kinds: frozenset[str]
) -> tuple[np.dtype[Any], bytes]:
    """An array's or scalar's dtype (one it holds, as written) and bytes."""
    if not isinstance(body, dict) or sorted(body) != sorted(keys):
        raise ValueError(f"options_typed: {tag} is not an object of {', '.join(keys)}")
    name, data = body["dtype"], body["data"]
    if not isinstance(name, str) or len(name) > _MAX_DTYPE_TEXT or not isinstance(data, str):
        raise ValueError(f"options_typed: {tag} has no dtype text or no data text")
    try:
        dtype = np.dtype(name)
    except (TypeError, ValueError):
        dtype = None
    if dtype is None or dtype.str != name or not _holds(dtype, kinds):
        raise ValueError(f"options_typed: {tag} has dtype {name!r}, which it does not hold")
    try:
        return dtype, base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise ValueError(f"options_typed: {tag}'s data is not base64") from None


_TAGS: dict[str, Callable[[Any], Any]] = {
    "$float": _float,
    "$tuple": _tuple,
    "$dict": _dict,
    "$array": _array,
    "$scalar": _scalar,
}


LAYOUT_SPEC_KWARGS_TYPED = "spec_kwargs_typed"
"""Layout key of a single-env or vector file with an env spec: the spec's kwargs that its JSON
gives back as other values than they were (a tuple as a list, an int key as text), as typed
text, ``{}`` when there are none (absent in files of older recorders, or when the typed form
cannot hold them): :func:`typed_spec_kwargs` writes it, :func:`spec_kwargs` reads it."""
MAX_SPEC_KWARGS_TYPED = 64 << 10
"""The largest :data:`LAYOUT_SPEC_KWARGS_TYPED` text a recorder writes (replay builds an env
from no more); larger, it is left out and the spec's JSON is the record."""


def typed_spec_kwargs(kwargs: Mapping[str, Any], held: Mapping[str, Any]) -> str | None:
    """The typed text of the env ``kwargs`` that ``held`` (the spec's JSON kwargs) changed.

    A kwarg JSON gives back as is, or that ``held`` keeps as a placeholder, is not in it, nor
    one the typed form cannot hold (``{}`` when none is left); ``None`` when the text would be
    larger than :data:`MAX_SPEC_KWARGS_TYPED`, or two kwargs share a value.

    >>> typed_spec_kwargs({"frameskip": (2, 5), "mode": 4}, {"frameskip": [2, 5], "mode": 4})
    '{"frameskip":{"$tuple":[2,5]}}'
    >>> typed_spec_kwargs({"mode": 4}, {"mode": 4})
    '{}'
    """
    changed: dict[str, Any] = {}
    for name, value in kwargs.items():
        if not isinstance(name, str) or unrecorded(held.get(name)) is not None:
            continue
        try:
            if json_loss(value) is None:
                continue
            encode_typed(value)
        except (TypeError, ValueError, RecursionError):
            continue
        changed[name] = value
    try:
        text = encode_typed(changed)
    except (TypeError, ValueError, RecursionError):  # (a value shared by two kwargs)
        return None
    return text if len(text) <= MAX_SPEC_KWARGS_TYPED else None


def spec_kwargs(held: Mapping[str, Any], typed: Any) -> dict[str, Any]:
    """The env spec's kwargs to build the env with, exact where ``typed`` holds them.

    ``held``: the spec's JSON kwargs; ``typed``: the layout's :data:`LAYOUT_SPEC_KWARGS_TYPED`.
    A typed kwarg replaces the held one only where JSON gives it back as the held value; typed
    text that does not decode, or is larger than :data:`MAX_SPEC_KWARGS_TYPED`, is left out:
    the spec's JSON is the record.

    >>> spec_kwargs({"frameskip": [2, 5], "mode": 4}, '{"frameskip":{"$tuple":[2,5]}}')
    {'frameskip': (2, 5), 'mode': 4}
    >>> spec_kwargs({"frameskip": [3, 5]}, '{"frameskip":{"$tuple":[2,5]}}')
    {'frameskip': [3, 5]}
    """
    kwargs = dict(held)
    if not isinstance(typed, str) or len(typed) > MAX_SPEC_KWARGS_TYPED:
        return kwargs
    try:
        exact = decode_typed(typed)
    except ValueError:
        return kwargs
    if not isinstance(exact, dict):
        return kwargs
    for name, value in exact.items():
        if not isinstance(name, str) or name not in kwargs:
            continue
        try:
            as_held = json.loads(json.dumps(value))
        except (TypeError, ValueError, RecursionError):
            continue
        if as_held == kwargs[name]:
            kwargs[name] = value
    return kwargs
