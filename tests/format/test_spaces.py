from __future__ import annotations

import hashlib
import inspect
import io
import json
import warnings
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import data_equivalence
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from episode_audit.errors import ConfigurationError
from episode_audit.format.spaces import (
    ColumnBuffer,
    SpaceCodec,
    UnknownSpace,
    codec_for,
    codec_in,
    describe_space,
    space_from_description,
    unknown_spaces,
)

ARRAY_SPACES = (spaces.Box, spaces.MultiDiscrete, spaces.MultiBinary)

DISCRETE_DTYPE = "dtype" in inspect.signature(spaces.Discrete).parameters  # Gymnasium >= 1.2
IMAGE = spaces.Box(0, 255, shape=(64, 64, 3), dtype=np.uint8)
NESTED = spaces.Dict(
    OrderedDict(  # (keys in this order: Gymnasium sorts a plain dict's before 1.4's sort_keys)
        {
            "pos": spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32),
            "inner": spaces.Tuple(
                (
                    spaces.Discrete(3, start=1),
                    spaces.Dict({"flags": spaces.MultiBinary(3), "name": spaces.Text(4)}),
                )
            ),
            "angle": spaces.Box(-np.pi, np.pi, shape=(), dtype=np.float64),
        }
    )
)

SPACES: dict[str, spaces.Space[Any]] = {
    "box-float32": spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
    "box-float64-2d": spaces.Box(-5.0, 5.0, shape=(2, 3), dtype=np.float64),
    "box-float16": spaces.Box(-2.0, 2.0, shape=(3,), dtype=np.float16),
    "box-unbounded": spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32),
    "box-uint8-image": IMAGE,
    "box-int32": spaces.Box(-100, 100, shape=(5,), dtype=np.int32),
    "box-int64-unbounded": spaces.Box(-np.inf, np.inf, shape=(2,), dtype=np.int64),
    "box-uint64": spaces.Box(0, 2**40, shape=(2,), dtype=np.uint64),
    "box-bool": spaces.Box(0, 1, shape=(4,), dtype=np.bool_),
    "box-scalar": spaces.Box(-1.0, 1.0, shape=(), dtype=np.float32),
    "box-per-element": spaces.Box(
        low=np.array([-1.0, 0.0, -np.inf], dtype=np.float32),
        high=np.array([1.0, np.inf, 3.5], dtype=np.float32),
    ),
    "discrete": spaces.Discrete(4),
    "discrete-start": spaces.Discrete(5, start=-2),
    **({"discrete-int32": spaces.Discrete(3, start=10, dtype=np.int32)} if DISCRETE_DTYPE else {}),
    "multidiscrete": spaces.MultiDiscrete([3, 4, 2]),
    "multidiscrete-2d": spaces.MultiDiscrete(
        np.array([[2, 3], [4, 5]]), start=np.array([[1, 1], [0, -2]]), dtype=np.int8
    ),
    "multibinary": spaces.MultiBinary(5),
    "multibinary-shape": spaces.MultiBinary([2, 3]),
    "dict-nested-tuple": NESTED,
    "tuple": spaces.Tuple((spaces.Discrete(2), spaces.Box(0.0, 1.0, shape=(2,)))),
    "text": spaces.Text(8, min_length=0, charset="abc é-]"),
    "sequence": spaces.Sequence(spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)),
    "graph": spaces.Graph(
        node_space=spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32),
        edge_space=spaces.Discrete(4),
    ),
    "oneof": spaces.OneOf((spaces.Discrete(3), spaces.Box(-1.0, 1.0, shape=(2,)))),
}


def samples(space: spaces.Space[Any], n: int = 5, seed: int = 0) -> list[Any]:
    space.seed(seed)
    return [space.sample() for _ in range(n)]


def through_ipc(codec: SpaceCodec, array: pa.Array) -> tuple[pa.Field, pa.Array]:
    """Write ``array`` as one column of an Arrow IPC stream and read it back."""
    schema = pa.schema([codec.field("value")])
    sink = io.BytesIO()
    with pa.ipc.new_stream(sink, schema) as writer:
        writer.write_batch(pa.record_batch([array], schema=schema))
    table = pa.ipc.open_stream(sink.getvalue()).read_all()
    return table.schema.field("value"), table.column("value").combine_chunks()


def assert_same(space: spaces.Space[Any], expected: Any, got: Any) -> None:
    """Exact equality with the native type, dtype and shape the space promises."""
    if isinstance(space, ARRAY_SPACES):
        assert type(got) is np.ndarray
        assert got.dtype == space.dtype
        assert got.shape == space.shape
        np.testing.assert_array_equal(got, expected, strict=True)
    elif isinstance(space, spaces.Discrete):
        assert type(got) is int
        assert got == int(expected)
    elif isinstance(space, spaces.Dict):
        assert type(got) is dict
        assert list(got) == list(space.spaces)
        for key, subspace in space.spaces.items():
            assert_same(subspace, expected[key], got[key])
    elif isinstance(space, spaces.Tuple):
        assert type(got) is tuple
        assert len(got) == len(space.spaces)
        for subspace, e, g in zip(space.spaces, expected, got, strict=True):
            assert_same(subspace, e, g)
    elif isinstance(space, spaces.Text):
        assert type(got) is str
        assert got == expected
    else:
        assert data_equivalence(expected, got, exact=True)


