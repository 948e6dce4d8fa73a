"""Space codecs: the Arrow type of a space, and whole-column decode, contains and compare.

:func:`codec_for` picks the :class:`SpaceCodec` of a space (how each space is stored:
``docs/format.md``, "Space → Arrow"); :func:`equal_elements` is the one element-wise compare rule
(bitwise, NaN equal to NaN, optional ``atol``) the codecs and replay share.
"""

from __future__ import annotations

import abc
import json
import math
from collections.abc import Iterable
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc
from gymnasium import spaces
from gymnasium.spaces import Space

from ...errors import ConfigurationError
from ..columns import null_mask, one_array
from ..records import from_json
from .buffers import (
    _DIGEST_SIZE,
    _INT64_MAX,
    _INT64_MIN,
    ColumnBuffer,
    _ArrayBuffer,
    _DigestBuffer,
    _FlatArrayBuffer,
    _IntBuffer,
    _JsonBuffer,
    _StructBuffer,
    _TextBuffer,
)
from .descriptions import UnknownSpace

__all__ = ["SpaceCodec", "codec_for", "codec_in", "equal_elements"]

# Keys of the Arrow field metadata every codec writes (values are UTF-8 strings).
_META_KIND: Final = "episode_audit.kind"
_META_SPACE: Final = "episode_audit.space"
_META_SHAPE: Final = "episode_audit.shape"
_META_DTYPE: Final = "episode_audit.dtype"
_META_DIGEST: Final = "episode_audit.digest"

_DIGEST_NAME: Final = "blake2b-128"
_COMPARE_ELEMENTS: Final = 1 << 20
"""Values an array compare takes per pass (its temporaries are a few times this in bytes)."""
# Up to this many values per row, a column's rows are checked transposed (column by column):
# numpy's inner loops over 4 values per row run ~10x slower than over a block's rows.
_NARROW: Final = 16

_BoolArray = npt.NDArray[np.bool_]
_FloatArray = npt.NDArray[np.float64]


def _equal_strings(expected: pa.Array, got: pa.Array) -> tuple[_BoolArray, _FloatArray]:
    equal: _BoolArray = np.asarray(
        pc.equal(expected, got).fill_null(False).to_numpy(zero_copy_only=False), dtype=np.bool_
    )
    return equal, np.where(equal, 0.0, np.inf)


