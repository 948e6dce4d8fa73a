"""A block's rows counted into their episodes, and the columns that come of it.

- :func:`count_block` — add a block's step rows to their episodes (lengths, returns, end
  times, term totals: running sums) and make its episode, step and ``terms`` columns.
- :class:`Compiled` — the same in C (``csrc/blocks.c``, ``native.counting()``), for the
  blocks it takes as they are.
- :func:`every_row_terms`, :func:`repeated_text` — the ``terms`` column of rows that all hold
  the same names (also the episode block's ``term_totals``), without a pass per row.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from ..format.columns import TERMS_TYPE, map_column, text_array
from .block import Block, Episode, TextColumns
from .notes import add_notes, note
from .rules import named_terms, plain_names

__all__ = ["Compiled", "count_block", "every_row_terms", "repeated_text", "uniform_names"]

_Int64s = np.ndarray[Any, np.dtype[np.int64]]


class Compiled(TextColumns, Protocol):
    """The compiled counting (``csrc/blocks.c``; ``native.counting()``): the same results."""

    def count_rows(
        self, block: Block, n: int, /
    ) -> tuple[_Int64s, _Int64s, tuple[str, ...] | bool | None] | None:
        """:func:`count_block`'s index columns and counts (``None``: not taken)."""

    def repeated_text(self, names: tuple[str, ...], times: int, /) -> tuple[bytes, bytes] | None:
        """:func:`repeated_text`'s value offsets and data (``None``: not taken)."""


def count_block(
    block: Block, n: int, compiled: Compiled | None = None
) -> tuple[_Int64s, _Int64s, pa.Array]:
    """Add a block's ``n`` step rows to their episodes (length, return, end time, term totals).

    Returns the block's episode and step index columns and its ``terms`` column. Rows stepped
    after an episode ended are not counted. Returns and term totals are running sums: each
    value is added to the episode's total so far, one at a time in row order, so they do not
    depend on where flushes cut the episode. ``compiled``, when given, counts the rows (and
    the terms of a block whose rows all hold the same plain names) in C, the same sums; it
    declines any block it does not take as it is.
    """
    done = None if compiled is None else compiled.count_rows(block, n)
    if done is None:
        episode_col, step_col = _index_columns(block.segments, n)
        _count_rows(block, n)
        names: tuple[str, ...] | bool | None = False
    else:
        episode_col, step_col, names = done
    return episode_col, step_col, _terms_column(block, n, episode_col, names, compiled)


def _spans(
    segments: Sequence[tuple[int, int, int, bool]], n: int
) -> Iterator[tuple[int, int, int, bool]]:
    """The segments that hold rows of a block of ``n``: ``(start, end, episode index, live)``."""
    ends = [*(s[0] for s in segments[1:]), n][: len(segments)]
    for (start, index, _, live), end in zip(segments, ends, strict=True):
        if end > start:
            yield start, end, index, live


def _count_rows(block: Block, n: int) -> None:
    """Add the block's rows to their episodes' steps, returns and end times (or after_end)."""
    episodes, times, rewards = block.episodes, block.times, block.rewards
    for start, end, index, live in _spans(block.segments, n):
        ep = episodes[index]
        if live:
            ret = ep.ret
            for reward in rewards[start:end]:
                ret += reward
            ep.ret = ret
            ep.steps += end - start
            ep.end_ns = times[end - 1]
        else:  # stepped after the end: numbered on, not counted
            ep.after_end += end - start


def _counted(segments: Sequence[tuple[int, int, int, bool]], n: int) -> np.ndarray[Any, Any]:
    """Per row, whether it counts in its episode (rows before any reset, or after an end, not)."""
    counted = np.zeros(n, dtype=np.bool_)
    for start, end, _, live in _spans(segments, n):
        counted[start:end] = live
    return counted


def _index_columns(
    segments: Sequence[tuple[int, int, int, bool]], n: int
) -> tuple[_Int64s, _Int64s]:
    """Episode and step index per row, from the block's segments."""
    if not segments or segments[0][0] != 0:
        segments = [(0, -1, 0, False), *segments]  # rows before any reset: no episode
    starts = np.array([s[0] for s in segments], dtype=np.int64)
    lengths = np.diff(np.append(starts, n))
    episode = np.repeat(np.array([s[1] for s in segments], dtype=np.int64), lengths)
    first = np.repeat(np.array([s[2] for s in segments], dtype=np.int64) - starts, lengths)
    return episode, np.arange(n, dtype=np.int64) + first


def _terms_column(
    block: Block,
    n: int,
    episode_col: _Int64s,
    counted_names: tuple[str, ...] | bool | None,
    compiled: Compiled | None,
) -> pa.Array:
    """The block's ``terms`` column; the counted rows' terms are added to their episodes.

    ``counted_names``: the names of every row's terms when :func:`count_block`'s compiled
    counting added their totals already (``None``: it found no terms); ``False``: add them here.
    """
    if not block.term_rows:
        return pa.nulls(n, TERMS_TYPE)
    rows = np.frombuffer(block.term_rows, dtype=np.int64)
    counts = np.frombuffer(block.term_counts, dtype=np.int64)
    values = np.frombuffer(block.term_vals, dtype=np.float64)
    keys = block.term_keys
    done = counted_names if isinstance(counted_names, tuple) else None
    names = uniform_names(keys, counts) if done is None else list(done)
    if block.raw_names and done is None and not plain_names(set(keys if names is None else names)):
        counts, keys, values = _named_block_terms(block, episode_col)
        names = None
    if names is not None:  # (every row the same names: coded by their place, not by text)
        key_array = repeated_text(names, len(rows), compiled)
        codes: _Int64s | None = None
    else:
        key_array = text_array(keys)  # every name plain (or named): as it is
        coded = key_array.dictionary_encode()
        names = coded.dictionary.to_pylist()
        codes = coded.indices.to_numpy().astype(np.int64)
    if done is None:
        if codes is None:
            codes = np.tile(np.arange(len(names), dtype=np.int64), len(rows))
        per_value = np.repeat(rows, counts)
        counted = _counted(block.segments, n)[per_value]
        _add_totals(block.episodes, names, episode_col[per_value], codes, counted, values)
    if len(rows) == n and codes is None:  # (every row the same names: no nulls, even offsets)
        return every_row_terms(n, len(names), key_array, values)
    row_counts = np.zeros(n, dtype=np.int64)
    row_counts[rows] = counts
    valid = np.zeros(n, dtype=np.bool_)
    valid[rows] = True
    return map_column(row_counts, valid, key_array, values)


