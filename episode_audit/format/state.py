"""State snapshots as data: what a reset row's ``state`` column holds (docs/format.md).

A snapshot is a list of entries, one per adapted env or wrapper (outermost first), each
``{"adapter": NAME, "state": {key: value}}``. Every value is tagged: ``{"array": {"dtype",
"shape", "data"}}`` (a numeric or bool numpy array, C-order bytes in base64), ``{"bytes":
BASE64}`` or ``{"json": VALUE}`` (finite numbers, text, bools, null, lists, string-keyed
dicts). Nothing else is held and nothing is unpickled: :func:`decode_snapshot` checks every
dtype, shape and size and raises ``ValueError`` naming what is wrong.

>>> import numpy as np
>>> text = encode_snapshot([("demo", {"mean": np.zeros(2), "count": 3.0})])
>>> [(name, state["mean"].tolist(), state["count"]) for name, state in decode_snapshot(text)]
[('demo', [0.0, 0.0], 3.0)]
"""

from __future__ import annotations

import base64
import binascii
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .records import from_json

__all__ = [
    "MAX_STATE_TEXT",
    "STATE_DTYPES",
    "Snapshot",
    "StateValue",
    "decode_snapshot",
    "encode_snapshot",
]

MAX_STATE_TEXT = 16 << 20
"""Largest snapshot of one reset, as JSON text: 16 MiB (the recorder notes a larger one)."""

STATE_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64"}
    | {"float16", "float32", "float64"}
)
"""The numpy dtypes a snapshot's arrays may have (no objects, no structured dtypes)."""

_DTYPE_NAMES = {np.dtype(name): name for name in STATE_DTYPES}  # (dtype.name is slow)
_MAX_DIMS = 32
_MAX_NAME = 256

StateValue = Any
"""A numpy array of a dtype in :data:`STATE_DTYPES`, ``bytes``, or a JSON value."""

Snapshot = list[tuple[str, dict[str, StateValue]]]
"""``[(adapter name, {key: value})]``, outermost env or wrapper first."""


def encode_snapshot(entries: Sequence[tuple[str, Mapping[str, StateValue]]]) -> str:
    """The snapshot's JSON text; ``TypeError`` / ``ValueError`` for a value it cannot hold."""
    out = []
    for name, state in entries:
        values = {}
        for key, value in state.items():
            if not isinstance(key, str):
                raise TypeError(f"{name}: state key {key!r} is not a string")
            values[key] = _encode_value(f"{name}.{key}", value)
        out.append({"adapter": name, "state": values})
    return json.dumps(out, separators=(",", ":"), allow_nan=False)


def _encode_value(where: str, value: Any) -> dict[str, Any]:
    if isinstance(value, np.generic):
        value = np.asarray(value)
    if isinstance(value, np.ndarray):
        dtype = _DTYPE_NAMES.get(value.dtype)
        if dtype is None:
            raise TypeError(f"{where}: arrays of dtype {value.dtype} cannot be a state value")
        data = base64.b64encode(value.tobytes()).decode("ascii")  # (C order)
        array = {"dtype": dtype, "shape": list(value.shape), "data": data}
        return {"array": array}
    if isinstance(value, (bytes, bytearray, memoryview)):
        return {"bytes": base64.b64encode(bytes(value)).decode("ascii")}
    _check_json(where, value)
    return {"json": value}


def _check_json(where: str, value: Any) -> None:
    """Raise ``TypeError`` unless ``value`` is plain JSON with finite numbers."""
    stack = [value]
    while stack:
        item = stack.pop()
        if item is None or isinstance(item, (bool, int, str)):
            continue
        if isinstance(item, float):
            if not math.isfinite(item):
                raise TypeError(f"{where}: {item} is not a finite number (use an array)")
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
        elif isinstance(item, dict) and all(isinstance(k, str) for k in item):
            stack.extend(item.values())
        else:
            raise TypeError(f"{where}: {type(item).__name__} cannot be a state value")


def decode_snapshot(text: str) -> Snapshot:
    """The entries of a snapshot's JSON text, arrays as (read-only) numpy arrays.

    Raises ``ValueError`` naming the entry and key when the text is not a snapshot
    episode-audit wrote: too large, a dtype or shape it does not hold, data of the wrong size.
    """
    raw = from_json(text, "the state snapshot", limit=MAX_STATE_TEXT)
    if not isinstance(raw, list):
        raise ValueError("the state snapshot is not a list of entries")
    out: Snapshot = []
    for entry in raw:
        name = entry.get("adapter") if isinstance(entry, dict) else None
        state = entry.get("state") if isinstance(entry, dict) else None
        if not (isinstance(name, str) and 0 < len(name) <= _MAX_NAME) or not isinstance(
            state, dict
        ):
            raise ValueError("a state snapshot entry lacks its adapter name or its state")
        out.append((name, {str(k): _decode_value(f"{name}.{k}", v) for k, v in state.items()}))
    return out


def _decode_value(where: str, tagged: Any) -> StateValue:
    if not (isinstance(tagged, dict) and len(tagged) == 1):
        raise ValueError(f"state value {where} is not tagged array, bytes or json")
    ((tag, value),) = tagged.items()
    if tag == "json":
        return value
    if tag == "bytes" and isinstance(value, str):
        return _b64(where, value)
    if tag != "array" or not isinstance(value, dict):
        raise ValueError(f"state value {where} is not tagged array, bytes or json")
    dtype, shape, data = value.get("dtype"), value.get("shape"), value.get("data")
    if dtype not in STATE_DTYPES:
        raise ValueError(f"state value {where}: dtype {str(dtype)[:40]!r} is not one it holds")
    if not (
        isinstance(shape, list)
        and len(shape) <= _MAX_DIMS
        and all(type(d) is int and d >= 0 for d in shape)
        and isinstance(data, str)
    ):
        raise ValueError(f"state value {where}: expected a shape (list of sizes) and data")
    raw = _b64(where, data)
    expected = math.prod(shape) * np.dtype(dtype).itemsize
    if len(raw) != expected:
        raise ValueError(
            f"state value {where}: expected {expected} bytes for {dtype} {shape}, got {len(raw)}"
        )
    return np.frombuffer(raw, dtype=dtype).reshape(shape)


def _b64(where: str, text: str) -> bytes:
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise ValueError(f"state value {where}: its data is not base64") from None