class SpaceCodec(abc.ABC):
    """The Arrow encoding of one Gymnasium space; build one with :func:`codec_for`.

    ``decode``, ``contains`` and ``compare`` take an Arrow array of :attr:`arrow_type` (a
    ``ChunkedArray`` is combined first) and work on the whole column at once.

    >>> from gymnasium import spaces
    >>> codec = codec_for(spaces.Discrete(3, start=1))
    >>> array = codec.encode([1, 3, None, 5])
    >>> codec.decode(array)
    [1, 3, None, 5]
    >>> codec.contains(array).tolist()
    [True, True, True, False]
    >>> equal, diff = codec.compare(array, codec.encode([1, 2, None, 5]))
    >>> equal.tolist(), diff.tolist()
    ([True, False, True, True], [0.0, 1.0, 0.0, 0.0])
    """

    kind: str
    """What the column holds: array, digest, discrete, dict, tuple, text or json."""
    space: Space[Any]
    """The space this codec encodes."""
    arrow_type: pa.DataType
    """The Arrow type of the column."""
    raw_rows: tuple[np.dtype[Any], tuple[int, ...]] | None = None
    """For fixed-shape numbers: the dtype and shape of a numpy array whose raw bytes
    (``tobytes()``) :meth:`from_raw` takes as one row; ``None`` for other columns."""

    def _metadata(self) -> dict[str, str]:
        return {_META_KIND: self.kind, _META_SPACE: type(self.space).__name__}

    def from_raw(self, data: bytes) -> pa.Array:
        """Return the column whose rows are ``data``: rows of :attr:`raw_rows`, back to back.

        A way to collect values faster than :meth:`new_buffer`, for arrays that have exactly
        the column's dtype and shape.

        >>> from gymnasium import spaces
        >>> codec = codec_for(spaces.Box(0, 1, (2,), np.float32))
        >>> codec.raw_rows
        (dtype('float32'), (2,))
        >>> rows = [np.array([0, 1], np.float32), np.array([1, 0], np.float32)]
        >>> [v.tolist() for v in codec.decode(codec.from_raw(b"".join(r.tobytes() for r in rows)))]
        [[0.0, 1.0], [1.0, 0.0]]
        """
        raise NotImplementedError(f"{type(self).__name__} has no raw rows")

    def field(self, name: str) -> pa.Field:
        """Return a nullable Arrow field of :attr:`arrow_type` with kind, shape, dtype metadata."""
        return pa.field(name, self.arrow_type, nullable=True, metadata=self._metadata())

    @abc.abstractmethod
    def new_buffer(self) -> ColumnBuffer:
        """Return an empty :class:`ColumnBuffer` for values of this space."""

    def encode(self, values: Iterable[Any]) -> pa.Array:
        """Encode values (``None`` becomes a null row) into one Arrow array."""
        buffer = self.new_buffer()
        for value in values:
            if value is None:
                buffer.append_null()
            else:
                buffer.append(value)
        return buffer.finish()

    def _check(self, array: Any) -> pa.Array:
        if isinstance(array, pa.ChunkedArray):
            array = one_array(array)
        if not isinstance(array, pa.Array):
            raise TypeError(f"Expect a pyarrow Array, actually: {type(array).__name__}")
        if not array.type.equals(self.arrow_type):
            raise TypeError(
                f"Expect an Arrow array of type {self.arrow_type}, actually: {array.type}"
            )
        return array

    def decode(self, array: pa.Array) -> list[Any]:
        """Return the native value of each row (``None`` for a null row)."""
        array = self._check(array)
        values = self._decode_values(array)
        if array.null_count:
            for i in np.flatnonzero(null_mask(array)).tolist():
                values[i] = None
        return values

    def contains(self, array: pa.Array) -> _BoolArray:
        """Return, per row, whether the value is inside the space (null rows count as inside)."""
        array = self._check(array)
        result = self._contains_values(array)
        if array.null_count:
            result[null_mask(array)] = True
        return result

    def compare(
        self,
        expected: pa.Array | pa.ChunkedArray,
        got: pa.Array | pa.ChunkedArray,
        *,
        atol: float = 0.0,
    ) -> tuple[_BoolArray, _FloatArray]:
        """Compare two columns row by row; return ``(equal, max_abs_diff)``.

        A chunked ``expected`` is compared chunk by chunk (its chunks are not joined, so not
        copied); wide rows are compared a few at a time, so the temporaries stay small.

        With ``atol == 0`` numbers must be bitwise equal (NaN equals NaN); otherwise numeric
        values are equal when ``|a - b| <= atol``. Text, digests and JSON values differ by 0.0
        when equal and by infinity when not; so do a null and a non-null row.
        """
        if not atol >= 0.0 or math.isinf(atol):
            raise ValueError(f"Expect atol to be a finite float >= 0, actually: {atol!r}")
        if isinstance(expected, pa.ChunkedArray) and expected.num_chunks > 1:
            # chunk by chunk: joining the chunks would copy the column (camera frames)
            if len(expected) != len(got):
                raise ValueError(
                    f"Expect arrays of the same length, actually: {len(expected)} and {len(got)}"
                )
            parts, offset = [], 0
            for chunk in expected.chunks:
                parts.append(self.compare(chunk, got.slice(offset, len(chunk)), atol=atol))
                offset += len(chunk)
            return (
                np.concatenate([equal for equal, _ in parts]),
                np.concatenate([diff for _, diff in parts]),
            )
        expected = self._check(expected)
        got = self._check(got)
        if len(expected) != len(got):
            raise ValueError(
                f"Expect arrays of the same length, actually: {len(expected)} and {len(got)}"
            )
        equal, diff = self._compare_values(expected, got, float(atol))
        if expected.null_count or got.null_count:
            expected_null = null_mask(expected)
            got_null = null_mask(got)
            both = expected_null & got_null
            one = expected_null ^ got_null
            equal[both] = True
            diff[both] = 0.0
            equal[one] = False
            diff[one] = np.inf
        return equal, diff

    @abc.abstractmethod
    def _decode_values(self, array: pa.Array) -> list[Any]:
        """Decode every row; values of null rows are arbitrary."""

    @abc.abstractmethod
    def _contains_values(self, array: pa.Array) -> _BoolArray:
        """Return a writable bool array; values of null rows are arbitrary."""

    @abc.abstractmethod
    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        """Return writable arrays; values of null rows are arbitrary."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.space}, {self.arrow_type})"


class _ArrayCodec(SpaceCodec):
    """Box, MultiDiscrete and MultiBinary: a fixed-size list of the space's dtype."""

    kind = "array"

    def __init__(self, space: Space[Any], low: npt.NDArray[Any], high: npt.NDArray[Any]) -> None:
        self.space = space
        self._shape: tuple[int, ...] = tuple(int(d) for d in space.shape or ())
        self._dtype: np.dtype[Any] = np.dtype(space.dtype)
        self._size = math.prod(self._shape)
        if self._size == 0:
            raise ConfigurationError(
                f"Expect a space with at least one element per value, actually: {space} "
                f"(shape {self._shape}); Arrow fixed-size lists cannot be empty"
            )
        self._low_flat = np.broadcast_to(low, self._shape).reshape(self._size)
        self._high_flat = np.broadcast_to(high, self._shape).reshape(self._size)
        self._value_type = pa.from_numpy_dtype(self._dtype)
        self.arrow_type = pa.list_(self._value_type, self._size)
        self.raw_rows = (self._dtype, self._shape)

    def from_raw(self, data: bytes) -> pa.Array:
        """Return the column whose rows are ``data`` (see :meth:`SpaceCodec.from_raw`)."""
        flat = np.frombuffer(data, dtype=self._dtype)
        if flat.size % self._size:
            raise ValueError(
                f"Expect whole rows of {self._size} values, actually: {flat.size} values"
            )
        values = pa.array(flat, type=self._value_type)
        return pa.FixedSizeListArray.from_arrays(values, list_size=self._size)

    def _metadata(self) -> dict[str, str]:
        return {
            **super()._metadata(),
            _META_SHAPE: json.dumps(list(self._shape)),
            _META_DTYPE: self._dtype.name,
        }

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer backed by a preallocated numpy block."""
        cls = _FlatArrayBuffer if len(self._shape) == 1 else _ArrayBuffer
        return cls(self._shape, self._dtype, self._value_type)

    def _block(self, array: pa.Array) -> npt.NDArray[Any]:
        """Return the values as one read-only numpy array of shape ``(len(array), *shape)``."""
        values = array.values.slice(array.offset * self._size, len(array) * self._size)
        if values.null_count:
            values = values.fill_null(pa.scalar(self._dtype.type(0).item(), values.type))
        flat = values.to_numpy(zero_copy_only=False)
        block: npt.NDArray[Any] = flat.astype(self._dtype, copy=False).reshape(
            (len(array), *self._shape)
        )
        return block

    def _decode_values(self, array: pa.Array) -> list[Any]:
        block = self._block(array).copy()
        if self._shape:
            return list(block)
        return [block[i, ...] for i in range(len(block))]

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        n = len(array)
        rows = self._block(array).reshape(n, self._size)
        low, high = self._low_flat, self._high_flat
        if self._size <= _NARROW:
            # numpy's inner loops are slow over a few values per row: compare column by column
            columns = np.ascontiguousarray(rows.T)
            inside = (columns >= low[:, None]) & (columns <= high[:, None])
            return np.asarray(inside.all(axis=0), dtype=np.bool_)
        return np.asarray(((rows >= low) & (rows <= high)).all(axis=1), dtype=np.bool_)

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        n = len(expected)
        a = self._block(expected).reshape(n, self._size)
        b = self._block(got).reshape(n, self._size)
        rows = max(1, _COMPARE_ELEMENTS // self._size)
        if n <= rows:  # one pass (small observations: a whole replay window)
            return self._compare_rows(a, b, atol)
        # in passes of whole rows: the temporaries stay small (camera frames)
        equal = np.empty(n, dtype=np.bool_)
        max_diff = np.empty(n, dtype=np.float64)
        for start in range(0, n, rows):
            stop = start + rows
            equal[start:stop], max_diff[start:stop] = self._compare_rows(
                a[start:stop], b[start:stop], atol
            )
        return equal, max_diff

    def _compare_rows(
        self, a: npt.NDArray[Any], b: npt.NDArray[Any], atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        n = len(a)
        bits = np.dtype(f"u{self._dtype.itemsize}")
        if (a.view(bits) == b.view(bits)).all():  # the usual case: one reduction, none per row
            return np.ones(n, dtype=np.bool_), np.zeros(n, dtype=np.float64)
        same = equal_elements(a, b)
        with np.errstate(all="ignore"):
            diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
        diff[same] = 0.0
        diff[np.isnan(diff)] = np.inf
        if atol > 0.0:
            same |= diff <= atol
        equal: _BoolArray = np.asarray(same.all(axis=1), dtype=np.bool_)
        max_diff: _FloatArray = diff.max(axis=1, initial=0.0)
        return equal, max_diff


def equal_elements(a: npt.NDArray[Any], b: npt.NDArray[Any], atol: float = 0.0) -> _BoolArray:
    """Element by element, whether two numeric arrays of one shape are equal as compared.

    Bitwise when their dtypes agree (else by value), NaN equal to NaN, or within ``atol``.

    >>> a, b = np.array([0.0, np.nan, 1.0]), np.array([-0.0, np.nan, 1.25])
    >>> equal_elements(a, b).tolist(), equal_elements(a, b, 0.5).tolist()
    ([False, True, False], [True, True, True])
    """
    if a.dtype == b.dtype:
        bits = np.dtype(f"u{a.dtype.itemsize}")
        same: _BoolArray = a.view(bits) == b.view(bits)
    else:
        same = np.asarray(a == b, dtype=np.bool_)
    if a.dtype.kind == "f" or b.dtype.kind == "f":
        same |= np.isnan(a) & np.isnan(b)
    if atol > 0.0:
        with np.errstate(all="ignore"):
            same |= np.abs(a.astype(np.float64) - b.astype(np.float64)) <= atol
    return same


class _DigestCodec(SpaceCodec):
    """A Box leaf stored as the BLAKE2b-128 digest of its bytes (large images)."""

    kind = "digest"

    def __init__(self, space: spaces.Box[Any]) -> None:
        self.space = space
        self._shape = space.shape
        self._dtype: np.dtype[Any] = np.dtype(space.dtype)
        self.arrow_type = pa.binary(_DIGEST_SIZE)

    def _metadata(self) -> dict[str, str]:
        return {
            **super()._metadata(),
            _META_SHAPE: json.dumps(list(self._shape)),
            _META_DTYPE: self._dtype.name,
            _META_DIGEST: _DIGEST_NAME,
        }

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer that keeps one 16-byte digest per value."""
        return _DigestBuffer(self._shape, self._dtype)

    def _decode_values(self, array: pa.Array) -> list[Any]:
        rows: list[Any] = array.to_pylist()
        return rows

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        return np.ones(len(array), dtype=np.bool_)

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        return _equal_strings(expected, got)


