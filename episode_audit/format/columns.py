"""Arrow columns shared by the recorder and replay (so both encode a step identically).

>>> terms_column(3, {0: {"a": 1.0}, 2: {"a": 0.5, "b": -1}}).to_pylist()
[[('a', 1.0)], None, [('a', 0.5), ('b', -1.0)]]
"""

from __future__ import annotations

import contextvars
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

__all__ = [
    "PLAIN_NUMBERS",
    "TERMS_TYPE",
    "counted",
    "map_column",
    "null_mask",
    "one_array",
    "prepare_pyarrow",
    "terms_column",
    "terms_matrix_column",
    "error_message",
    "error_text",
    "number",
    "number_or_nan",
    "text",
    "text_array",
]


def prepare_pyarrow() -> None:
    """Make pyarrow's first conversion now, before an env steps, in a context of its own.

    pyarrow imports pandas (when installed) at its first conversion: 0.3-1 s, paid here rather
    than amid the env's steps. The import sets ``decimal``'s context variable, and once the
    running context holds a variable, numpy reads its own context variables more slowly at
    each array made and each ufunc called: ~1.7 k instructions more a Reacher-v5 step
    (``bench/instructions.py``). Run in a new, empty context, the import leaves the caller's
    context as it was.

    >>> import contextvars
    >>> before = list(contextvars.copy_context())
    >>> prepare_pyarrow()
    >>> list(contextvars.copy_context()) == before
    True
    """
    contextvars.Context().run(pa.array, [0])


TERMS_TYPE = pa.map_(pa.string(), pa.float64())
"""Arrow type of the ``terms`` column: term name -> value, null when a step has no terms."""

PLAIN_NUMBERS = frozenset(
    {float, int, bool, np.float64, np.float32, np.float16, np.int64, np.int32, np.bool_}
)
"""Types whose values numpy turns into float64 as they are (no text parsing, no arrays)."""


def text(value: Any) -> str:
    r"""``value`` as text that UTF-8 (so Arrow and the file) can hold.

    Lone surrogates — e.g. a file name decoded by ``os.fsdecode`` from bytes that are not UTF-8 —
    become backslash escapes; anything else is kept as it is. Recorder and replay both store
    names and labels through this, so the two agree.

    >>> text("door"), text("level-\udcff.json"), text(3)
    ('door', 'level-\\udcff.json', '3')
    """
    s = value if isinstance(value, str) else str(value)
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        return s.encode("utf-8", "backslashreplace").decode("utf-8")
    return s


def number(value: Any) -> float:
    """``float(value)`` for numbers only: text such as ``"1.5"`` raises ``TypeError``.

    How the recorder reads a reward or term (and replay the re-run env's, identically). An
    array of one or more dimensions (numpy's, or any with an ``ndim``: a torch tensor) is not a
    number either, with any numpy (``float()`` of one of a single element gives its value
    before numpy 2.4, with a warning from 1.25 on).

    >>> number(np.float32(0.5)), number(True), number(np.array(2.0))
    (0.5, 1.0, 2.0)
    >>> number(np.array([1.5]))
    Traceback (most recent call last):
    TypeError: an array of shape (1,) is not a number
    """
    if isinstance(value, (str, bytes, bytearray)):
        raise TypeError(f"{type(value).__name__} is not a number")
    dims: Any = getattr(value, "ndim", None)  # (numpy's arrays, a torch tensor too)
    if dims and type(value) not in PLAIN_NUMBERS:
        raise TypeError(f"an array of shape {tuple(value.shape)} is not a number")
    return float(value)


def number_or_nan(value: Any) -> float:
    """:func:`number`, or NaN for a value that is not a number (as the recorder stores it).

    >>> number_or_nan("1.5"), number_or_nan(None), number_or_nan(2)
    (nan, nan, 2.0)
    """
    try:
        return number(value)
    except Exception:
        return math.nan


def error_message(exc: BaseException) -> str:
    r"""``str(exc)`` as :func:`text`, even when that ``str()`` raises.

    >>> error_message(ValueError("bad \udcff"))
    'bad \\udcff'
    """
    try:
        return text(str(exc))
    except Exception as trouble:
        return f"<str() raised {type(trouble).__name__}>"


def error_text(exc: BaseException) -> str:
    """``"Type: message"`` of an exception (see :func:`error_message`).

    >>> error_text(KeyError("x"))
    "KeyError: 'x'"
    """
    return f"{text(type(exc).__qualname__)}: {error_message(exc)}"


