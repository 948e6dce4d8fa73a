"""Gymnasium spaces <-> Arrow columns: the one encode/decode pair of episode-audit.

- :func:`codec_for` picks the :class:`SpaceCodec` of a space.
- :class:`SpaceCodec` knows the Arrow type of a space, decodes columns back to native values and
  checks them (``contains``) and compares them (``compare``) a whole column at a time.
- :class:`ColumnBuffer` collects one value per step (the recorder's hot path) and turns them into
  one Arrow array.
- :func:`describe_space` / :func:`space_from_description` write a space as JSON and read it back.

How each space is stored:

=================================  ===========================================================
Box, MultiDiscrete, MultiBinary    ``fixed_size_list<dtype>[prod(shape)]``, shape and dtype in
                                   the field metadata (a scalar shape uses a list of size 1)
Box in digest mode                 ``fixed_size_binary[16]``: BLAKE2b-128 of the value's bytes
Discrete                           ``int64`` (the value itself, ``start`` included)
Dict / Tuple                       ``struct`` (key order kept; Tuple fields are ``"0"``, ``"1"``…)
Text                               ``string``
anything else (Graph, Sequence…)   ``string`` holding the JSON of ``space.to_jsonable``
=================================  ===========================================================

Example:
>>> import numpy as np
>>> from gymnasium import spaces
>>> codec = codec_for(spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32))
>>> codec.arrow_type
FixedSizeListType(fixed_size_list<item: float>[2])
>>> buffer = codec.new_buffer()
>>> buffer.append(np.array([0.5, -0.5], dtype=np.float32)) is None
True
>>> buffer.append(np.array([2.0, 0.0]))
'dtype float64 cast to float32'
>>> array = buffer.finish()
>>> codec.decode(array)
[array([ 0.5, -0.5], dtype=float32), array([2., 0.], dtype=float32)]
>>> codec.contains(array)
array([ True, False])
"""

from __future__ import annotations

import abc
import functools
import hashlib
import json
import math
import operator
from collections.abc import Hashable, Iterable, Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc
from gymnasium import spaces
from gymnasium.spaces import Space

from episode_audit.errors import ConfigurationError
from episode_audit.format.columns import null_mask, one_array

__all__ = [
    "ColumnBuffer",
    "SpaceCodec",
    "codec_for",
    "describe_space",
    "equal_elements",
    "space_from_description",
]

# Keys of the Arrow field metadata every codec writes (values are UTF-8 strings).
_META_KIND: Final = "episode_audit.kind"
_META_SPACE: Final = "episode_audit.space"
_META_SHAPE: Final = "episode_audit.shape"
_META_DTYPE: Final = "episode_audit.dtype"
_META_DIGEST: Final = "episode_audit.digest"

_DIGEST_NAME: Final = "blake2b-128"
_DIGEST_SIZE: Final = 16
_COMPARE_ELEMENTS: Final = 1 << 20
"""Values an array compare takes per pass (its temporaries are a few times this in bytes)."""
_INT64_MIN: Final = -(2**63)
_INT64_MAX: Final = 2**63 - 1
_BLOCK_BYTES: Final = 1 << 20
"""Bytes a fresh array buffer preallocates (at most 1024 rows, at least one)."""
_LARGE_ROW_BYTES: Final = 4096
_LARGE_BLOCK_BYTES: Final = 32 << 20
"""… but for rows of at least ``_LARGE_ROW_BYTES``: as many rows as this many bytes hold (the
recorder's blocks of large rows are that size, ``streams.CHUNK_TARGET_BYTES``)."""
# Up to this many values per row, a column's rows are checked transposed (column by column):
# numpy's inner loops over 4 values per row run ~10x slower than over a block's rows.
_NARROW: Final = 16

_BoolArray = npt.NDArray[np.bool_]
_FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Buffers
# --------------------------------------------------------------------------------------------