# --------------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SPACES))
def test_round_trip_through_ipc_keeps_type_dtype_and_shape(name: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    values = samples(space)
    array = codec.encode(values)
    assert array.type == codec.arrow_type
    assert len(array) == len(values)
    field, read_back = through_ipc(codec, array)
    assert field.metadata == codec.field("value").metadata
    decoded = codec.decode(read_back)
    assert len(decoded) == len(values)
    for value, got in zip(values, decoded, strict=True):
        assert_same(space, value, got)
        assert space.contains(got)


@pytest.mark.parametrize(
    ("name", "arrow_type"),
    [
        ("box-float32", pa.list_(pa.float32(), 4)),
        ("box-float64-2d", pa.list_(pa.float64(), 6)),
        ("box-float16", pa.list_(pa.float16(), 3)),
        ("box-uint8-image", pa.list_(pa.uint8(), 64 * 64 * 3)),
        ("box-bool", pa.list_(pa.bool_(), 4)),
        ("box-scalar", pa.list_(pa.float32(), 1)),
        ("discrete-start", pa.int64()),
        ("multidiscrete-2d", pa.list_(pa.int8(), 4)),
        ("multibinary-shape", pa.list_(pa.int8(), 6)),
        ("text", pa.string()),
        ("sequence", pa.string()),
        ("graph", pa.string()),
    ],
)
def test_arrow_type_of_each_space(name: str, arrow_type: pa.DataType) -> None:
    assert codec_for(SPACES[name]).arrow_type == arrow_type


def test_dict_and_tuple_become_structs_in_key_order() -> None:
    codec = codec_for(NESTED)
    assert [f.name for f in codec.arrow_type] == ["pos", "inner", "angle"]
    inner = codec.arrow_type.field("inner").type
    assert [f.name for f in inner] == ["0", "1"]
    assert inner.field("1").type.field("name").type == pa.string()


@pytest.mark.parametrize(
    ("name", "kind", "shape", "dtype"),
    [
        ("box-float64-2d", "array", "[2, 3]", "float64"),
        ("box-scalar", "array", "[]", "float32"),
        ("multibinary-shape", "array", "[2, 3]", "int8"),
        ("discrete-int32", "discrete", "[]", "int32"),
    ],
)
def test_field_metadata_carries_kind_shape_and_dtype(
    name: str, kind: str, shape: str, dtype: str
) -> None:
    if name not in SPACES:
        pytest.skip("Gymnasium < 1.2: a Discrete space has no dtype but int64")
    field = codec_for(SPACES[name]).field("observation")
    assert field.name == "observation"
    assert field.nullable
    assert field.metadata[b"episode_audit.kind"] == kind.encode()
    assert field.metadata[b"episode_audit.shape"] == shape.encode()
    assert field.metadata[b"episode_audit.dtype"] == dtype.encode()


def test_struct_children_keep_their_metadata_through_ipc() -> None:
    codec = codec_for(NESTED)
    field, _ = through_ipc(codec, codec.encode(samples(NESTED, 2)))
    pos = field.type.field("pos")
    assert pos.metadata[b"episode_audit.shape"] == b"[2]"
    assert field.metadata[b"episode_audit.kind"] == b"dict"


@pytest.mark.parametrize(
    "dtype",
    [
        np.float16,
        np.float32,
        np.float64,
        np.int8,
        np.int16,
        np.int32,
        np.int64,
        np.uint8,
        np.uint16,
        np.uint32,
        np.uint64,
        np.bool_,
    ],
)
@pytest.mark.parametrize("shape", [(), (1,), (3,), (2, 2)])
def test_every_box_dtype_round_trips(dtype: type[Any], shape: tuple[int, ...]) -> None:
    high = 1 if dtype is np.bool_ else 100
    space = spaces.Box(0, high, shape=shape, dtype=dtype)
    codec = codec_for(space)
    values = samples(space, 4)
    buffer = codec.new_buffer()
    assert all(buffer.append(v) is None for v in values)
    decoded = codec.decode(through_ipc(codec, buffer.finish())[1])
    for value, got in zip(values, decoded, strict=True):
        assert_same(space, value, got)


def test_decoded_arrays_are_writable_copies() -> None:
    space = SPACES["box-float32"]
    codec = codec_for(space)
    array = codec.encode(samples(space, 2))
    first = codec.decode(array)[0]
    first[0] = 42.0
    assert codec.decode(array)[0][0] != 42.0


def test_decode_accepts_sliced_and_chunked_arrays() -> None:
    for name in ("box-float32", "dict-nested-tuple", "discrete-start", "text"):
        space = SPACES[name]
        codec = codec_for(space)
        values = samples(space, 6)
        array = codec.encode(values)
        for got, value in zip(codec.decode(array.slice(2, 3)), values[2:5], strict=True):
            assert_same(space, value, got)
        chunked = pa.chunked_array([array.slice(0, 2), array.slice(2)])
        for got, value in zip(codec.decode(chunked), values, strict=True):
            assert_same(space, value, got)
        assert codec.contains(array.slice(1, 4)).shape == (4,)


def test_decode_rejects_an_array_of_another_type() -> None:
    codec = codec_for(SPACES["box-float32"])
    with pytest.raises(TypeError, match=r"Expect an Arrow array of type fixed_size_list"):
        codec.decode(pa.array([1, 2]))


def test_json_fallback_stores_to_jsonable_text() -> None:
    space = SPACES["sequence"]
    codec = codec_for(space)
    values = samples(space, 3)
    array = codec.encode(values)
    for text, value in zip(array.to_pylist(), values, strict=True):
        assert json.loads(text) == space.to_jsonable([value])[0]
    assert codec.field("x").metadata[b"episode_audit.kind"] == b"json"


# --------------------------------------------------------------------------------------------
# Buffers
# --------------------------------------------------------------------------------------------


def test_buffer_grows_and_is_reusable_without_touching_finished_arrays() -> None:
    space = SPACES["box-float32"]
    codec = codec_for(space)
    buffer = codec.new_buffer()
    assert isinstance(buffer, ColumnBuffer)
    first_values = samples(space, 3000, seed=1)  # beyond the preallocated block
    for value in first_values:
        buffer.append(value)
    assert len(buffer) == 3000
    first = buffer.finish()
    assert len(buffer) == 0
    second_values = samples(space, 10, seed=2)
    for value in second_values:
        buffer.append(value)
    second = buffer.finish()
    third_values = samples(space, 3000, seed=3)  # would overwrite a block still shared
    for value in third_values:
        buffer.append(value)
    third = buffer.finish()
    for array, values in ((first, first_values), (second, second_values), (third, third_values)):
        np.testing.assert_array_equal(np.stack(codec.decode(array)), np.stack(values))


@pytest.mark.parametrize(
    "name", ["discrete-start", "box-uint8-image", "box-scalar", "box-bool", "dict-nested-tuple"]
)
def test_other_buffers_are_reusable(name: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    buffer = codec.new_buffer()
    batches = [samples(space, n, seed=n) for n in (1500, 7, 1500)]
    arrays = []
    for values in batches:
        for value in values:
            buffer.append(value)
        arrays.append(buffer.finish())
    for array, values in zip(arrays, batches, strict=True):
        for value, got in zip(values, codec.decode(array), strict=True):
            assert_same(space, value, got)


@pytest.mark.parametrize("name", list(SPACES))
def test_null_rows_round_trip_and_count_as_inside(name: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    values = samples(space, 3)
    with_nulls = [None, values[0], None, values[1], values[2], None]
    array = through_ipc(codec, codec.encode(with_nulls))[1]
    assert array.null_count == 3
    decoded = codec.decode(array)
    for value, got in zip(with_nulls, decoded, strict=True):
        if value is None:
            assert got is None
        else:
            assert_same(space, value, got)
    assert codec.contains(array).tolist() == [True] * 6


def test_append_null_on_a_buffer() -> None:
    codec = codec_for(NESTED)
    buffer = codec.new_buffer()
    buffer.append_null()
    buffer.append(samples(NESTED, 1)[0])
    assert len(buffer) == 2
    array = buffer.finish()
    assert array.is_null().to_pylist() == [True, False]


@pytest.mark.parametrize(
    "value",
    [
        pytest.param(np.zeros(3, np.float32), id="too-short"),
        pytest.param(np.zeros((4, 1), np.float32), id="extra-axis"),
        pytest.param(np.zeros(8, np.float32)[::2][:3], id="strided-too-short"),
        pytest.param(np.float32(1.0), id="numpy-scalar"),
        pytest.param(1.0, id="python-scalar"),
        pytest.param(np.zeros((), np.float32), id="zero-d-array"),
        pytest.param([1.0, 2.0], id="short-list"),
    ],
)
def test_wrong_shape_raises_and_leaves_the_buffer_unchanged(value: Any) -> None:
    codec = codec_for(SPACES["box-float32"])
    buffer = codec.new_buffer()
    good = np.arange(4, dtype=np.float32)
    buffer.append(good)
    with pytest.raises(ValueError, match=r"Expect shape \(4,\), actually: shape"):
        buffer.append(value)
    assert len(buffer) == 1
    buffer.append(good + 1)
    decoded = codec.decode(buffer.finish())
    np.testing.assert_array_equal(np.stack(decoded), np.stack([good, good + 1]))


@pytest.mark.parametrize("value", [np.float32(1.0), 1.0, np.zeros((), np.float32)])
def test_a_scalar_is_not_broadcast_into_a_one_element_box(value: Any) -> None:
    buffer = codec_for(spaces.Box(0.0, 1.0, shape=(1,))).new_buffer()
    with pytest.raises(ValueError, match=r"Expect shape \(1,\), actually: shape \(\)"):
        buffer.append(value)
    assert len(buffer) == 0


@pytest.mark.parametrize("name", list(SPACES))
def test_finish_on_an_empty_buffer_gives_an_empty_array(name: str) -> None:
    codec = codec_for(SPACES[name])
    array = codec.new_buffer().finish()
    assert len(array) == 0
    assert array.type == codec.arrow_type
    assert codec.decode(array) == []
    assert codec.contains(array).shape == (0,)


def test_wrong_shape_image_raises() -> None:
    buffer = codec_for(IMAGE).new_buffer()
    with pytest.raises(ValueError, match=r"Expect shape \(64, 64, 3\)"):
        buffer.append(np.zeros((64, 64), np.uint8))
    with pytest.raises(ValueError, match=r"Expect shape"):
        buffer.append(np.uint8(7))  # would broadcast to every pixel
    assert len(buffer) == 0


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [
        pytest.param(["a", "b", "c", "d"], TypeError, "numeric array", id="text"),
        pytest.param(np.array([1 + 1j] * 4), TypeError, "numeric array", id="complex"),
        pytest.param([None] * 4, TypeError, "numeric array", id="objects"),
        pytest.param([[1.0], [1.0, 2.0], 3.0, 4.0], ValueError, "Expect an array", id="ragged"),
    ],
)
def test_unconvertible_values_raise(value: Any, error: type[Exception], match: str) -> None:
    buffer = codec_for(SPACES["box-float32"]).new_buffer()
    with pytest.raises(error, match=match):
        buffer.append(value)
    assert len(buffer) == 0


@pytest.mark.parametrize(
    ("name", "value", "note"),
    [
        ("box-float32", np.zeros(4, np.float64), "dtype float64 cast to float32"),
        ("box-float32", np.zeros(4, np.int64), "dtype int64 cast to float32"),
        ("box-float32", np.zeros(4, ">f4"), "dtype >f4 cast to float32"),
        ("box-float32", [0.0, 1.0, 0.5, 0.25], "list cast to float32"),
        ("box-float32", (np.float32(0),) * 4, "tuple converted to float32 array"),
        ("box-int32", np.arange(5, dtype=np.float64), "dtype float64 cast to int32"),
        ("box-int32", np.arange(5, dtype=np.uint8), "dtype uint8 cast to int32"),
        ("box-scalar", 0.5, "float cast to float32"),
        ("box-scalar", np.float64(0.5), "dtype float64 cast to float32"),
        ("multibinary", [1, 0, 1, 0, 1], "list cast to int8"),
        ("multidiscrete", np.array([1, 2, 0], np.int32), "dtype int32 cast to int64"),
        ("discrete", 2.0, "float 2.0 cast to int"),
        ("discrete", np.float32(3.0), "float32 3.0 cast to int"),
        ("tuple", (1, np.zeros(2, np.float64)), "1: dtype float64 cast to float32"),
    ],
)
def test_coerced_value_returns_a_note(name: str, value: Any, note: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    buffer = codec.new_buffer()
    assert buffer.append(value) == note
    assert buffer.append(value) == note  # the cached note of the repeated cast
    (got, _) = codec.decode(buffer.finish())
    if isinstance(space, ARRAY_SPACES):
        assert got.dtype == space.dtype
        np.testing.assert_array_equal(got, np.asarray(value, dtype=space.dtype))


def test_nested_note_names_the_key() -> None:
    buffer = codec_for(NESTED).new_buffer()
    value = samples(NESTED, 1)[0]
    value["pos"] = value["pos"].astype(np.float64)
    value["inner"] = (2.0, value["inner"][1])
    assert (
        buffer.append(value)
        == "pos: dtype float64 cast to float32; inner: 0: float 2.0 cast to int"
    )


@pytest.mark.parametrize(
    ("name", "value", "error", "match"),
    [
        ("box-int32", np.full(5, 0.5), ValueError, "holds exactly"),
        ("box-int32", np.full(5, np.nan), ValueError, "holds exactly"),
        ("box-int32", np.full(5, 2**40), ValueError, "holds exactly"),
        ("box-uint64", np.array([-1, 0]), ValueError, "holds exactly"),
        ("box-bool", np.array([0, 1, 2, 1]), ValueError, "holds exactly"),
        ("discrete", 2.5, ValueError, "Expect an integer, actually: 2.5"),
        ("discrete", float("nan"), ValueError, "Expect an integer"),
        ("discrete", 2**63, ValueError, "fits int64"),
        ("discrete", np.array([1]), ValueError, r"shape \(1,\)"),
        ("discrete", "1", TypeError, "Expect an integer, actually: str"),
        ("discrete", None, TypeError, "Expect an integer, actually: NoneType"),
        ("text", 5, TypeError, "Expect a str"),
        ("text", "\ud800", ValueError, "UTF-8"),
        ("dict-nested-tuple", [1, 2, 3], TypeError, "Expect a dict"),
        ("dict-nested-tuple", {"pos": np.zeros(2, np.float32)}, ValueError, "keys"),
        ("tuple", (1,), ValueError, "Expect a tuple of 2 items"),
        ("tuple", 1, TypeError, "Expect a tuple"),
        ("sequence", 3.5, ValueError, r"Sequence\.to_jsonable"),
    ],
)
def test_values_that_cannot_be_encoded_raise(
    name: str, value: Any, error: type[Exception], match: str
) -> None:
    buffer = codec_for(SPACES[name]).new_buffer()
    with pytest.raises(error, match=match):
        buffer.append(value)
    assert len(buffer) == 0


def test_failed_struct_append_undoes_the_children_already_appended() -> None:
    codec = codec_for(NESTED)
    buffer = codec.new_buffer()
    good = samples(NESTED, 2)
    buffer.append(good[0])
    bad = dict(good[1])
    bad["angle"] = np.zeros(3)  # the last child fails after "pos" and "inner" went in
    with pytest.raises(ValueError, match=r"angle: Expect shape \(\)"):
        buffer.append(bad)
    assert len(buffer) == 1
    buffer.append(good[1])
    decoded = codec.decode(buffer.finish())
    for value, got in zip(good, decoded, strict=True):
        assert_same(NESTED, value, got)


# --------------------------------------------------------------------------------------------
# contains
# --------------------------------------------------------------------------------------------


def out_of_space_values(name: str, space: spaces.Space[Any]) -> list[Any]:
    """Values that encode fine but some of which lie outside ``space``."""
    if isinstance(space, spaces.Box):
        low = np.where(space.bounded_below, space.low, 0).astype(space.dtype)
        high = np.where(space.bounded_above, space.high, 0).astype(space.dtype)
        values = [low, high]
        if space.dtype.kind == "f":
            with np.errstate(over="ignore"):
                values += [low - 1, high + 1, np.full(space.shape, np.nan, space.dtype)]
                values += [np.full(space.shape, np.inf, space.dtype)]
                values += [np.full(space.shape, -np.inf, space.dtype)]
        elif space.dtype.kind in "iu" and np.all(space.bounded_below & space.bounded_above):
            values += [(high.astype(np.int64) + 1).astype(space.dtype)]
            if np.all(low > np.iinfo(space.dtype).min):
                values += [low - 1]
        return [np.asarray(v, dtype=space.dtype) for v in values]
    if isinstance(space, spaces.Discrete):
        start, n = int(space.start), int(space.n)
        return list(range(start - 2, start + n + 2))
    if isinstance(space, spaces.MultiDiscrete):
        last = space.start + space.nvec - 1
        return [space.start - 1, last, last + 1, space.start]
    if isinstance(space, spaces.MultiBinary):
        return [np.full(space.shape, v, np.int8) for v in (-1, 0, 1, 2)]
    if isinstance(space, spaces.Text):
        return ["", "abc", "ab\u00e9 -]", "x", "abcabcabc", "a\nb"]
    if isinstance(space, spaces.Dict):
        base = samples(space, 1, seed=9)[0]
        result = []
        for key, subspace in space.spaces.items():
            for bad in out_of_space_values(key, subspace):
                result.append({**base, key: bad})
        return result
    if isinstance(space, spaces.Tuple):
        base = samples(space, 1, seed=9)[0]
        result = []
        for i, subspace in enumerate(space.spaces):
            for bad in out_of_space_values(str(i), subspace):
                result.append(tuple(bad if j == i else v for j, v in enumerate(base)))
        return result
    if isinstance(space, spaces.Sequence):
        return [(np.full(2, 2.0, np.float32),), (np.zeros(2, np.float32),), ()]
    return []


@pytest.mark.parametrize("name", list(SPACES))
def test_contains_agrees_with_the_space(name: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    values = samples(space, 8) + out_of_space_values(name, space)
    got = codec.contains(through_ipc(codec, codec.encode(values))[1])
    assert isinstance(got, np.ndarray)
    assert got.dtype == np.bool_
    assert got.tolist() == [bool(space.contains(v)) for v in values]


def test_contains_catches_nan_and_bounds() -> None:
    codec = codec_for(spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32))
    values = [[0.0, 0.0], [np.nan, 0.0], [1.0, -1.0], [1.0, 1.0001], [-np.inf, 0.0]]
    array = codec.encode([np.array(v, np.float32) for v in values])
    assert codec.contains(array).tolist() == [True, False, True, False, False]


def test_digested_leaves_count_as_inside() -> None:
    codec = codec_for(IMAGE, digest_min_bytes=1)
    array = codec.encode([np.zeros(IMAGE.shape, np.uint8)])
    assert codec.contains(array).tolist() == [True]


# --------------------------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------------------------


def test_compare_is_exact_by_default_and_tolerant_with_atol() -> None:
    codec = codec_for(spaces.Box(-10.0, 10.0, shape=(3,), dtype=np.float32))
    base = np.array([1.0, 2.0, 3.0], np.float32)
    close = base + np.array([0.0, 1e-4, 0.0], np.float32)
    far = base + np.array([0.0, 0.0, 0.5], np.float32)
    expected = codec.encode([base, base, base])
    got = codec.encode([base.copy(), close, far])
    equal, diff = codec.compare(expected, got)
    assert equal.tolist() == [True, False, False]
    assert diff[0] == 0.0
    assert diff[1] == pytest.approx(1e-4, rel=1e-2)
    assert diff[2] == pytest.approx(0.5)
    equal, diff = codec.compare(expected, got, atol=1e-3)
    assert equal.tolist() == [True, True, False]
    assert diff.dtype == np.float64


def test_compare_exact_is_bitwise_with_nan_equal_to_nan() -> None:
    codec = codec_for(spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float64))
    rows = [[np.nan], [0.0], [np.inf], [np.inf], [1.0]]
    other = [[np.nan], [-0.0], [np.inf], [-np.inf], [np.nan]]
    expected = codec.encode([np.array(r) for r in rows])
    got = codec.encode([np.array(r) for r in other])
    equal, diff = codec.compare(expected, got)
    assert equal.tolist() == [True, False, True, False, False]
    assert diff.tolist() == [0.0, 0.0, 0.0, np.inf, np.inf]
    equal, _ = codec.compare(expected, got, atol=1e-9)
    assert equal.tolist() == [True, True, True, False, False]


@pytest.mark.parametrize("space_name", ["box", "nested"])
def test_compare_by_chunk_and_in_passes_gives_the_one_pass_result(
    space_name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Replay hands compare a column of several chunks (one per recorded block) and wide rows
    # (camera frames) are compared a few rows per pass; neither may change a result.
    from episode_audit.format.spaces import codecs as spaces_module

    space = spaces.Box(-10.0, 10.0, shape=(5,), dtype=np.float32) if space_name == "box" else NESTED
    codec = codec_for(space)
    values = samples(space, 12)
    changed = list(values)
    changed[4] = samples(space, 13)[12]
    changed[9] = samples(space, 14)[13]
    expected = codec.encode(values)
    got = codec.encode(changed)
    chunked = pa.chunked_array([expected.slice(0, 5), expected.slice(5, 1), expected.slice(6)])
    whole = codec.compare(expected, got)
    assert not whole[0][4] and not whole[0][9] and whole[0].sum() == 10
    for atol in (0.0, 0.5):
        one = codec.compare(expected, got, atol=atol)
        by_chunk = codec.compare(chunked, got, atol=atol)
        monkeypatch.setattr(spaces_module, "_COMPARE_ELEMENTS", 7)
        in_passes = codec.compare(chunked, got, atol=atol)
        monkeypatch.undo()
        for other in (by_chunk, in_passes):
            assert other[0].tolist() == one[0].tolist()
            assert other[1].tolist() == one[1].tolist()
    with pytest.raises(ValueError, match="the same length"):
        codec.compare(chunked, got.slice(1))


@pytest.mark.parametrize("name", ["discrete-start", "multidiscrete", "box-int32", "box-bool"])
def test_compare_integers(name: str) -> None:
    space = SPACES[name]
    codec = codec_for(space)
    values = samples(space, 6)
    equal, diff = codec.compare(codec.encode(values), codec.encode(values))
    assert equal.all()
    assert not diff.any()


def test_compare_discrete_with_atol() -> None:
    codec = codec_for(spaces.Discrete(10))
    equal, diff = codec.compare(codec.encode([1, 2, 3]), codec.encode([1, 3, 6]), atol=1)
    assert equal.tolist() == [True, True, False]
    assert diff.tolist() == [0.0, 1.0, 3.0]


def test_compare_non_numeric_leaves_differ_by_infinity() -> None:
    codec = codec_for(SPACES["text"])
    equal, diff = codec.compare(codec.encode(["ab", "c"]), codec.encode(["ab", "cc"]), atol=5)
    assert equal.tolist() == [True, False]
    assert diff.tolist() == [0.0, np.inf]


def test_compare_structs_combine_children() -> None:
    codec = codec_for(NESTED)
    values = samples(NESTED, 3)
    changed = [dict(v) for v in values]
    changed[1]["pos"] = changed[1]["pos"] + np.float32(0.25)
    changed[2]["inner"] = (changed[2]["inner"][0], {**changed[2]["inner"][1], "name": "zz"})
    equal, diff = codec.compare(codec.encode(values), codec.encode(changed))
    assert equal.tolist() == [True, False, False]
    assert diff[0] == 0.0
    assert diff[1] == pytest.approx(0.25)
    assert diff[2] == np.inf


def test_compare_nulls() -> None:
    codec = codec_for(SPACES["box-float32"])
    value = np.zeros(4, np.float32)
    equal, diff = codec.compare(
        codec.encode([None, None, value]), codec.encode([None, value, None])
    )
    assert equal.tolist() == [True, False, False]
    assert diff.tolist() == [0.0, np.inf, np.inf]


@pytest.mark.parametrize("atol", [-1.0, float("nan"), float("inf")])
def test_compare_rejects_a_bad_atol(atol: float) -> None:
    codec = codec_for(spaces.Discrete(2))
    array = codec.encode([0])
    with pytest.raises(ValueError, match="Expect atol"):
        codec.compare(array, array, atol=atol)


def test_compare_rejects_arrays_of_different_lengths() -> None:
    codec = codec_for(spaces.Discrete(2))
    with pytest.raises(ValueError, match="same length"):
        codec.compare(codec.encode([0]), codec.encode([0, 1]))


# --------------------------------------------------------------------------------------------
# Digest mode
# --------------------------------------------------------------------------------------------


def test_digest_mode_round_trip() -> None:
    codec = codec_for(IMAGE, digest_min_bytes=1024)
    assert codec.arrow_type == pa.binary(16)
    metadata = codec.field("observation").metadata
    assert metadata[b"episode_audit.kind"] == b"digest"
    assert metadata[b"episode_audit.shape"] == b"[64, 64, 3]"
    assert metadata[b"episode_audit.dtype"] == b"uint8"
    image = samples(IMAGE, 1)[0]
    same = image.copy()
    changed = image.copy()
    changed[10, 20, 1] ^= 1
    strided = np.asfortranarray(image)  # same values, other memory layout
    array = through_ipc(codec, codec.encode([image, same, changed, strided, None]))[1]
    digests = codec.decode(array)
    assert digests[0] == hashlib.blake2b(image.tobytes(), digest_size=16).digest()
    assert digests[0] == digests[1] == digests[3]
    assert digests[0] != digests[2]
    assert digests[4] is None
    assert all(isinstance(d, bytes) and len(d) == 16 for d in digests[:4])
    equal, diff = codec.compare(codec.encode([image, image]), codec.encode([same, changed]))
    assert equal.tolist() == [True, False]
    assert diff.tolist() == [0.0, np.inf]


def test_digest_applies_to_large_box_leaves_only() -> None:
    space = spaces.Dict({"image": IMAGE, "pos": spaces.Box(-1.0, 1.0, shape=(2,))})
    codec = codec_for(space, digest_min_bytes=4096)
    assert codec.arrow_type.field("image").type == pa.binary(16)
    assert codec.arrow_type.field("pos").type == pa.list_(pa.float32(), 2)
    value = samples(space, 1)[0]
    (got,) = codec.decode(codec.encode([value]))
    assert isinstance(got["image"], bytes)
    np.testing.assert_array_equal(got["pos"], value["pos"])


def test_digest_mode_casts_with_a_note_and_rejects_wrong_shapes() -> None:
    codec = codec_for(IMAGE, digest_min_bytes=0)
    buffer = codec.new_buffer()
    image = np.zeros(IMAGE.shape, np.int64)
    assert buffer.append(image) == "dtype int64 cast to uint8"
    with pytest.raises(ValueError, match="Expect shape"):
        buffer.append(np.zeros((64, 64), np.uint8))
    assert len(buffer) == 1
    (digest,) = codec.decode(buffer.finish())
    assert digest == hashlib.blake2b(image.astype(np.uint8).tobytes(), digest_size=16).digest()


# --------------------------------------------------------------------------------------------
# describe_space / space_from_description
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SPACES))
def test_description_round_trip(name: str) -> None:
    space = SPACES[name]
    description = describe_space(space)
    text = json.dumps(description, allow_nan=False)
    rebuilt = space_from_description(json.loads(text))
    assert rebuilt == space
    assert type(rebuilt) is type(space)
    assert describe_space(rebuilt) == description


@pytest.mark.parametrize(
    "space",
    [
        spaces.Box(-np.inf, np.inf, shape=(2,), dtype=np.float32),
        spaces.Box(np.array([-np.inf, 0.0]), np.array([1.0, np.inf]), dtype=np.float64),
        spaces.Box(-np.inf, 5, shape=(3,), dtype=np.int16),
        spaces.Box(
            low=np.array([-np.inf, 0.0, -2.0]), high=np.array([np.inf, 1.0, 2.0]), dtype=np.int32
        ),
        spaces.Box(np.iinfo(np.int64).min, np.iinfo(np.int64).max - 1, (2,), np.int64),
        spaces.Box(np.float32(0.1), np.float32(0.7), shape=(2,), dtype=np.float32),
        spaces.Box(-1.5, 1.5, shape=(), dtype=np.float16),
    ],
    ids=repr,
)
def test_box_description_keeps_bounds_and_boundedness(space: spaces.Box[Any]) -> None:
    description = describe_space(space)
    rebuilt = space_from_description(json.loads(json.dumps(description, allow_nan=False)))
    assert isinstance(rebuilt, spaces.Box)
    assert rebuilt.dtype == space.dtype
    assert rebuilt.shape == space.shape
    np.testing.assert_array_equal(rebuilt.low, space.low, strict=True)
    np.testing.assert_array_equal(rebuilt.high, space.high, strict=True)
    np.testing.assert_array_equal(rebuilt.bounded_below, space.bounded_below)
    np.testing.assert_array_equal(rebuilt.bounded_above, space.bounded_above)


def test_description_writes_non_finite_floats_as_strings() -> None:
    description = describe_space(SPACES["box-per-element"])
    assert description == {
        "type": "Box",
        "shape": [3],
        "dtype": "float32",
        "low": [-1.0, 0.0, "-inf"],
        "high": [1.0, "inf", 3.5],
    }
    assert describe_space(SPACES["box-int64-unbounded"])["low"] == "-inf"


def test_dict_description_keeps_key_order() -> None:
    description = describe_space(NESTED)
    assert [key for key, _ in description["spaces"]] == ["pos", "inner", "angle"]
    rebuilt = space_from_description(description)
    assert isinstance(rebuilt, spaces.Dict)
    assert list(rebuilt.spaces) == ["pos", "inner", "angle"]


class Custom(spaces.Space[int]):
    def sample(self, mask: Any = None, probability: Any = None) -> int:
        return 1

    def contains(self, x: Any) -> bool:
        return x == 1


def test_custom_space_is_described_and_rebuilt_as_an_unknown_space() -> None:
    description = describe_space(Custom())
    json.dumps(description)
    assert description["type"] == "Custom"
    assert description["class"].endswith("Custom")
    rebuilt = space_from_description(description)
    assert isinstance(rebuilt, UnknownSpace)
    assert rebuilt.name == "Custom"
    assert rebuilt == space_from_description(description)
    with pytest.raises(ConfigurationError, match="Cannot sample Custom: the file describes it"):
        rebuilt.sample()


def test_an_unknown_sub_space_is_json_and_the_rest_of_the_dict_keeps_its_columns() -> None:
    space = spaces.Dict({"pos": spaces.Box(-1.0, 1.0, (2,)), "custom": Custom()})
    recorded = codec_for(space)
    rebuilt = codec_for(space_from_description(describe_space(space)))
    assert rebuilt.arrow_type.equals(recorded.arrow_type)
    assert str(rebuilt.arrow_type) == "struct<custom: string, pos: fixed_size_list<item: float>[2]>"
    array = recorded.encode([{"pos": np.zeros(2, np.float32), "custom": 1}])
    decoded = rebuilt.decode(array)[0]
    assert decoded["custom"] == 1 and decoded["pos"].tolist() == [0.0, 0.0]
    assert rebuilt.contains(array).tolist() == [True]
    assert codec_in(rebuilt, space) is not rebuilt  # the env's own space converts its JSON
    assert codec_in(recorded, space) is recorded  # no unknown space: the file's codec


def test_unknown_spaces_names_each_by_where_it_is() -> None:
    space = spaces.Dict(
        {"a": Custom(), "b": spaces.Tuple([spaces.Discrete(2), Custom()]), "c": spaces.Discrete(2)}
    )
    unknown = ": Custom is not a Gymnasium space episode-audit knows: stored as JSON"
    assert unknown_spaces(describe_space(space), "observation") == [
        "observation['a']" + unknown,
        "observation['b'][1]" + unknown,
    ]
    assert unknown_spaces(describe_space(spaces.Discrete(2)), "action") == []
    assert unknown_spaces(describe_space(Custom()), "action") == [
        "action: Custom is not a Gymnasium space episode-audit knows: stored as JSON"
    ]


def test_custom_space_uses_the_json_fallback() -> None:
    codec = codec_for(Custom())
    array = codec.encode([1, 1, None])
    assert codec.decode(array) == [1, 1, None]
    assert codec.contains(array).tolist() == [True, True, True]


@pytest.mark.parametrize(
    ("description", "match"),
    [
        ("Box", "Expect a space description"),
        ({}, "Expect a space description"),
        ({"type": "Nope"}, "Expect a space type .*actually: 'Nope'"),
        ({"type": "Box", "shape": [2]}, "KeyError"),
        (
            {"type": "Box", "shape": [2], "dtype": "float32", "low": [0.0], "high": 1.0},
            "with 2 values",
        ),
        (
            {"type": "Box", "shape": [1], "dtype": "float32", "low": "low", "high": 1.0},
            "Expect a number",
        ),
        ({"type": "Box", "shape": [1], "dtype": "int8", "low": 1.5, "high": 2}, "integer Box"),
        ({"type": "Box", "shape": [1], "dtype": "float32", "low": 2.0, "high": 1.0}, "low"),
        ({"type": "Box", "shape": [1], "dtype": "complex64", "low": 0, "high": 1}, "dtype"),
        ({"type": "Discrete", "n": 0, "start": 0, "dtype": "int64"}, "positive"),
        ({"type": "Dict", "spaces": [["a", {"type": "Nope"}]]}, "Nope"),
    ],
)
def test_invalid_descriptions_raise(description: Any, match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        space_from_description(description)


# --------------------------------------------------------------------------------------------
# codec_for errors
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("space", "kwargs", "match"),
    [
        (spaces.Discrete(2), {"digest_min_bytes": -1}, "digest_min_bytes"),
        (spaces.Box(0.0, 1.0, shape=(0,)), {}, "at least one element"),
        (spaces.Dict({"a": spaces.Dict({1: spaces.Discrete(2)})}), {}, "str keys"),
        *(
            [(spaces.Discrete(4, start=2**63 - 2, dtype=np.uint64), {}, "fit int64")]
            if DISCRETE_DTYPE
            else []
        ),
    ],
)
def test_codec_for_rejects(space: Any, kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        codec_for(space, **kwargs)


# --------------------------------------------------------------------------------------------
# Property: random samples of random spaces round-trip exactly
# --------------------------------------------------------------------------------------------

BOX_DTYPES = [
    np.float16,
    np.float32,
    np.float64,
    np.int8,
    np.int16,
    np.int32,
    np.int64,
    np.uint8,
    np.uint16,
    np.uint32,
    np.uint64,
    np.bool_,
]
SHAPES = st.lists(st.integers(1, 4), min_size=0, max_size=3).map(tuple)


@st.composite
def boxes(draw: st.DrawFn) -> spaces.Box[Any]:
    dtype = np.dtype(draw(st.sampled_from(BOX_DTYPES)))
    shape = draw(SHAPES)
    if dtype.kind == "b":
        return spaces.Box(0, 1, shape=shape, dtype=dtype)
    info = np.iinfo(dtype) if dtype.kind in "iu" else None
    lowest = -1000 if info is None else max(-1000, int(info.min))
    highest = 1000 if info is None else min(1000, int(info.max))
    low = draw(st.integers(lowest, highest))
    high = draw(st.integers(low, highest))
    if dtype.kind == "f":
        return spaces.Box(
            -np.inf if draw(st.booleans()) else float(low),
            np.inf if draw(st.booleans()) else float(high),
            shape=shape,
            dtype=dtype,
        )
    return spaces.Box(low, high, shape=shape, dtype=dtype)


@st.composite
def multi_discretes(draw: st.DrawFn) -> spaces.MultiDiscrete:
    shape = draw(SHAPES.filter(lambda s: len(s) > 0))
    dtype = np.dtype(draw(st.sampled_from([np.int8, np.int32, np.int64, np.uint16])))
    nvec = draw(hnp.arrays(dtype, shape, elements=st.integers(1, 50)))
    lowest = 0 if dtype.kind == "u" else -50
    start = draw(hnp.arrays(dtype, shape, elements=st.integers(lowest, 50)))
    return spaces.MultiDiscrete(nvec, dtype=dtype, start=start)


@st.composite
def discretes(draw: st.DrawFn) -> spaces.Discrete[Any]:
    return spaces.Discrete(draw(st.integers(1, 2**40)), start=draw(st.integers(-(2**40), 2**40)))


@settings(max_examples=60, deadline=None)
@given(
    space=st.one_of(boxes(), multi_discretes(), discretes()),
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 20),
    null_at=st.none() | st.integers(0, 19),
)
def test_random_samples_of_random_spaces_round_trip_exactly(
    space: spaces.Space[Any], seed: int, n: int, null_at: int | None
) -> None:
    codec = codec_for(space)
    values: list[Any] = samples(space, n, seed)
    # (Gymnasium 1.2's Box(126, 126, (), int8).sample() gives 125 under numpy 2.5: its own
    # space refuses it; a sample the space itself holds is what this is about)
    with warnings.catch_warnings():  # (Box.contains warns of a numpy scalar it casts)
        warnings.simplefilter("ignore")
        assume(all(space.contains(value) for value in values))
    if null_at is not None and null_at < n:
        values[null_at] = None
    buffer = codec.new_buffer()
    for value in values:
        if value is None:
            buffer.append_null()
        else:
            assert buffer.append(value) is None
    array = through_ipc(codec, buffer.finish())[1]
    for value, got in zip(values, codec.decode(array), strict=True):
        if value is None:
            assert got is None
        else:
            assert_same(space, value, got)
    assert codec.contains(array).all()
    equal, diff = codec.compare(array, codec.encode(values))
    assert equal.all()
    assert not diff.any()
    assert space_from_description(describe_space(space)) == space


@settings(max_examples=60, deadline=None)
@given(
    data=st.data(),
    dtype=st.sampled_from(BOX_DTYPES),
    shape=SHAPES,
)
def test_any_array_of_the_box_dtype_round_trips_bit_for_bit(
    data: st.DataObject, dtype: type[Any], shape: tuple[int, ...]
) -> None:
    space = spaces.Box(0, 1, shape=shape, dtype=dtype)
    codec = codec_for(space)
    values = data.draw(st.lists(hnp.arrays(np.dtype(dtype), shape), min_size=1, max_size=5))
    buffer = codec.new_buffer()
    for value in values:
        assert buffer.append(value) is None
    decoded = codec.decode(buffer.finish())
    for value, got in zip(values, decoded, strict=True):
        assert got.dtype == value.dtype
        assert got.shape == value.shape
        assert got.tobytes() == value.tobytes()


def test_public_api_is_sorted() -> None:
    from episode_audit.format import spaces as module

    assert module.__all__ == sorted(module.__all__)
    assert all(hasattr(module, name) for name in module.__all__)


def test_ipc_round_trip_through_a_file(tmp_path: Path) -> None:
    space = SPACES["dict-nested-tuple"]
    codec = codec_for(space)
    values = samples(space, 4)
    schema = pa.schema([codec.field("observation")])
    path = tmp_path / "steps.arrow"
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_stream(sink, schema) as writer:
        writer.write_batch(pa.record_batch([codec.encode(values)], schema=schema))
    with pa.OSFile(str(path), "rb") as source:
        table = pa.ipc.open_stream(source).read_all()
    for value, got in zip(values, codec.decode(table.column("observation")), strict=True):
        assert_same(space, value, got)


@pytest.mark.parametrize(
    ("space", "batch", "refused"),
    [
        (spaces.Box(-1, 1, (3,), np.float32), np.arange(12, dtype=np.float32).reshape(4, 3), None),
        (
            spaces.Box(-1, 1, (2, 2), np.float64),
            np.zeros((3, 2, 2)),
            np.zeros((3, 2, 2), np.float32),
        ),
        (spaces.Discrete(5), np.array([4, 0, 2], np.int32), np.array([1.0, 2.0])),
        (spaces.Dict({"a": spaces.Discrete(2)}), np.zeros(2, np.int64), None),
    ],
)
def test_extend_takes_a_batch_as_it_is_or_nothing(
    space: spaces.Space[Any], batch: np.ndarray[Any, Any], refused: np.ndarray[Any, Any] | None
) -> None:
    codec = codec_for(space)
    one_by_one, at_once = codec.new_buffer(), codec.new_buffer()
    if not at_once.extend(batch):
        assert isinstance(space, spaces.Dict) and len(at_once) == 0  # no batch form: row by row
        return
    for row in batch:
        assert one_by_one.append(row) is None
    assert at_once.finish().equals(one_by_one.finish())
    if refused is not None:
        assert not at_once.extend(refused) and len(at_once) == 0  # a cast is never silent


def test_from_raw_takes_rows_of_the_space_dtype_and_shape_back_to_back() -> None:
    codec = codec_for(spaces.Box(0.0, 10.0, (2, 2), np.float32))
    rows = np.arange(8, dtype=np.float32).reshape(2, 2, 2)
    assert codec.raw_rows == (np.dtype(np.float32), (2, 2))
    column = codec.from_raw(rows.tobytes())
    assert column.type == codec.arrow_type
    assert codec.compare(column, codec.encode(list(rows)))[0].tolist() == [True, True]
    with pytest.raises(ValueError, match="whole rows of 4 values, actually: 6 values"):
        codec.from_raw(rows.tobytes()[:24])
    discrete = codec_for(spaces.Discrete(3))
    assert discrete.raw_rows is None
    with pytest.raises(NotImplementedError, match="has no raw rows"):
        discrete.from_raw(b"")


def test_a_buffer_of_camera_frames_takes_a_recorder_block_without_growing() -> None:
    # Doubling a block of 720 kB rows copies every row again at each step; a large-row buffer
    # starts with a recorder block's worth (numpy commits the memory only as rows arrive).
    codec = codec_for(spaces.Box(0, 255, shape=(400, 600, 3), dtype=np.uint8))
    buffer = codec.new_buffer()
    block = buffer._data  # type: ignore[attr-defined]
    frame = np.zeros((400, 600, 3), np.uint8)
    rows = (32 << 20) // frame.nbytes  # what the recorder puts in one block of such rows
    for i in range(rows):
        frame[0, 0, 0] = i
        buffer.append(frame)
    assert buffer._data is block  # type: ignore[attr-defined]
    column = buffer.finish()
    assert len(column) == rows and column[rows - 1].values[0].as_py() == rows - 1
    # small rows keep their small first block
    assert len(codec_for(spaces.Box(-1, 1, (4,))).new_buffer()._data) == 1024  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "space",
    [spaces.Box(0, 255, (32, 32, 3), np.uint8), spaces.Box(-1, 1, (6,), np.float32)],
    ids=["frames", "vector"],
)
def test_a_block_handed_to_arrow_is_taken_back_only_once_it_is_recycled(
    space: spaces.Space[Any],
) -> None:
    buffer = codec_for(space).new_buffer()
    rng = np.random.default_rng(0)
    rows = [space.sample() for _ in range(3)] + [rng.integers(0, 9, space.shape) for _ in range(3)]

    def fill(values: list[Any]) -> pa.Array:
        for value in values:
            buffer.append(np.asarray(value, dtype=space.dtype))
        return buffer.finish()

    size = len(buffer._data)  # type: ignore[attr-defined]
    first = fill(rows[:3] * (size // 3))  # (full blocks: handed over, not copied)
    kept = first.to_pylist()
    second = fill(rows[3:] * (size // 3))  # (first not recycled: a new block to write into)
    memory = second.values.buffers()[1].address
    buffer.recycle()  # nothing refers to second's memory any more: the next hand-over...
    del second
    third = fill(rows[3:] * (size // 3))  # ...takes it back, to write fourth's rows into
    fourth = fill(rows[3:] * (size // 3))
    assert fourth.values.buffers()[1].address == memory
    fifth = fill(rows[:3] * (size // 3))  # (not recycled since: a new block again)
    addresses = {a.values.buffers()[1].address for a in (first, third, fourth, fifth)}
    assert len(addresses) == 4
    assert first.to_pylist() == fifth.to_pylist() == kept  # never written over
    assert third.to_pylist() == fourth.to_pylist() != kept


def test_a_recycling_callers_rows_go_into_two_blocks_in_turn_however_few() -> None:
    # (a recorder's flushes: each block written and dropped, then recycled)
    space = spaces.Box(0, 255, (32, 32, 3), np.uint8)
    buffer = codec_for(space).new_buffer()
    rows = [space.sample() for _ in range(3)]
    addresses = []
    for _ in range(6):
        for row in rows:
            buffer.append(row)
        array = buffer.finish()
        assert array.to_pylist() == pa.array([r.reshape(-1) for r in rows]).to_pylist()
        addresses.append(array.values.buffers()[1].address)
        del array
        buffer.recycle()
    assert len(set(addresses[1:])) == 2  # (the first, before any recycle, is a copy)


def test_a_discrete_of_another_dtype_is_rebuilt_where_gymnasium_can() -> None:
    """Gymnasium 1.1's Discrete is always int64: another dtype is told, not guessed."""
    desc = {"type": "Discrete", "n": 3, "start": 10, "dtype": "int32"}
    if DISCRETE_DTYPE:
        assert space_from_description(desc) == spaces.Discrete(3, start=10, dtype=np.int32)
    else:
        with pytest.raises(
            ConfigurationError, match=r"^a Discrete space of dtype int32 needs Gymnasium >= 1\.2 "
        ):
            space_from_description(desc)
    assert space_from_description({**desc, "dtype": "int64"}) == spaces.Discrete(3, start=10)
