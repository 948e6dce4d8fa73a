"""Typed options (format/options.py): what plain JSON changes, and the tagged JSON that does not."""

from __future__ import annotations

import enum
import json
import math
from collections import OrderedDict
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from episode_audit.format.options import MAX_TYPED_TEXT, decode_typed, encode_typed, json_loss
from tests.support.typed_options import Logger


def same(a: Any, b: Any) -> bool:
    """Whether ``a`` and ``b`` are the same options: equal, of the same types all the way down
    (numpy values: dtype, shape and bytes; floats: NaN is NaN, -0.0 is not 0.0; dict order)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, np.generic):
        return a.dtype == b.dtype and a.tobytes() == b.tobytes()
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or (
            a == b and math.copysign(1, a) == math.copysign(1, b)
        )
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return len(a) == len(b) and all(
            same(ka, kb) and same(va, vb)
            for (ka, va), (kb, vb) in zip(a.items(), b.items(), strict=True)
        )
    return bool(a == b)


_DTYPE_NAMES = ["?", "i1", "<i2", ">i4", "<i8", "u1", "<u2", "<u4", ">u8", "<f2", "<f4", ">f4"]
_DTYPE_NAMES += ["<f8", "<c8", "<c16", "<M8[s]", "<m8[ms]", "<U3", "|S2"]
_DTYPES = st.sampled_from(_DTYPE_NAMES).map(np.dtype)
_ARRAYS = _DTYPES.flatmap(
    lambda dtype: hnp.arrays(dtype, hnp.array_shapes(min_dims=0, max_dims=3, max_side=3))
)
_SCALARS = _DTYPES.filter(lambda d: d.kind not in "SU").flatmap(
    lambda dtype: hnp.from_dtype(dtype).map(lambda v: np.asarray(v, dtype)[()])
)
_FLOATS = st.floats(allow_nan=True, allow_infinity=True)
_KEYS = st.one_of(
    st.text(max_size=4),
    st.sampled_from(["$", "$tuple", "$dict", "$x"]),
    st.integers(),
    st.booleans(),
    st.none(),
    _FLOATS.filter(lambda f: not math.isnan(f)),
    st.tuples(st.integers(), st.text(max_size=2)),
)
_LEAVES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    _FLOATS,
    st.text(max_size=6),
    _ARRAYS,
    _SCALARS,
)
_OPTIONS = st.recursive(
    _LEAVES,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3),
        st.lists(inner, max_size=3).map(tuple),
        st.dictionaries(_KEYS, inner, max_size=3),
        st.dictionaries(st.text(max_size=4), inner, max_size=3),
    ),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
@given(_OPTIONS)
def test_typed_options_come_back_exactly(options: Any) -> None:
    text = encode_typed(options)
    assert text.isascii()
    assert same(decode_typed(text), options)


def _through_json(value: Any) -> Any:
    return json.loads(json.dumps(value, allow_nan=False))


@settings(max_examples=300, deadline=None)
@given(_OPTIONS)
def test_json_loss_says_whether_plain_json_gives_them_back(options: Any) -> None:
    """None exactly when JSON (as the file holds it: no NaN, no infinities) gives them back."""
    try:
        back = same(_through_json(options), options)
    except (TypeError, ValueError):
        back = False
    assert (json_loss(options) is None) == back, json_loss(options)


def test_what_plain_json_would_change_is_named() -> None:
    assert json_loss({"a": [1, 2.5, "x", None, True], "b": {}}) is None
    assert json_loss({"a": (1, 2)}) == "JSON keeps no tuples: they come back as lists"
    assert json_loss([np.zeros(2)]) == (
        "JSON keeps no numpy arrays: a float64 array comes back as a list"
    )
    assert (
        json_loss({"n": np.int64(3)}) == "JSON keeps no numpy numbers: a int64 comes back as a int"
    )
    assert json_loss({True: 1}) == "JSON keys are text, not bool True"
    assert json_loss([float("-inf")]) == "JSON has no -inf"
    assert json_loss({"s": {1, 2}}) == "JSON has no set values"


def test_a_dict_whose_own_keys_look_like_tags_is_escaped() -> None:
    options = {"$tuple": [1, 2], "plain": {"$float": "inf"}}
    text = encode_typed(options)
    assert text == '{"$dict":[["$tuple",[1,2]],["plain",{"$dict":[["$float","inf"]]}]]}'
    assert decode_typed(text) == options


def test_decoded_arrays_are_writable_copies_in_their_byte_order() -> None:
    big = np.arange(6, dtype=">i4").reshape(2, 3)
    back = decode_typed(encode_typed({"a": big, "f": np.asfortranarray(big.astype("<f4"))}))
    assert back["a"].dtype.str == ">i4" and back["a"].flags.writeable
    back["a"][0, 0] = 7  # an env may change its options in place
    assert back["a"].tolist() == [[7, 1, 2], [3, 4, 5]]
    assert back["f"].tolist() == big.tolist() and back["f"].dtype == np.float32


def test_a_negative_nan_comes_back_negative() -> None:
    """A NaN's sign survives (an env may read it with ``math.copysign``); its payload does not."""
    negative = math.copysign(math.nan, -1.0)
    text = encode_typed({"cap": negative, "low": math.nan})
    assert text == '{"cap":{"$float":"-nan"},"low":{"$float":"nan"}}'
    back = decode_typed(text)
    assert math.isnan(back["cap"]) and math.copysign(1.0, back["cap"]) == -1.0
    assert math.copysign(1.0, back["low"]) == 1.0