class ColumnBuffer(abc.ABC):
    """Rows of one column being collected, one value per call, then turned into an Arrow array.

    Get one from :meth:`SpaceCodec.new_buffer`. :meth:`append` is the recorder's hot path: it
    returns ``None`` normally, a short note when it had to coerce the value (the caller prefixes
    the column name), and raises ``ValueError`` / ``TypeError`` when the value cannot be encoded,
    leaving the buffer unchanged.
    """

    __slots__ = ()

    @abc.abstractmethod
    def append(self, value: Any) -> str | None:
        """Add one value; return a note when it was coerced (e.g. ``"dtype float64 cast to …"``)."""

    @abc.abstractmethod
    def append_null(self) -> None:
        """Add a null row."""

    @abc.abstractmethod
    def __len__(self) -> int:
        """Return the number of rows collected since the last :meth:`finish`."""

    @abc.abstractmethod
    def finish(self) -> pa.Array:
        """Return the collected rows as one Arrow array and empty the buffer for reuse."""

    @abc.abstractmethod
    def truncate(self, length: int) -> None:
        """Drop the rows from ``length`` on (undoes the children of a failed struct append)."""

    def extend(self, values: Any) -> bool:
        """Add many rows at once when they need no coercion; ``False`` (nothing added) if not.

        ``values`` is a numpy array of rows (a batch, e.g. a vector env's observations). Buffers
        that cannot take a batch as it is return ``False``; the caller then appends row by row.
        """
        return False


def _null_mask_array(length: int, nulls: list[int]) -> _BoolArray | None:
    """Return the mask (True = null) of a buffer's rows, or None when no row is null."""
    if not nulls:
        return None
    mask = np.zeros(length, dtype=np.bool_)
    mask[nulls] = True
    return mask