class _DiscreteCodec(SpaceCodec):
    kind = "discrete"

    def __init__(self, space: spaces.Discrete[Any]) -> None:
        self.space = space
        self._start = int(space.start)
        self._last = int(space.start) + int(space.n) - 1
        if not _INT64_MIN <= self._start <= self._last <= _INT64_MAX:
            raise ConfigurationError(
                f"Expect a Discrete space whose values fit int64, actually: {space}"
            )
        self.arrow_type = pa.int64()

    def _metadata(self) -> dict[str, str]:
        return {**super()._metadata(), _META_SHAPE: "[]", _META_DTYPE: str(self.space.dtype)}

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer backed by a preallocated int64 block."""
        return _IntBuffer()

    @staticmethod
    def _numbers(array: pa.Array) -> npt.NDArray[np.int64]:
        if array.null_count:
            array = array.fill_null(0)
        numbers: npt.NDArray[np.int64] = array.to_numpy(zero_copy_only=False)
        return numbers

    def _decode_values(self, array: pa.Array) -> list[Any]:
        rows: list[Any] = self._numbers(array).tolist()
        return rows

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        numbers = self._numbers(array)
        result: _BoolArray = (numbers >= self._start) & (numbers <= self._last)
        return result

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        a = self._numbers(expected)
        b = self._numbers(got)
        equal: _BoolArray = np.asarray(a == b, dtype=np.bool_)
        diff: _FloatArray = np.abs(a.astype(np.float64) - b.astype(np.float64))
        diff[equal] = 0.0
        if atol > 0.0:
            equal |= diff <= atol
        return equal, diff


class _StructCodec(SpaceCodec):
    """Dict (key order kept) and Tuple (fields ``"0"``, ``"1"``, …): one child codec per item."""

    def __init__(
        self,
        space: Space[Any],
        keys: tuple[Any, ...],
        children: list[SpaceCodec],
        *,
        tuple_: bool,
    ) -> None:
        self.space = space
        self.kind = "tuple" if tuple_ else "dict"
        self._keys = keys
        self._children = children
        self._tuple = tuple_
        self._fields = [child.field(str(key)) for key, child in zip(keys, children, strict=True)]
        self.arrow_type = pa.struct(self._fields)

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer with one child buffer per item."""
        return _StructBuffer(
            self._keys,
            [child.new_buffer() for child in self._children],
            self._fields,
            tuple_=self._tuple,
        )

    def _decode_values(self, array: pa.Array) -> list[Any]:
        n = len(array)
        columns = [c.decode(a) for c, a in zip(self._children, array.flatten(), strict=True)]
        if self._tuple:
            return [tuple(column[i] for column in columns) for i in range(n)]
        return [
            {k: column[i] for k, column in zip(self._keys, columns, strict=True)} for i in range(n)
        ]

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        result = np.ones(len(array), dtype=np.bool_)
        for child, child_array in zip(self._children, array.flatten(), strict=True):
            result &= child.contains(child_array)
        return result

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        equal = np.ones(len(expected), dtype=np.bool_)
        diff = np.zeros(len(expected), dtype=np.float64)
        for child, a, b in zip(self._children, expected.flatten(), got.flatten(), strict=True):
            child_equal, child_diff = child.compare(a, b, atol=atol)
            equal &= child_equal
            np.maximum(diff, child_diff, out=diff)
        return equal, diff