def counted(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless ``n`` is 1 (a regular noun: ``episode``, ``step``).

    >>> counted(1, "episode"), counted(0, "step"), counted(3, "game")
    ('1 episode', '0 steps', '3 games')
    """
    return f"{n} {noun}{'' if n == 1 else 's'}"


def text_array(values: Sequence[Any]) -> pa.Array:
    r"""A string column of ``values`` (``None`` stays null); see :func:`text` for the rest.

    >>> text_array(["a", None, 7, "b\udcff"]).to_pylist()
    ['a', None, '7', 'b\\udcff']
    """
    try:
        return pa.array(values, pa.string())
    except (pa.ArrowException, TypeError, ValueError):  # not str, or not UTF-8-encodable
        return pa.array([None if v is None else text(v) for v in values], pa.string())


def terms_column(n: int, rows: Mapping[int, Mapping[str, Any]]) -> pa.Array:
    """The ``terms`` map column of ``n`` steps from ``{row: {name: value}}``.

    Rows absent from ``rows`` are null (no terms on that step); a value that is not a number
    becomes NaN.
    """
    if not rows:
        return pa.nulls(n, TERMS_TYPE)
    counts = np.zeros(n, dtype=np.int32)
    valid = np.zeros(n, dtype=np.bool_)
    if not any(rows.values()):  # (no terms at all, e.g. CartPole's episode totals: empty maps)
        if len(rows) == n:  # (distinct rows: all of them)
            valid[:] = True
        else:
            valid[np.fromiter(rows, dtype=np.int64, count=len(rows))] = True
        return map_column(counts, valid, text_array([]), np.zeros(0))
    keys: list[str] = []
    values: list[Any] = []
    for row, terms in rows.items():
        counts[row] = len(terms)
        valid[row] = True
        keys.extend(terms)
        values.extend(terms.values())
    try:
        numbers = np.asarray(values, dtype=np.float64)
    except Exception:
        numbers = np.array([_as_float(v) for v in values], dtype=np.float64)
    return map_column(counts, valid, text_array(keys), numbers)


def terms_matrix_column(
    n: int, rows: np.ndarray[Any, Any], names: Sequence[str], values: np.ndarray[Any, Any]
) -> pa.Array:
    """The ``terms`` column of ``n`` steps whose ``rows`` all have the same ``names``.

    ``values`` holds one float64 row per entry of ``rows`` (ascending); other steps are null.

    >>> terms_matrix_column(3, np.array([0, 2]), ["a"], np.array([[1.0], [2.0]])).to_pylist()
    [[('a', 1.0)], None, [('a', 2.0)]]
    """
    k = len(names)
    counts = np.zeros(n, dtype=np.int32)
    counts[rows] = k
    valid = np.zeros(n, dtype=np.bool_)
    valid[rows] = True
    keys = pa.array(list(names), pa.string()).take(pa.array(np.tile(np.arange(k), len(rows))))
    return map_column(counts, valid, keys, values.reshape(-1))


def map_column(
    counts: np.ndarray[Any, Any], valid: np.ndarray[Any, Any] | None, keys: pa.Array, values: Any
) -> pa.Array:
    """A ``terms`` map column from entries per row, row validity and the flat keys/values.

    ``valid`` ``None``: every row is valid (the same column as an all-true ``valid``).

    >>> map_column(np.array([1, 0]), None, text_array(["a"]), [0.5]).to_pylist()
    [[('a', 0.5)], []]
    """
    offsets = np.zeros(len(counts) + 1, dtype=np.int32)
    np.cumsum(counts, out=offsets[1:])
    mask = None if valid is None else pa.array(~valid)
    return pa.MapArray.from_arrays(
        pa.array(offsets), keys, pa.array(values, pa.float64()), mask=mask
    )


def one_array(column: pa.Array | pa.ChunkedArray) -> pa.Array:
    """``column`` as one Array, without a copy when it has a single chunk.

    (``ChunkedArray.combine_chunks()`` copies even a single chunk: for a column of camera
    frames that is hundreds of megabytes written for nothing.)

    >>> one_array(pa.chunked_array([[1, 2], [3]])).to_pylist()
    [1, 2, 3]
    >>> chunk = pa.array([1.5])
    >>> one_array(pa.chunked_array([chunk])) is not None and one_array(chunk) is chunk
    True
    """
    if isinstance(column, pa.Array):
        return column
    if column.num_chunks == 1:
        return column.chunk(0)
    return column.combine_chunks()


def null_mask(array: pa.Array) -> np.ndarray[Any, np.dtype[np.bool_]]:
    """Per row, whether it is null (a writable numpy bool array).

    Read from the validity bitmap, several times faster than ``array.is_null().to_numpy()``.

    >>> null_mask(pa.array([1, None, 3])).tolist()
    [False, True, False]
    """
    n = len(array)
    mask: np.ndarray[Any, np.dtype[np.bool_]]
    if pa.types.is_union(array.type):  # no validity bitmap: a row is null when its child's is
        return np.array(array.is_null().to_numpy(zero_copy_only=False), dtype=np.bool_)
    if array.null_count == 0:
        return np.zeros(n, dtype=np.bool_)
    if array.null_count == n:
        return np.ones(n, dtype=np.bool_)
    bitmap = array.buffers()[0]
    start = array.offset
    bits = np.frombuffer(bitmap, dtype=np.uint8, count=(start + n + 7) // 8)
    valid = np.unpackbits(bits, bitorder="little")[start : start + n]
    mask = valid == 0
    return mask


def _as_float(value: Any) -> float:
    try:
        return float(value)
    except Exception:
        return math.nan