def _initial_rows(row_nbytes: int) -> int:
    if row_nbytes >= _LARGE_ROW_BYTES:
        # (camera frames) a recorder block's worth at once: numpy's empty block takes memory
        # only as rows are written into it, and doubling would copy every row again
        return max(1, _LARGE_BLOCK_BYTES // row_nbytes)
    return max(1, min(1024, _BLOCK_BYTES // max(1, row_nbytes)))


@functools.lru_cache(maxsize=1024)
def _cast_note(source: Hashable, converted: np.dtype[Any], target: np.dtype[Any]) -> str | None:
    """Return the note for a value of ``source`` (a dtype, or a non-numpy type) now ``target``.

    Cached: formatting a dtype costs microseconds, and a misbehaving env repeats the same cast
    every step.
    """
    if isinstance(source, np.dtype):
        return None if source == target else f"dtype {source} cast to {target}"
    name = getattr(source, "__name__", str(source))
    if converted == target:
        return f"{name} converted to {target} array"
    return f"{name} cast to {target}"


def _coerce_array(
    value: Any, shape: tuple[int, ...], dtype: np.dtype[Any]
) -> tuple[npt.NDArray[Any], str | None]:
    """Convert ``value`` to an array of exactly ``shape`` and ``dtype``, or raise.

    Never broadcasts. Integer and bool targets only take values they hold exactly; float targets
    take any real value (a narrower float type may round). The note says what was converted.
    """
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise ValueError(
            f"Expect an array of shape {shape} and dtype {dtype}, actually: "
            f"{type(value).__name__} ({exc})"
        ) from exc
    if arr.shape != shape:
        raise ValueError(
            f"Expect shape {shape}, actually: shape {arr.shape} ({type(value).__name__})"
        )
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"Expect a numeric array of dtype {dtype}, actually: dtype {arr.dtype}")
    source: Any = value.dtype if isinstance(value, (np.ndarray, np.generic)) else type(value)
    note = _cast_note(source, arr.dtype, dtype)
    if arr.dtype == dtype:
        return arr, note
    with np.errstate(all="ignore"):
        cast = arr.astype(dtype)
    if dtype.kind != "f" and not bool((cast == arr).all()):
        raise ValueError(
            f"Expect values that {dtype} holds exactly, actually: {arr.dtype} values "
            f"out of range or not integral"
        )
    return cast, note


class _ArrayBuffer(ColumnBuffer):
    """Fixed-shape numeric values in a preallocated numpy block that doubles when full."""

    __slots__ = (
        "_data",
        "_dtype",
        "_n",
        "_notes",
        "_nulls",
        "_scalar",
        "_shape",
        "_size",
        "_value_type",
    )

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype[Any], value_type: Any) -> None:
        self._shape = shape
        self._dtype = dtype
        self._scalar = dtype.type  # numpy scalars have .shape == () and .dtype too
        self._size = math.prod(shape)
        self._value_type = value_type
        self._n = 0
        self._nulls: list[int] = []
        self._notes: dict[np.dtype[Any], str | None] = {}
        rows = _initial_rows(self._size * dtype.itemsize)
        self._set_block(np.empty((rows, *shape), dtype=dtype))

    def _set_block(self, block: npt.NDArray[Any]) -> None:
        self._data = block

    def append(self, value: Any) -> str | None:
        """Add one value (see :meth:`ColumnBuffer.append`)."""
        n = self._n
        if (
            (type(value) is np.ndarray or type(value) is self._scalar)
            and value.shape == self._shape
            and value.dtype is self._dtype
        ):
            try:
                self._data[n] = value
            except IndexError:  # block full
                return self._append_slow(value)
            self._n = n + 1
            return None
        return self._append_slow(value)

    def _append_slow(self, value: Any) -> str | None:
        n = self._n
        self._reserve(n + 1)
        if (
            type(value) is np.ndarray
            and value.shape == self._shape
            and self._dtype.kind == "f"
            and value.dtype.kind in "biuf"
        ):
            # A float target takes any real value: let numpy cast while copying (the frequent
            # float64 observation in a float32 Box costs no temporary array and no errstate).
            try:
                self._data[n] = value
            except (RuntimeWarning, FloatingPointError):  # overflow, with warnings as errors
                with np.errstate(all="ignore"):
                    self._data[n] = value
            self._n = n + 1
            try:
                return self._notes[value.dtype]
            except KeyError:
                note = self._notes[value.dtype] = _cast_note(value.dtype, value.dtype, self._dtype)
                return note
        arr, note = _coerce_array(value, self._shape, self._dtype)
        self._data[n] = arr
        self._n = n + 1
        return note

    def _reserve(self, rows: int) -> None:
        capacity = len(self._data)
        if rows <= capacity:
            return
        block = np.empty((max(rows, 2 * capacity), *self._shape), dtype=self._dtype)
        block[: self._n] = self._data[: self._n]
        self._set_block(block)

    def append_null(self) -> None:
        """Add a null row (stored as zeros under a cleared validity bit)."""
        n = self._n
        self._reserve(n + 1)
        self._data[n] = 0
        self._nulls.append(n)
        self._n = n + 1

    def extend(self, values: Any) -> bool:
        """Add rows of exactly this buffer's shape and dtype (see :meth:`ColumnBuffer.extend`)."""
        if not (
            type(values) is np.ndarray
            and values.shape[1:] == self._shape
            and values.dtype == self._dtype
        ):
            return False
        n, k = self._n, len(values)
        self._reserve(n + k)
        self._data[n : n + k] = values
        self._n = n + k
        return True

    def __len__(self) -> int:
        return self._n

    def truncate(self, length: int) -> None:
        self._n = length
        self._nulls = [i for i in self._nulls if i < length]

    def finish(self) -> pa.Array:
        """Return the rows as a ``FixedSizeListArray`` and empty the buffer."""
        n = self._n
        flat = self._data[:n].reshape(-1)
        if self._dtype.kind == "b":
            pass  # Arrow packs bools into bits: a copy, so the block stays ours
        elif 2 * n >= len(self._data):
            self._set_block(np.empty_like(self._data))  # hand the block over to Arrow
        else:
            flat = flat.copy()  # do not pin a mostly empty block
        values = pa.array(flat, type=self._value_type)
        mask = _null_mask_array(n, self._nulls)
        result = pa.FixedSizeListArray.from_arrays(
            values, list_size=self._size, mask=None if mask is None else pa.array(mask)
        )
        self._n = 0
        self._nulls = []
        return result


class _FlatArrayBuffer(_ArrayBuffer):
    """An :class:`_ArrayBuffer` for 1-D shapes whose fast path is a memoryview slice assignment.

    Assigning to a memoryview slice copies only when the source has the same item format and
    the same 1-D shape (otherwise ``ValueError``/``TypeError``, nothing written): the same
    check as ``shape == … and dtype is …`` at about half the cost of numpy's ``block[n] = value``.
    """

    __slots__ = ("_mv",)

    def _set_block(self, block: npt.NDArray[Any]) -> None:
        self._data = block
        self._mv = block.reshape(-1).data

    def append(self, value: Any) -> str | None:
        """Add one value (see :meth:`ColumnBuffer.append`)."""
        n = self._n
        size = self._size
        start = n * size
        try:
            self._mv[start : start + size] = value
        except Exception:  # other format or shape, not a buffer, or the block is full
            return self._append_slow(value)
        self._n = n + 1
        return None


class _IntBuffer(ColumnBuffer):
    """Scalar integers in a preallocated int64 block that doubles when full."""

    __slots__ = ("_data", "_mv", "_n", "_nulls")

    def __init__(self) -> None:
        self._n = 0
        self._nulls: list[int] = []
        self._set_block(np.empty(1024, dtype=np.int64))

    def _set_block(self, block: npt.NDArray[np.int64]) -> None:
        self._data = block
        self._mv = block.data

    def append(self, value: Any) -> str | None:
        """Add one integer (see :meth:`ColumnBuffer.append`)."""
        n = self._n
        try:
            self._mv[n] = operator.index(value)
        except Exception:  # not an integer, out of int64 range, or the block is full
            return self._append_slow(value)
        self._n = n + 1
        return None

    def _append_slow(self, value: Any) -> str | None:
        note = None
        try:
            number = operator.index(value)
        except TypeError:
            if isinstance(value, np.ndarray) and value.shape != ():
                raise ValueError(
                    f"Expect a scalar integer, actually: an array of shape {value.shape}"
                ) from None
            if not isinstance(value, (float, np.floating)) and not (
                isinstance(value, np.ndarray) and value.dtype.kind == "f"
            ):
                raise TypeError(f"Expect an integer, actually: {type(value).__name__}") from None
            real = float(value)
            if not real.is_integer():
                raise ValueError(f"Expect an integer, actually: {real!r}") from None
            number = int(real)
            note = f"{type(value).__name__} {real!r} cast to int"
        if not _INT64_MIN <= number <= _INT64_MAX:
            raise ValueError(f"Expect an integer that fits int64, actually: {number}")
        n = self._n
        self._reserve(n + 1)
        self._data[n] = number
        self._n = n + 1
        return note

    def _reserve(self, rows: int) -> None:
        if rows > len(self._data):
            block = np.empty(max(rows, 2 * len(self._data)), dtype=np.int64)
            block[: self._n] = self._data[: self._n]
            self._set_block(block)

    def append_null(self) -> None:
        """Add a null row."""
        n = self._n
        self._reserve(n + 1)
        self._data[n] = 0
        self._nulls.append(n)
        self._n = n + 1

    def extend(self, values: Any) -> bool:
        """Add signed integers (a 1-D numpy array; see :meth:`ColumnBuffer.extend`)."""
        if not (type(values) is np.ndarray and values.ndim == 1 and values.dtype.kind == "i"):
            return False
        n, k = self._n, len(values)
        self._reserve(n + k)
        self._data[n : n + k] = values
        self._n = n + k
        return True

    def __len__(self) -> int:
        return self._n

    def truncate(self, length: int) -> None:
        self._n = length
        self._nulls = [i for i in self._nulls if i < length]

    def finish(self) -> pa.Array:
        """Return the rows as an ``int64`` array and empty the buffer."""
        n = self._n
        data = self._data[:n]
        if 2 * n >= len(self._data):
            self._set_block(np.empty_like(self._data))
        else:
            data = data.copy()
        result = pa.array(data, type=pa.int64(), mask=_null_mask_array(n, self._nulls))
        self._n = 0
        self._nulls = []
        return result


class _ListBuffer(ColumnBuffer):
    """Rows kept as Python objects (str or bytes), for the columns that are not numeric."""

    __slots__ = ("_rows", "_type")

    def __init__(self, arrow_type: Any) -> None:
        self._type = arrow_type
        self._rows: list[Any] = []

    def append_null(self) -> None:
        """Add a null row."""
        self._rows.append(None)

    def __len__(self) -> int:
        return len(self._rows)

    def truncate(self, length: int) -> None:
        del self._rows[length:]

    def finish(self) -> pa.Array:
        """Return the rows as one Arrow array and empty the buffer."""
        result = pa.array(self._rows, type=self._type)
        self._rows = []
        return result


class _TextBuffer(_ListBuffer):
    __slots__ = ()

    def append(self, value: Any) -> str | None:
        """Add one string (see :meth:`ColumnBuffer.append`)."""
        if type(value) is not str:
            if not isinstance(value, str):
                raise TypeError(f"Expect a str, actually: {type(value).__name__}")
            value = str(value)
        if not value.isascii():
            try:
                value.encode("utf-8")
            except UnicodeEncodeError as exc:
                raise ValueError(f"Expect a str that UTF-8 can encode, actually: {exc}") from exc
        self._rows.append(value)
        return None


class _JsonBuffer(_ListBuffer):
    __slots__ = ("_space",)

    def __init__(self, space: Space[Any]) -> None:
        super().__init__(pa.string())
        self._space = space

    def append(self, value: Any) -> str | None:
        """Add one value as ``json.dumps(space.to_jsonable([value])[0])``."""
        try:
            text = json.dumps(self._space.to_jsonable([value])[0])
        except Exception as exc:
            raise ValueError(
                f"Expect a value {type(self._space).__name__}.to_jsonable can convert to JSON, "
                f"actually: {type(value).__name__} ({type(exc).__name__}: {exc})"
            ) from exc
        self._rows.append(text)
        return None


class _DigestBuffer(_ListBuffer):
    __slots__ = ("_dtype", "_shape")

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype[Any]) -> None:
        super().__init__(pa.binary(_DIGEST_SIZE))
        self._shape = shape
        self._dtype = dtype

    def append(self, value: Any) -> str | None:
        """Add the BLAKE2b-128 digest of one value (see :meth:`ColumnBuffer.append`)."""
        note = None
        if not (
            type(value) is np.ndarray and value.shape == self._shape and value.dtype == self._dtype
        ):
            value, note = _coerce_array(value, self._shape, self._dtype)
        data = np.ascontiguousarray(value, dtype=self._dtype)
        self._rows.append(hashlib.blake2b(data.data, digest_size=_DIGEST_SIZE).digest())
        return note