def test_an_arrays_fortran_order_is_kept_not_its_strides_or_flags() -> None:
    fortran = np.asfortranarray(np.arange(6, dtype="<i2").reshape(2, 3))
    strided = np.arange(12.0)[::2]
    frozen = np.arange(3.0)
    frozen.flags.writeable = False
    text = encode_typed({"f": fortran, "s": strided, "r": frozen})
    assert '"order":"F"' in text and text.count('"order"') == 1
    back = decode_typed(text)
    assert back["f"].flags.f_contiguous and not back["f"].flags.c_contiguous
    assert back["f"].tolist() == fortran.tolist() and back["f"].dtype == fortran.dtype
    assert back["s"].flags.c_contiguous and back["s"].tolist() == strided.tolist()
    assert back["r"].flags.writeable


@pytest.mark.parametrize("kind", ["list", "dict", "array"])
def test_a_mutable_value_found_twice_is_not_held(kind: str) -> None:
    """Given back as two copies, an env changing one would not see the other change."""
    shared = {"list": [1.0], "dict": {"x": 1}, "array": np.zeros(2)}[kind]
    options = {"a": shared, "b": (1, shared)}
    with pytest.raises(ValueError, match=f"^options_typed holds no {kind} twice: the same"):
        encode_typed(options)
    if kind != "array":
        assert json_loss({"a": shared, "b": [shared]}) == (
            f"JSON keeps no {kind} twice: the same {kind} is at two places in them, it comes "
            "back as two"
        )
    assert decode_typed(encode_typed({"a": (1, 2), "b": (1, 2), "c": [1], "d": [1]})) == {
        "a": (1, 2),
        "b": (1, 2),
        "c": [1],
        "d": [1],
    }


