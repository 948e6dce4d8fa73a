from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from episode_audit.format.columns import TERMS_TYPE, null_mask, terms_column

ARRAYS = {
    "int64": pa.array([1, None, 3, None, 5, 6, None, 8, 9, None, 11]),
    "string": pa.array(["a", None, "c", "d", None, "f", "g", "h", None]),
    "none null": pa.array([1.0, 2.0, 3.0]),
    "all null": pa.array([None, None, None], pa.string()),
    "null type": pa.nulls(4),
    "fixed size list": pa.array([[1.0, 2.0], None, [3.0, 4.0]], pa.list_(pa.float32(), 2)),
    "terms": terms_column(5, {0: {"a": 1.0}, 3: {"b": 2.0}}),
    "struct": pa.array([{"x": 1}, None, {"x": 3}], pa.struct([("x", pa.int64())])),
    "dense union": pa.UnionArray.from_dense(
        pa.array([0, 1, 0], pa.int8()),
        pa.array([0, 0, 1], pa.int32()),
        [pa.array([1, None]), pa.array([None], pa.string())],
    ),
}


@pytest.mark.parametrize("name", list(ARRAYS))
def test_null_mask_agrees_with_is_null_at_every_offset(name: str) -> None:
    array = ARRAYS[name]
    for start in range(len(array)):
        for length in (0, 1, len(array) - start):
            part = array.slice(start, length)
            got = null_mask(part)
            assert got.dtype == np.bool_ and got.flags.writeable
            assert got.tolist() == part.is_null().to_pylist(), (start, length)


def test_terms_column_type_and_nulls() -> None:
    column = terms_column(3, {1: {"a": "x"}})
    assert column.type == TERMS_TYPE
    assert null_mask(column).tolist() == [True, False, True]
    assert np.isnan(column.items.to_numpy()[0])