class _StructBuffer(ColumnBuffer):
    """One child buffer per Dict key / Tuple position; an append is all children or none."""

    __slots__ = ("_children", "_fields", "_keys", "_n", "_nulls", "_tuple")

    def __init__(
        self,
        keys: tuple[Any, ...],
        children: list[ColumnBuffer],
        fields: list[Any],
        *,
        tuple_: bool,
    ) -> None:
        self._keys = keys
        self._children = children
        self._fields = fields
        self._tuple = tuple_
        self._n = 0
        self._nulls: list[int] = []

    def append(self, value: Any) -> str | None:
        """Add one dict (Dict space) or tuple (Tuple space), every child or none."""
        if self._tuple:
            if not isinstance(value, (tuple, list)):
                raise TypeError(f"Expect a tuple, actually: {type(value).__name__}")
            if len(value) != len(self._keys):
                raise ValueError(
                    f"Expect a tuple of {len(self._keys)} items, actually: {len(value)} items"
                )
            items = list(value)
        else:
            if not isinstance(value, Mapping):
                raise TypeError(f"Expect a dict, actually: {type(value).__name__}")
            if len(value) != len(self._keys) or any(key not in value for key in self._keys):
                raise ValueError(
                    f"Expect a dict with keys {list(self._keys)}, actually: keys {list(value)}"
                )
            items = [value[key] for key in self._keys]
        notes = []
        n = self._n
        for i, (key, child, item) in enumerate(zip(self._keys, self._children, items, strict=True)):
            try:
                note = child.append(item)
            except BaseException as exc:
                for done in self._children[:i]:
                    done.truncate(n)
                if isinstance(exc, TypeError):
                    raise TypeError(f"{key}: {exc}") from exc
                if isinstance(exc, ValueError):
                    raise ValueError(f"{key}: {exc}") from exc
                raise
            if note is not None:
                notes.append(f"{key}: {note}")
        self._n = n + 1
        return "; ".join(notes) if notes else None

    def append_null(self) -> None:
        """Add a null row (every child gets a null row too)."""
        for child in self._children:
            child.append_null()
        self._nulls.append(self._n)
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def truncate(self, length: int) -> None:
        for child in self._children:
            child.truncate(length)
        self._n = length
        self._nulls = [i for i in self._nulls if i < length]

    def finish(self) -> pa.Array:
        """Return the rows as a ``StructArray`` and empty the buffer."""
        n = self._n
        mask = _null_mask_array(n, self._nulls)
        if self._children:
            arrays = [child.finish() for child in self._children]
            result = pa.StructArray.from_arrays(
                arrays, fields=self._fields, mask=None if mask is None else pa.array(mask)
            )
        else:  # Arrow cannot tell the length of a struct without children from its children
            nulls = set(self._nulls)
            result = pa.array([None if i in nulls else {} for i in range(n)], type=pa.struct([]))
        self._n = 0
        self._nulls = []
        return result