class _Level(enum.IntEnum):
    EASY = 1


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"level": _Level.EASY}, "options_typed holds no _Level values"),
        (OrderedDict(a=1), "options_typed holds no OrderedDict values"),
        ({"ids": {1, 2}}, "options_typed holds no set values"),
        ({"raw": b"x"}, "options_typed holds no bytes values"),
        ({"o": np.array([None])}, "options_typed holds no numpy object values"),
        ({"r": np.zeros(1, "f4,i4")}, r"options_typed holds no numpy \[\('f0', '<f4'\)"),
        ({"log": Logger()}, "options_typed holds no Logger values"),
        (
            {"m": np.zeros((1, 2), np.int64).view(np.matrix)},
            "^options_typed holds no numpy.matrix values: a subclass of numpy.ndarray$",
        ),
        (
            {"m": np.ma.masked_array([1, 2])},
            r"^options_typed holds no numpy\.ma(\.core)?\.MaskedArray values: "
            r"a subclass of numpy\.ndarray$",
        ),
    ],
    ids=[
        "int-enum",
        "ordered-dict",
        "set",
        "bytes",
        "object-array",
        "structured",
        "object",
        "matrix",
        "masked",
    ],
)
def test_what_the_typed_form_cannot_give_back_is_refused(options: Any, message: str) -> None:
    with pytest.raises(TypeError, match=message):
        encode_typed(options)


def test_typed_options_are_bounded_in_size_and_depth() -> None:
    with pytest.raises(ValueError, match=f"more than the {MAX_TYPED_TEXT} it holds"):
        encode_typed({"big": np.zeros(MAX_TYPED_TEXT, np.int8)})
    deep: list[Any] = []
    for _ in range(5000):
        deep = [deep]
    with pytest.raises(RecursionError):
        encode_typed(deep)
    cyclic: list[Any] = []
    cyclic.append(cyclic)
    with pytest.raises(ValueError, match="options_typed holds no list twice"):
        encode_typed(cyclic)
    with pytest.raises(ValueError, match="options_typed is nested too deeply"):
        decode_typed('{"$tuple":[' * 5000 + "]}" * 5000)  # (Python 3.13's json parses it)
    with pytest.raises(
        ValueError, match=r"options_typed is \d+ bytes of JSON, more than the limit"
    ):
        decode_typed('"' + "x" * MAX_TYPED_TEXT + '"')


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"$set":[1]}', "unknown tag '\\$set'"),
        ('{"$tuple":[1],"b":2}', "an object with a '\\$' key that is not a tag"),
        ('{"$float":"1e999"}', "\\$float is not 'inf', '-inf', 'nan' or '-nan'"),
        ('{"$tuple":{"a":1}}', "\\$tuple is not a list"),
        ('{"$dict":[[1]]}', "\\$dict is not a list of \\[key, value\\] pairs"),
        ('{"$dict":[[[1],2]]}', "a \\$dict key is a list, which no dict key can be"),
        ('{"$array":{"dtype":"|O","shape":[1],"data":"AAAAAAAAAAA="}}', "dtype '\\|O'"),
        ('{"$array":{"dtype":"f4,f4","shape":[1],"data":"AAAAAAAAAAA="}}', "dtype 'f4,f4'"),
        ('{"$array":{"dtype":"<i1","shape":[1],"data":"AA=="}}', "dtype '<i1'"),
        (
            '{"$array":{"dtype":"<f4","shape":[3],"data":"AAAAAA=="}}',
            "takes 12 bytes, its data is 4",
        ),
        ('{"$array":{"dtype":"<f4","shape":[-1],"data":""}}', "shape is not a list of sizes"),
        ('{"$array":{"dtype":"<f4","shape":[1],"data":"*"}}', "\\$array's data is not base64"),
        ('{"$array":{"dtype":"<f4","data":""}}', "\\$array is not an object of dtype, shape, data"),
        (
            '{"$array":{"dtype":"<f4","shape":[0],"data":"","order":"A"}}',
            "an \\$array's order is not 'C' or 'F': 'A'",
        ),
        ('{"$scalar":{"dtype":"<U1","data":"YQAAAA=="}}', "dtype '<U1'"),
        ('{"$scalar":{"dtype":"<f8","data":"AAAAAA=="}}', "takes 8 bytes, its data is 4"),
    ],
)
def test_typed_options_a_recorder_did_not_write_are_refused(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        decode_typed(text)
