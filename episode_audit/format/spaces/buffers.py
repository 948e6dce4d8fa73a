"""Column buffers: one value per step in, one Arrow array out (the recorder's hot path).

:class:`ColumnBuffer` is the interface; each codec's :meth:`~.codecs.SpaceCodec.new_buffer`
returns the buffer of its storage (arrays, integers, text, JSON, digests, structs).
"""

from __future__ import annotations

import abc
import functools
import hashlib
import json
import math
import operator
import warnings
from collections.abc import Hashable, Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import pyarrow as pa
from gymnasium.spaces import Space

__all__ = ["ColumnBuffer"]

_DIGEST_SIZE: Final = 16
_INT64_MIN: Final = -(2**63)
_INT64_MAX: Final = 2**63 - 1
# A real value too large for a float column is stored as inf, and the cast's note says the
# dtype was cast (``check`` reports it); numpy's "overflow encountered in cast" would add a line
# to the training loop's (or replay's) output. Only warnings of this module are silenced; with
# warnings raised as errors, the cast is redone under ``np.errstate``.
warnings.filterwarnings(
    "ignore",
    message="overflow encountered in cast",
    category=RuntimeWarning,
    module=r"episode_audit\.format\.spaces\.buffers\Z",
)

_BLOCK_BYTES: Final = 1 << 20
"""Bytes a fresh array buffer preallocates (at most 1024 rows, at least one)."""
_LARGE_ROW_BYTES: Final = 4096
_LARGE_BLOCK_BYTES: Final = 32 << 20
"""… but for rows of at least ``_LARGE_ROW_BYTES``: as many rows as this many bytes hold (the
recorder's blocks of large rows are that size, ``record.file.CHUNK_TARGET_BYTES``)."""

_BoolArray = npt.NDArray[np.bool_]


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

    def recycle(self) -> None:
        """Nothing refers any more to the arrays :meth:`finish` gave: their memory may be reused.

        A recorder says so once it has written them; a buffer that keeps its memory takes it
        back at a later :meth:`finish` (:class:`_BlockBuffer`). Without the call nothing is
        reused.
        """
        return  # (the buffers that keep no memory of their own: nothing to take back)

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


class _BlockBuffer(ColumnBuffer):
    """Rows in a preallocated numpy block (``_data``) that doubles when full, with null rows.

    The block last handed over to Arrow is kept (``_spare``): once the caller said nothing
    refers to it any more (:meth:`recycle`), the next hand-over takes it back to write into,
    instead of a new block, whose memory would be new to the process (a page fault for each
    4 KiB of it on first write: for camera frames, more than copying them in).
    """

    __slots__ = ("_data", "_n", "_nulls", "_spare", "_spare_free")

    _data: npt.NDArray[Any]
    _n: int
    _nulls: list[int]
    _spare: npt.NDArray[Any]  # (both unset until the first hand-over or recycle)
    _spare_free: bool | None

    def recycle(self) -> None:
        """See :meth:`ColumnBuffer.recycle`."""
        self._spare_free = True

    def _set_block(self, block: npt.NDArray[Any]) -> None:
        self._data = block

    def _reserve(self, rows: int) -> None:
        data = self._data
        if rows <= len(data):
            return
        block = np.empty((max(rows, 2 * len(data)), *data.shape[1:]), dtype=data.dtype)
        block[: self._n] = data[: self._n]
        self._set_block(block)

    def _accepts(self, values: Any) -> bool:
        """Whether a batch of rows can be copied in as it is (see :meth:`extend`)."""
        return False

    def append_null(self) -> None:
        """Add a null row (stored as zeros under a cleared validity bit)."""
        n = self._n
        self._reserve(n + 1)
        self._data[n] = 0
        self._nulls.append(n)
        self._n = n + 1

    def extend(self, values: Any) -> bool:
        """Add rows that need no coercion at once (see :meth:`ColumnBuffer.extend`)."""
        if not self._accepts(values):
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

    def _taken(
        self, arrow_copies: bool = False
    ) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_] | None]:
        """The rows and their null mask, the buffer emptied for reuse.

        A block at least half full is handed over to Arrow (another takes its place); the rows
        of a mostly empty one are copied, so it is not pinned, unless the caller recycles (then
        it is handed over too: it is written and dropped at once). With ``arrow_copies`` (Arrow
        makes its own copy, e.g. bools packed into bits) the rows are a view of the block.
        """
        n = self._n
        block = self._data
        data = block[:n]
        # None (or unset): the caller never recycled; True: the spare is free; False: in use
        recycling = getattr(self, "_spare_free", None)
        if arrow_copies:
            pass
        elif 2 * n >= len(block) or recycling is not None:
            spare = getattr(self, "_spare", None) if recycling else None
            self._spare, self._spare_free = block, None if recycling is None else False
            if spare is None or spare.shape != block.shape:
                spare = np.empty_like(block)
            self._set_block(spare)
        else:
            data = data.copy()
        mask = _null_mask_array(n, self._nulls)
        self._n = 0
        self._nulls = []
        return data, mask


class _ArrayBuffer(_BlockBuffer):
    """Fixed-shape numeric values in a preallocated numpy block that doubles when full."""

    __slots__ = ("_dtype", "_notes", "_scalar", "_shape", "_size", "_value_type")

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

    def _accepts(self, values: Any) -> bool:
        return (
            type(values) is np.ndarray
            and values.shape[1:] == self._shape
            and values.dtype == self._dtype
        )

    def finish(self) -> pa.Array:
        """Return the rows as a ``FixedSizeListArray`` and empty the buffer."""
        # Arrow packs bools into bits (a copy): the block stays ours, nothing to hand over
        data, mask = self._taken(arrow_copies=self._dtype.kind == "b")
        values = pa.array(data.reshape(-1), type=self._value_type)
        return pa.FixedSizeListArray.from_arrays(
            values, list_size=self._size, mask=None if mask is None else pa.array(mask)
        )


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


class _IntBuffer(_BlockBuffer):
    """Scalar integers in a preallocated int64 block that doubles when full."""

    __slots__ = ("_mv",)

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

    def _accepts(self, values: Any) -> bool:
        return type(values) is np.ndarray and values.ndim == 1 and values.dtype.kind == "i"

    def finish(self) -> pa.Array:
        """Return the rows as an ``int64`` array and empty the buffer."""
        data, mask = self._taken()
        return pa.array(data, type=pa.int64(), mask=mask)


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