# --------------------------------------------------------------------------------------------
# Codecs
# --------------------------------------------------------------------------------------------


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
        return self.space.from_jsonable([json.loads(text)])[0]

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


# --------------------------------------------------------------------------------------------
# Descriptions
# --------------------------------------------------------------------------------------------


def _json_float(value: float) -> float | str:
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def _describe_bound(values: npt.NDArray[Any], bounded: npt.NDArray[np.bool_], marker: str) -> Any:
    """Return one bound of a Box: a scalar when all elements agree, else a flat C-order list."""
    kind = values.dtype.kind
    flat, flat_bounded = values.reshape(-1), bounded.reshape(-1)
    if flat.size > 1 and (flat_bounded == flat_bounded[0]).all() and (flat == flat[0]).all():
        # the usual case (an image: 0 and 255 everywhere), without a loop over the elements
        return _describe_bound(flat[:1], flat_bounded[:1], marker)
    items: list[Any] = []
    for value, is_bounded in zip(
        values.reshape(-1).tolist(), bounded.reshape(-1).tolist(), strict=True
    ):
        if kind == "f":
            items.append(_json_float(value))
        elif kind == "b":
            items.append(bool(value))
        else:
            items.append(int(value) if is_bounded else marker)
    if items and all(type(x) is type(items[0]) and x == items[0] for x in items):
        return items[0]
    return items