def every_row_terms(
    n: int, k: int, key_array: pa.Array, values: np.ndarray[Any, np.dtype[np.float64]]
) -> pa.Array:
    """A terms column of ``n`` rows each with the same ``k`` names (``key_array``: them, repeated).

    The column (and IPC bytes) :func:`~episode_audit.format.columns.terms_column` makes of such
    rows, without its pass per row: no row is null, the offsets are every ``k``.

    >>> every_row_terms(2, 1, repeated_text(["a"], 2), np.array([0.5, 1.5])).to_pylist()
    [[('a', 0.5)], [('a', 1.5)]]
    """
    offsets = pa.array(np.arange(0, (n + 1) * k, k, dtype=np.int32))
    return pa.MapArray.from_arrays(offsets, key_array, pa.array(values))


def _add_totals(
    episodes: dict[int, Episode],
    names: Sequence[Any],
    episode_of: _Int64s,
    code_of: _Int64s,
    counted: np.ndarray[Any, np.dtype[np.bool_]],
    values: np.ndarray[Any, np.dtype[np.float64]],
) -> None:
    """Add each counted value to its episode's total of ``names[code]``, one at a time.

    In row order, onto the total so far (as the compiled counting does): an episode's totals
    take the names in the order they first appear.
    """
    for index, code, value in zip(
        episode_of[counted].tolist(),
        code_of[counted].tolist(),
        values[counted].tolist(),
        strict=True,
    ):
        totals = episodes[index].totals
        name = names[code]
        totals[name] = totals.get(name, 0.0) + value


def uniform_names(keys: list[Any], counts: _Int64s) -> list[Any] | None:
    """The names of every row's terms, in order, when all rows have the same; else ``None``.

    The common case (an env reporting the same terms each step) is told by comparing the list
    with its first row's names repeated, which costs a pointer comparison per term.

    >>> uniform_names(["a", "b", "a", "b"], np.array([2, 2]))
    ['a', 'b']
    >>> uniform_names(["a", "b", "b", "a"], np.array([2, 2])) is None
    True
    """
    if not len(counts) or not (counts == counts[0]).all():
        return None
    names = keys[: int(counts[0])]
    return names if names and keys == names * len(counts) else None


def repeated_text(names: Sequence[Any], times: int, compiled: Compiled | None = None) -> pa.Array:
    """``text_array(list(names) * times)``, from the names' text repeated.

    Each value is not converted again: the same buffers (offsets from 0, no validity bitmap
    when none is null) at a fraction of the cost.

    ``compiled`` (:class:`Compiled`), when given, makes the buffers of plain names in C.

    >>> repeated_text(["ab", "c"], 2).to_pylist()
    ['ab', 'c', 'ab', 'c']
    """
    parts = None if compiled is None or times <= 1 else compiled.repeated_text(tuple(names), times)
    if parts is not None:
        offsets_bytes, data_bytes = parts
        return pa.StringArray.from_buffers(
            len(names) * times, pa.py_buffer(offsets_bytes), pa.py_buffer(data_bytes)
        )
    once = text_array(list(names))
    if once.null_count or times <= 1:
        return text_array(list(names) * times)
    _, offsets_buffer, data_buffer = once.buffers()
    offsets = np.frombuffer(offsets_buffer, dtype=np.int32)[: len(once) + 1]
    size = int(offsets[-1])
    data = bytes(data_buffer)[:size]
    every = (offsets[1:] + (np.arange(times, dtype=np.int64) * size)[:, None]).ravel()
    if every[-1] > np.iinfo(np.int32).max:
        return text_array(list(names) * times)
    tiled = np.zeros(len(every) + 1, dtype=np.int32)
    tiled[1:] = every
    return pa.StringArray.from_buffers(len(every), pa.py_buffer(tiled), pa.py_buffer(data * times))


def _named_block_terms(
    block: Block, episode_col: _Int64s
) -> tuple[_Int64s, list[str], np.ndarray[Any, np.dtype[np.float64]]]:
    """The block's term counts, names and values, each row's named by :func:`named_terms`.

    For a block whose keys are not all plain names (``b"a"``, ``1``, ``"1"``): as the slow
    path names a step's terms, with its ``terms_name_collision`` note.
    """
    keys = block.term_keys
    values = block.term_vals
    counts = array("q")
    names: list[str] = []
    named_values = array("d")
    start = 0
    for row, count in zip(block.term_rows, block.term_counts, strict=True):
        end = start + count
        terms, shared = named_terms(keys[start:end], values[start:end])
        start = end
        if shared is not None:
            episode = block.episodes.get(int(episode_col[row]))
            add_notes(episode, block.notes, row, [note("terms_name_collision", shared)])
        counts.append(len(terms))
        names.extend(terms)
        named_values.extend(terms.values())
    return (
        np.frombuffer(counts, dtype=np.int64),
        names,
        np.frombuffer(named_values, dtype=np.float64),
    )