class _TextCodec(SpaceCodec):
    kind = "text"

    def __init__(self, space: spaces.Text) -> None:
        self.space = space
        self._min = space.min_length
        self._max = space.max_length
        chars = "".join(f"\\x{{{ord(c):x}}}" for c in sorted(space.character_set))
        # RE2 syntax; \A and \z anchor the whole string, not a line.
        self._pattern = f"\\A[{chars}]*\\z" if chars else None
        self.arrow_type = pa.string()

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer of strings."""
        return _TextBuffer(pa.string())

    def _decode_values(self, array: pa.Array) -> list[Any]:
        rows: list[Any] = array.to_pylist()
        return rows

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        lengths = pc.utf8_length(array).fill_null(0).to_numpy(zero_copy_only=False)
        result: _BoolArray = (lengths >= self._min) & (lengths <= self._max)
        if self._pattern is None:
            result &= lengths == 0
        else:
            charset = pc.match_substring_regex(array, self._pattern).fill_null(True)
            result &= charset.to_numpy(zero_copy_only=False)
        return result

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        return _equal_strings(expected, got)


class _JsonCodec(SpaceCodec):
    """Any other space: ``json.dumps(space.to_jsonable([value])[0])`` in a string column."""

    kind = "json"

    def __init__(self, space: Space[Any]) -> None:
        self.space = space
        self.arrow_type = pa.string()

    def new_buffer(self) -> ColumnBuffer:
        """Return an empty buffer that keeps each value as JSON text."""
        return _JsonBuffer(self.space)

    def _from_json(self, text: str) -> Any:
        return self.space.from_jsonable([from_json(text, "a JSON-coded value")])[0]

    def _decode_values(self, array: pa.Array) -> list[Any]:
        return [None if text is None else self._from_json(text) for text in array.to_pylist()]

    def _contains_values(self, array: pa.Array) -> _BoolArray:
        result = np.ones(len(array), dtype=np.bool_)
        for i, text in enumerate(array.to_pylist()):
            if text is not None:
                try:
                    result[i] = self.space.contains(self._from_json(text))
                except Exception:  # a value from_jsonable cannot rebuild is not in the space
                    result[i] = False
        return result

    def _compare_values(
        self, expected: pa.Array, got: pa.Array, atol: float
    ) -> tuple[_BoolArray, _FloatArray]:
        return _equal_strings(expected, got)


def codec_for(space: Space[Any], *, digest_min_bytes: int | None = None) -> SpaceCodec:
    """Return the codec that stores values of ``space`` in Arrow.

    With ``digest_min_bytes``, every Box leaf whose one value takes at least that many bytes is
    stored as a 16-byte BLAKE2b digest instead (values cannot be decoded back, only compared).

    >>> import numpy as np
    >>> from gymnasium import spaces
    >>> image = spaces.Box(0, 255, shape=(64, 64, 3), dtype=np.uint8)
    >>> codec_for(spaces.Dict({"image": image, "speed": spaces.Discrete(3)})).arrow_type
    StructType(struct<image: fixed_size_list<item: uint8>[12288], speed: int64>)
    >>> codec_for(image, digest_min_bytes=4096).arrow_type
    FixedSizeBinaryType(fixed_size_binary[16])

    Raises :class:`ConfigurationError` for a space that cannot be stored (a Dict with non-string
    keys, an empty Box, a Discrete beyond int64) or a negative ``digest_min_bytes``.
    """
    if digest_min_bytes is not None and (
        not isinstance(digest_min_bytes, int)
        or isinstance(digest_min_bytes, bool)
        or digest_min_bytes < 0
    ):
        raise ConfigurationError(
            f"Expect digest_min_bytes to be None or an int >= 0, actually: {digest_min_bytes!r}"
        )
    if isinstance(space, spaces.Box):
        nbytes = space.dtype.itemsize * math.prod(space.shape)
        if digest_min_bytes is not None and nbytes >= digest_min_bytes:
            return _DigestCodec(space)
        return _ArrayCodec(space, space.low, space.high)
    if isinstance(space, spaces.Discrete):
        return _DiscreteCodec(space)
    if isinstance(space, spaces.MultiDiscrete):
        return _ArrayCodec(space, space.start, space.start + (space.nvec - 1))
    if isinstance(space, spaces.MultiBinary):
        return _ArrayCodec(space, np.zeros((), np.int8), np.ones((), np.int8))
    if isinstance(space, spaces.Dict):
        bad = [key for key in space.spaces if not isinstance(key, str)]
        if bad:
            raise ConfigurationError(f"Expect a Dict space with str keys, actually: keys {bad}")
        keys = tuple(space.spaces)
        children = [codec_for(s, digest_min_bytes=digest_min_bytes) for s in space.spaces.values()]
        return _StructCodec(space, keys, children, tuple_=False)
    if isinstance(space, spaces.Tuple):
        children = [codec_for(s, digest_min_bytes=digest_min_bytes) for s in space.spaces]
        return _StructCodec(space, tuple(range(len(children))), children, tuple_=True)
    if isinstance(space, spaces.Text):
        return _TextCodec(space)
    if not isinstance(space, Space):
        raise ConfigurationError(
            f"Expect a gymnasium.spaces.Space, actually: {type(space).__name__}"
        )
    return _JsonCodec(space)


def _has_unknown(space: Space[Any]) -> bool:
    if isinstance(space, UnknownSpace):
        return True
    if isinstance(space, spaces.Dict):
        return any(_has_unknown(s) for s in space.spaces.values())
    if isinstance(space, spaces.Tuple):
        return any(_has_unknown(s) for s in space.spaces)
    return False


def codec_in(
    recorded: SpaceCodec, space: Space[Any], *, digest_min_bytes: int | None = None
) -> SpaceCodec:
    """The codec to use for values of ``space`` (an env's own) against a column ``recorded`` reads.

    Where the file's space holds an :class:`UnknownSpace` (a space class episode-audit does not
    know), the env's space converts its values to and from JSON as the recorder did: its codec
    is returned when it stores the same Arrow type. Otherwise ``recorded``.
    """
    if not _has_unknown(recorded.space):
        return recorded
    try:
        codec = codec_for(space, digest_min_bytes=digest_min_bytes)
    except ConfigurationError:
        return recorded
    return codec if codec.arrow_type.equals(recorded.arrow_type) else recorded