def describe_space(space: Space[Any]) -> dict[str, Any]:
    """Return a JSON-serializable description of ``space`` (:func:`space_from_description` inverts).

    Non-finite floats are written as the strings ``"inf"``, ``"-inf"`` and ``"nan"``; a Box bound
    that is the same for every element is written once. Spaces this module does not know are
    described by class and ``repr`` only, and cannot be rebuilt.

    >>> import numpy as np
    >>> from gymnasium import spaces
    >>> describe_space(spaces.Box(-np.inf, 1.0, shape=(2,), dtype=np.float32))
    {'type': 'Box', 'shape': [2], 'dtype': 'float32', 'low': '-inf', 'high': 1.0}
    >>> describe_space(spaces.Discrete(3, start=-1))
    {'type': 'Discrete', 'n': 3, 'start': -1, 'dtype': 'int64'}
    """
    if isinstance(space, spaces.Box):
        return {
            "type": "Box",
            "shape": list(space.shape),
            "dtype": space.dtype.name,
            "low": _describe_bound(space.low, space.bounded_below, "-inf"),
            "high": _describe_bound(space.high, space.bounded_above, "inf"),
        }
    if isinstance(space, spaces.Discrete):
        return {
            "type": "Discrete",
            "n": int(space.n),
            "start": int(space.start),
            "dtype": space.dtype.name,
        }
    if isinstance(space, spaces.MultiDiscrete):
        return {
            "type": "MultiDiscrete",
            "nvec": space.nvec.tolist(),
            "start": space.start.tolist(),
            "dtype": space.dtype.name,
        }
    if isinstance(space, spaces.MultiBinary):
        return {"type": "MultiBinary", "n": space.n if isinstance(space.n, int) else list(space.n)}
    if isinstance(space, spaces.Text):
        return {
            "type": "Text",
            "min_length": space.min_length,
            "max_length": space.max_length,
            "charset": "".join(space.character_list),
        }
    if isinstance(space, spaces.Dict):
        return {
            "type": "Dict",
            "spaces": [[key, describe_space(s)] for key, s in space.spaces.items()],
        }
    if isinstance(space, spaces.Tuple):
        return {"type": "Tuple", "spaces": [describe_space(s) for s in space.spaces]}
    if isinstance(space, spaces.Sequence):
        return {
            "type": "Sequence",
            "space": describe_space(space.feature_space),
            "stack": bool(space.stack),
        }
    if isinstance(space, spaces.Graph):
        return {
            "type": "Graph",
            "node_space": describe_space(space.node_space),
            "edge_space": None if space.edge_space is None else describe_space(space.edge_space),
        }
    if isinstance(space, spaces.OneOf):
        return {"type": "OneOf", "spaces": [describe_space(s) for s in space.spaces]}
    cls = type(space)
    return {"type": "Custom", "class": f"{cls.__module__}.{cls.__qualname__}", "repr": repr(space)}


