"""State snapshots as data: every value round-trips exactly; anything else is refused by name."""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np
import pytest

from episode_audit.format.state import MAX_STATE_TEXT, decode_snapshot, encode_snapshot


@pytest.mark.parametrize(
    "value",
    [
        np.arange(6, dtype=np.float32).reshape(2, 3),
        np.array([True, False]),
        np.float64(0.1),
        np.zeros((0, 4), dtype=np.uint8),
        b"\x00\xffALE",
        0.1,
        7,
        None,
        {"a": [1, "x", True]},
    ],
)
def test_values_round_trip_exactly(value: Any) -> None:
    [(name, state)] = decode_snapshot(encode_snapshot([("demo", {"v": value})]))
    got = state["v"]
    assert name == "demo"
    if isinstance(value, (np.ndarray, np.generic)):
        assert isinstance(got, np.ndarray)
        assert got.dtype == value.dtype and got.shape == np.shape(value)
        assert np.array_equal(got, value)
    else:
        assert got == value and type(got) is type(value)


def test_entries_keep_their_order_and_repeats() -> None:
    text = encode_snapshot([("a", {}), ("b", {"x": 1}), ("a", {"x": 2})])
    assert [(n, s) for n, s in decode_snapshot(text)] == [
        ("a", {}),
        ("b", {"x": 1}),
        ("a", {"x": 2}),
    ]


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.array(["a"], dtype=object), "dtype object cannot be a state value"),
        (np.array([1 + 2j]), "dtype complex128 cannot be a state value"),
        (float("nan"), "nan is not a finite number"),
        ({1: 2}, "dict cannot be a state value"),
        (object(), "object cannot be a state value"),
    ],
)
def test_encoding_refuses_what_is_not_data(value: Any, message: str) -> None:
    with pytest.raises(TypeError, match=f"demo.v: .*{message}"):
        encode_snapshot([("demo", {"v": value})])


def _array(dtype: Any, shape: Any, data: str) -> str:
    entry = {
        "adapter": "demo",
        "state": {"v": {"array": {"dtype": dtype, "shape": shape, "data": data}}},
    }
    return json.dumps([entry])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"adapter": "demo"}', "not a list of entries"),
        ('[{"state": {}}]', "lacks its adapter name"),
        ('[{"adapter": "demo", "state": {"v": 1}}]', "demo.v is not tagged"),
        ('[{"adapter": "demo", "state": {"v": {"pickle": "gASV"}}}]', "demo.v is not tagged"),
        (_array("object", [1], "AA=="), "dtype 'object' is not one it holds"),
        (_array("float64", [2], base64.b64encode(b"\0" * 8).decode()), "expected 16 bytes"),
        (_array("float64", [-1], ""), "expected a shape"),
        (_array("uint8", [1], "not base64!"), "not base64"),
        ("[" * 10, "not valid JSON"),
    ],
)
def test_decoding_refuses_what_episode_audit_never_writes(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        decode_snapshot(text)


def test_decoding_is_bounded() -> None:
    with pytest.raises(ValueError, match="more than the limit"):
        decode_snapshot(" " * (MAX_STATE_TEXT + 1))
