"""Arrow columns shared by the recorder and replay (so both encode a step identically).

>>> terms_column([{"a": 1.0}, None, {"a": 0.5, "b": -1}]).to_pylist()
[[('a', 1.0)], None, [('a', 0.5), ('b', -1.0)]]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

__all__ = ["TERMS_TYPE", "bool_column", "terms_column"]

TERMS_TYPE = pa.map_(pa.string(), pa.float64())
"""Arrow type of the ``terms`` column: term name -> value, null when a step has no terms."""


def bool_column(flags: Sequence[Any]) -> pa.Array:
    """A boolean column from per-step flags (numpy or Python bools)."""
    try:
        return pa.array(np.fromiter(flags, dtype=np.bool_, count=len(flags)))
    except Exception:  # flags the slow path has already normalised cannot get here
        return pa.array([bool(f) for f in flags], pa.bool_())


def terms_column(rows: Sequence[dict[str, Any] | None]) -> pa.Array:
    """The ``terms`` map column from one dict (or ``None``) per step; bad values become NaN."""
    n = len(rows)
    if all(t is None for t in rows):
        return pa.nulls(n, TERMS_TYPE)
    offsets = np.zeros(n + 1, dtype=np.int32)
    keys: list[str] = []
    values: list[Any] = []
    mask = np.zeros(n, dtype=np.bool_)
    for i, terms in enumerate(rows):
        if terms is None:
            mask[i] = True
        else:
            keys.extend(terms)
            values.extend(terms.values())
        offsets[i + 1] = len(keys)
    try:
        numbers = np.asarray(values, dtype=np.float64)
    except Exception:
        numbers = np.array([_as_float(v) for v in values], dtype=np.float64)
    return pa.MapArray.from_arrays(
        pa.array(offsets), pa.array(keys, pa.string()), pa.array(numbers), mask=pa.array(mask)
    )


def _as_float(value: Any) -> float:
    try:
        return float(value)
    except Exception:
        return math.nan
