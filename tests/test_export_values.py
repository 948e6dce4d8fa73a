from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
from gymnasium import spaces

from episode_audit.export._values import (
    NONFINITE_NULL,
    Split,
    json_rows,
    json_schema,
    split_column,
)
from episode_audit.format.spaces.codecs import codec_for


def _split(space: spaces.Space, values: list, **options: int | None) -> Split:
    codec = codec_for(space, **options)
    return split_column(("observation",), codec.encode(values), codec.field("observation"))


def test_large_arrays_are_left_out_and_images_are_frames() -> None:
    big = spaces.Box(-1, 1, (65,), np.float32)
    assert _split(big, [np.zeros(65, np.float32)]).left_out == ["observation"]
    grid = spaces.Box(0, 255, (7, 7, 3), np.uint8)  # MiniGrid-sized: not a camera, too many
    assert _split(grid, [np.zeros((7, 7, 3), np.uint8)]).left_out == ["observation"]
    camera = spaces.Box(0, 255, (16, 20), np.uint8)
    frame = np.arange(320, dtype=np.uint8).reshape(16, 20)
    (frames,) = _split(camera, [frame, frame]).images
    assert frames.pixels.shape == (2, 16, 20) and (frames.pixels[1] == frame).all()
    digest = _split(
        spaces.Box(0, 255, (32, 32, 3), np.uint8),
        [np.zeros((32, 32, 3), np.uint8)],
        digest_min_bytes=64,
    )
    assert digest.left_out == ["observation"] and not digest.images


def test_json_values_and_schema() -> None:
    space = spaces.Dict(
        {
            "pos": spaces.Box(-np.inf, np.inf, (2,), np.float64),
            "bits": spaces.MultiBinary(3),
            "gear": spaces.Discrete(4, start=1),
            "speed": spaces.Box(0, 1, (), np.float32),
        }
    )
    rows = [
        {
            "pos": np.array([1.0, math.nan]),
            "bits": np.array([1, 0, 1], np.int8),
            "gear": 2,
            "speed": np.float32(0.5),
        },
    ]
    split = _split(space, rows)
    assert json_rows(split.leaves, 1) == [
        {"pos": [1.0, None], "bits": [1, 0, 1], "gear": 2, "speed": 0.5}
    ]
    assert json_schema(split.leaves) == {
        "type": "object",
        "properties": {
            "pos": {"type": "array", "items": {"type": "number", "description": NONFINITE_NULL}},
            "bits": {"type": "array", "items": {"type": "integer"}},
            "gear": {"type": "integer"},
            "speed": {"type": "number", "description": NONFINITE_NULL},
        },
    }


def test_a_null_row_has_no_value() -> None:
    codec = codec_for(spaces.Box(-1, 1, (2,), np.float32))
    good = codec.encode([np.zeros(2, np.float32)])
    array = pa.concat_arrays([good, pa.nulls(1, good.type)])
    split = split_column(("action",), array, codec.field("action"))
    assert json_rows(split.leaves, 2) == [[0.0, 0.0], None]


def test_metadata_that_does_not_describe_the_column_leaves_it_out() -> None:
    """A file not from our recorder may say anything in a field's metadata: never a crash."""
    codec = codec_for(spaces.Box(-1, 1, (4,), np.float32))
    column = codec.encode([np.zeros(4, np.float32)])
    plain = codec.field("observation")
    for shape, dtype in [
        (b"5", b"float32"),  # not a list
        (b"[" * 100_000, b"float32"),  # nested past the JSON bound
        (b'["a"]', b"float32"),
        (b"[-1]", b"float32"),
        (b"[3]", b"float32"),  # 3 numbers a row, where the column has 4
        (b"[4]", b"uint8"),  # not the column's type
        (b"[4]", b"no such dtype"),
        (b"[4]", b"\xff"),
    ]:
        meta = {**(plain.metadata or {}), b"episode_audit.shape": shape}
        meta[b"episode_audit.dtype"] = dtype
        split = split_column(("observation",), column, plain.with_metadata(meta))
        assert split.left_out == ["observation"] and not split.leaves, (shape, dtype)
    for kind in (b"discrete", b"dict", b"json", b"\xa3\xff"):  # another kind; not UTF-8
        meta = {**(plain.metadata or {}), b"episode_audit.kind": kind}
        split = split_column(("observation",), column, plain.with_metadata(meta))
        assert split.left_out == ["observation"] and not split.leaves, kind
    assert split_column(("observation",), column, plain).leaves  # (as the recorder wrote it)