def _parse_float(value: Any) -> float:
    if isinstance(value, str) and value in ("inf", "-inf", "nan"):
        return float(value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    raise ConfigurationError(f"Expect a number or 'inf', '-inf', 'nan', actually: {value!r}")


def _parse_bound(
    raw: Any, shape: tuple[int, ...], dtype: np.dtype[Any], marker: str
) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    size = math.prod(shape)
    if not isinstance(raw, list) and size != 1:
        # one value for every element (written so when all agree): parsed once
        one, one_bounded = _parse_bound(raw, (1,), dtype, marker)
        return np.full(shape, one[0], dtype=dtype), np.full(shape, bool(one_bounded[0]))
    items = raw if isinstance(raw, list) else [raw] * size
    if len(items) != size:
        raise ConfigurationError(
            f"Expect a Box bound with {size} values for shape {shape}, actually: {len(items)}"
        )
    bounded = np.array([x != marker for x in items], dtype=np.bool_).reshape(shape)
    if dtype.kind == "f":
        values = np.array([_parse_float(x) for x in items], dtype=dtype)
    elif dtype.kind == "b":
        if not all(isinstance(x, bool) for x in items):
            raise ConfigurationError(f"Expect bool Box bounds, actually: {raw!r}")
        values = np.array(items, dtype=dtype)
    else:
        info = np.iinfo(dtype)
        limit = int(info.min) if marker == "-inf" else int(info.max)
        if not all(x == marker or (isinstance(x, int) and not isinstance(x, bool)) for x in items):
            raise ConfigurationError(f"Expect integer Box bounds, actually: {raw!r}")
        values = np.array([limit if x == marker else x for x in items], dtype=dtype)
    return values.reshape(shape), bounded


def _box_from_description(desc: Mapping[str, Any]) -> spaces.Box[Any]:
    shape = tuple(desc["shape"])
    if not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape):
        raise ConfigurationError(f"Expect a Box shape of ints >= 0, actually: {desc['shape']!r}")
    dtype = np.dtype(desc["dtype"])
    low, bounded_below = _parse_bound(desc["low"], shape, dtype, "-inf")
    high, bounded_above = _parse_bound(desc["high"], shape, dtype, "inf")
    box = spaces.Box(low=low, high=high, shape=shape, dtype=dtype)
    if dtype.kind in "iu":  # integer boxes store unbounded ends as the dtype limits
        box.bounded_below = bounded_below
        box.bounded_above = bounded_above
    return box


