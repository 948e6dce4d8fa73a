"""Arrow columns shared by the recorder and replay (so both encode a step identically).

>>> terms_column(3, {0: {"a": 1.0}, 2: {"a": 0.5, "b": -1}}).to_pylist()
[[('a', 1.0)], None, [('a', 0.5), ('b', -1.0)]]
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

__all__ = ["TERMS_TYPE", "terms_column"]

TERMS_TYPE = pa.map_(pa.string(), pa.float64())
"""Arrow type of the ``terms`` column: term name -> value, null when a step has no terms."""


def terms_column(n: int, rows: Mapping[int, Mapping[str, Any]]) -> pa.Array:
    """The ``terms`` map column of ``n`` steps from ``{row: {name: value}}``.

    Rows absent from ``rows`` are null (no terms on that step); a value that is not a number
    becomes NaN.
    """
    if not rows:
        return pa.nulls(n, TERMS_TYPE)
    counts = np.zeros(n, dtype=np.int32)
    valid = np.zeros(n, dtype=np.bool_)
    keys: list[str] = []
    values: list[Any] = []
    for row, terms in rows.items():
        counts[row] = len(terms)
        valid[row] = True
        keys.extend(terms)
        values.extend(terms.values())
    offsets = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(counts, out=offsets[1:])
    try:
        numbers = np.asarray(values, dtype=np.float64)
    except Exception:
        numbers = np.array([_as_float(v) for v in values], dtype=np.float64)
    return pa.MapArray.from_arrays(
        pa.array(offsets), pa.array(keys, pa.string()), pa.array(numbers), mask=pa.array(~valid)
    )


def _as_float(value: Any) -> float:
    try:
        return float(value)
    except Exception:
        return math.nan