def _from_description(desc: Any) -> Space[Any]:
    if not isinstance(desc, Mapping) or not isinstance(desc.get("type"), str):
        raise ConfigurationError(
            f"Expect a space description (a dict with a 'type'), actually: {desc!r:.200}"
        )
    kind = desc["type"]
    if kind == "Box":
        return _box_from_description(desc)
    if kind == "Discrete":
        return spaces.Discrete(int(desc["n"]), start=int(desc["start"]), dtype=desc["dtype"])
    if kind == "MultiDiscrete":
        dtype: np.dtype[Any] = np.dtype(desc["dtype"])
        nvec: npt.NDArray[np.integer[Any]] = np.array(desc["nvec"], dtype=dtype)
        start: npt.NDArray[np.integer[Any]] = np.array(desc["start"], dtype=dtype)
        return spaces.MultiDiscrete(nvec, dtype=dtype, start=start)
    if kind == "MultiBinary":
        n = desc["n"]
        return spaces.MultiBinary(n if isinstance(n, int) else tuple(n))
    if kind == "Text":
        return spaces.Text(
            int(desc["max_length"]),
            min_length=int(desc["min_length"]),
            charset=str(desc["charset"]),
        )
    if kind == "Dict":
        return spaces.Dict([(key, _from_description(s)) for key, s in desc["spaces"]])
    if kind == "Tuple":
        return spaces.Tuple([_from_description(s) for s in desc["spaces"]])
    if kind == "Sequence":
        return spaces.Sequence(_from_description(desc["space"]), stack=bool(desc["stack"]))
    if kind == "Graph":
        edge = desc["edge_space"]
        return spaces.Graph(
            node_space=_from_description(desc["node_space"]),
            edge_space=None if edge is None else _from_description(edge),
        )
    if kind == "OneOf":
        return spaces.OneOf([_from_description(s) for s in desc["spaces"]])
    if kind == "Custom":
        raise ConfigurationError(
            f"Cannot rebuild the custom space {desc.get('repr')!r} (class {desc.get('class')}) "
            "from its description; build it in code"
        )
    raise ConfigurationError(
        "Expect a space type Box, Discrete, MultiDiscrete, MultiBinary, Text, Dict, Tuple, "
        f"Sequence, Graph or OneOf, actually: {kind!r}"
    )


def space_from_description(desc: dict[str, Any]) -> Space[Any]:
    """Rebuild the space :func:`describe_space` described (its RNG state is not kept).

    >>> from gymnasium import spaces
    >>> space = spaces.Dict({"pos": spaces.Box(-1.0, 1.0, shape=(2,)), "id": spaces.Discrete(4)})
    >>> space_from_description(describe_space(space)) == space
    True

    Raises :class:`ConfigurationError` when the description is unknown or invalid.
    """
    try:
        return _from_description(desc)
    except ConfigurationError:
        raise
    except (KeyError, TypeError, ValueError, OverflowError, AssertionError) as exc:
        raise ConfigurationError(
            f"Expect a valid space description, actually: {desc!r:.200} "
            f"({type(exc).__name__}: {exc})"
        ) from exc
