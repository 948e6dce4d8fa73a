"""One stream's rows not yet written, and how they become step and reset record batches.

- :class:`Episode` — the running state of one open episode of a stream.
- :class:`Block` — column buffers of a stream's steps and resets since its last write.
- :func:`step_batch`, :func:`reset_batch` — a block as the Arrow batches a flush writes
  (its rows counted first: :func:`~.counting.count_block`).
- :func:`row_bytes` — the estimated bytes of one step row (for sizing blocks).
"""

from __future__ import annotations

from array import array
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from ..format import names as fmt
from ..format.columns import text_array
from ..format.records import to_json, to_jsonable
from ..format.spaces import ColumnBuffer, SpaceCodec
from .notes import add_notes, note, short

__all__ = [
    "Block",
    "Episode",
    "TextColumns",
    "reset_batch",
    "row_bytes",
    "sparse_text",
    "step_batch",
]

_Int64s = np.ndarray[Any, np.dtype[np.int64]]

_OTHER_COLUMNS_BYTES = 64  # episode, step, time, reward, flags, offsets of a step row


class Episode:
    """Running state of one open episode of a stream."""

    __slots__ = (
        "after_end",
        "agent",
        "end_ns",
        "ended",
        "env_index",
        "game",
        "index",
        "notes",
        "options",
        "options_json",
        "options_typed",
        "ret",
        "rng_json",
        "seed",
        "start_ns",
        "steps",
        "totals",
    )

    def __init__(
        self,
        index: int,
        seed: int | None,
        rng_json: bytes | None,
        options: Any,
        start_ns: int,
        env_index: int = 0,
        agent: str | None = None,
        game: int | None = None,
        options_typed: str | None = None,
        options_json: str | None = None,
    ) -> None:
        self.index = index
        self.seed = seed
        self.rng_json = rng_json  # (the RNG state before an unseeded reset, as JSON)
        self.options = options
        if options_json is None and options is not None:  # (not made by the caller)
            options_json = to_json(options).decode()
        self.options_json = options_json
        self.options_typed = options_typed  # (when plain JSON does not hold them exactly)
        self.start_ns = start_ns
        self.end_ns = start_ns
        self.steps = 0
        self.after_end = 0  # rows stepped after it ended, in blocks already written
        self.ret = 0.0
        self.totals: dict[str, float] = {}
        self.notes = 0
        self.ended = False
        self.env_index = env_index
        self.agent = agent
        self.game = game

    def next_step(self) -> int:
        """The step index of its next row in a new block (rows after its end number on)."""
        return self.steps + self.after_end


class Block:
    """Column buffers of one stream's steps (and resets) not yet written.

    Per step only the observation and action buffers and the ``times`` / ``rewards`` C arrays
    grow (plus the flat ``term_*`` arrays when the step has reward terms); the episode and step
    index columns, episode lengths, returns and term totals are derived at flush time from
    ``segments``; flags, outcomes, info and notes are kept sparsely, by row.
    """

    __slots__ = (
        "act",
        "ends",
        "episodes",
        "flags",
        "info",
        "notes",
        "obs",
        "pending",
        "raw_names",
        "reset_info",
        "reset_notes",
        "reset_obs",
        "resets",
        "rewards",
        "segments",
        "term_counts",
        "term_keys",
        "term_rows",
        "term_vals",
        "times",
    )

    def __init__(
        self, obs_codec: SpaceCodec, act_codec: SpaceCodec, episode: Episode | None
    ) -> None:
        self.obs: ColumnBuffer = obs_codec.new_buffer()
        self.act: ColumnBuffer = act_codec.new_buffer()
        self.times = array("q")  # monotonic ns of each step
        self.rewards = array("d")
        # (first row, episode index, step index of that row, counted): a new one at every
        # reset; rows of a segment that is not counted were stepped after their episode ended.
        self.segments: list[tuple[int, int, int, bool]] = []
        self.episodes: dict[int, Episode] = {}
        if episode is not None:
            self.add_segment(0, episode, episode.next_step(), not episode.ended)
        self.flags: dict[int, tuple[bool, bool]] = {}  # rows with terminated or truncated set
        # reward terms, flat: for each row that has terms, its row, count, keys and values
        self.term_rows = array("q")
        self.term_counts = array("q")
        self.term_keys: list[Any] = []
        self.term_vals = array("d")
        # whether add_terms took keys as an extractor gave them (named at flush: count_block)
        self.raw_names = False
        self.ends: dict[int, tuple[str, str | None]] = {}
        self.info: dict[int, dict[str, Any]] = {}
        self.notes: dict[int, list[str]] = {}
        # resets: (episode, monotonic ns, seed, rng_state JSON, options JSON, game, state JSON,
        # typed options JSON)
        self.reset_obs: ColumnBuffer = obs_codec.new_buffer()
        self.resets: list[
            tuple[int, int, int | None, str | None, str | None, int | None, str | None, str | None]
        ] = []
        self.reset_info: dict[int, dict[str, Any]] = {}
        self.reset_notes: dict[int, list[str]] = {}
        # rows a batching recorder has taken but not yet handed over with Stream.extend
        self.pending = 0

    def rows(self) -> int:
        """Rows of the block, counting the ``pending`` ones not yet handed over."""
        return len(self.times) + self.pending

    def add_segment(
        self, row: int, episode: Episode, first_step: int, counted: bool
    ) -> tuple[int, int, int, bool]:
        """From ``row`` on, rows are ``episode``'s, numbered from ``first_step``; the segment."""
        segment = (row, episode.index, first_step, counted)
        self.segments.append(segment)
        self.episodes[episode.index] = episode
        return segment

    def next_step_index(self) -> int:
        """The step index the next row of the last segment's episode gets."""
        row, _, first, _ = self.segments[-1]
        return first + self.rows() - row

    def add_terms(self, row: int, keys: Any, values: list[float]) -> None:
        """Add a row's terms, its keys as they are (named by the one rule at flush)."""
        self.raw_names = True
        self.term_rows.append(row)
        self.term_counts.append(len(values))
        self.term_keys.extend(keys)
        self.term_vals.extend(values)

    def take_buffers(self, written: Block) -> None:
        """Go on in the column buffers of ``written``, a block just written (they are empty).

        Its batches are written (serialized, copied into the chunk) and dropped: nothing refers
        to the arrays its buffers gave any more, so their memory may be written again
        (:meth:`ColumnBuffer.recycle`), and the rows of this block go into memory the process
        has used, not new memory.
        """
        for name in ("obs", "act", "reset_obs"):
            mine, theirs = getattr(self, name), getattr(written, name)
            if type(theirs) is type(mine) and not len(theirs) and not len(mine):
                theirs.recycle()
                setattr(self, name, theirs)

    def roll_back(self) -> int:
        """Drop what a step appended before it was committed; return the committed rows.

        A fast path may append an observation, an action, a reward or term values and then
        bail out: every column is cut back to the committed row count, so they stay aligned.
        """
        rows = len(self.times)
        self.obs.truncate(rows)
        self.act.truncate(rows)
        del self.rewards[rows:]
        del self.term_vals[len(self.term_keys) :]
        return rows

    def add_after_end(self, row: int, episode: Episode) -> None:
        """Row ``row`` is stepped after ``episode`` ended: it numbers on, it is not counted."""
        last = self.segments[-1] if self.segments else None
        if last is None or last[1] != episode.index or last[3]:
            first = (
                self.next_step_index()
                if last is not None and last[1] == episode.index
                else episode.next_step()
            )
            self.add_segment(row, episode, first, False)


def row_bytes(obs_codec: SpaceCodec, act_codec: SpaceCodec) -> int:
    """Estimated bytes of one step row of these codecs (for sizing blocks)."""
    return (
        _type_bytes(obs_codec.field("o").type)
        + _type_bytes(act_codec.field("a").type)
        + _OTHER_COLUMNS_BYTES
    )


def _type_bytes(kind: pa.DataType) -> int:
    """Bytes of one value of ``kind`` (a guess of 64 for variable-size types)."""
    if pa.types.is_fixed_size_list(kind):
        return int(kind.list_size) * _type_bytes(kind.value_type)
    if pa.types.is_struct(kind):
        return sum(_type_bytes(kind.field(i).type) for i in range(kind.num_fields))
    try:
        return max(1, int(kind.bit_width) // 8)
    except ValueError:
        return 64


# ---------------------------------------------------------------------- record batches


class TextColumns(Protocol):
    """A block's text columns made in C (``csrc/blocks.c``): the same arrays as the Python."""

    def sparse_text(
        self, n: int, values: dict[int, str | None], /
    ) -> tuple[bytes, bytes, bytes, int] | None:
        """:func:`sparse_text`'s validity, value offsets, data and null count (or ``None``)."""


def step_batch(
    block: Block,
    counted: tuple[_Int64s, _Int64s, pa.Array],
    schema: pa.Schema,
    wall_offset: int,
    compiled: TextColumns | None = None,
) -> tuple[pa.RecordBatch, int]:
    """The block's step rows as a batch of ``schema`` (``counted``: :func:`count_block`'s).

    Also the wall-clock time of its last row. Notes found now (``info_unserializable``)
    count in the episodes' records, written after this (flush). ``compiled``: the text
    columns made in C (:class:`TextColumns`), or ``None``.
    """
    episode, step, terms = counted
    n = len(block.times)
    times = np.frombuffer(block.times, dtype=np.int64) + wall_offset
    terminated = np.zeros(n, dtype=np.bool_)
    truncated = np.zeros(n, dtype=np.bool_)
    for row, (term, trunc) in block.flags.items():
        terminated[row] = term
        truncated[row] = trunc
    ends = block.ends
    outcome = {row: out for row, (out, _) in ends.items()}
    label = {row: lab for row, (_, lab) in ends.items() if lab is not None}
    episode_at = block.episodes.get
    info = _info_column(n, block.info, block.notes, lambda row: episode_at(int(episode[row])))
    columns = {
        fmt.COL_EPISODE: pa.array(episode),
        fmt.COL_STEP: pa.array(step),
        fmt.COL_TIME: pa.array(times),
        fmt.COL_ACTION: block.act.finish(),
        fmt.COL_OBSERVATION: block.obs.finish(),
        fmt.COL_REWARD: pa.array(np.frombuffer(block.rewards, dtype=np.float64)),
        fmt.COL_TERMS: terms,
        fmt.COL_TERMINATED: pa.array(terminated),
        fmt.COL_TRUNCATED: pa.array(truncated),
        fmt.COL_OUTCOME: sparse_text(n, outcome, compiled),
        fmt.COL_LABEL: sparse_text(n, label, compiled),
        fmt.COL_INFO: info,
        fmt.COL_NOTES: _notes_column(n, block.notes),
    }
    return _batch(columns, schema), int(times[-1])


def reset_batch(
    block: Block,
    schema: pa.Schema,
    wall_offset: int,
    env_index: int,
    agent: str | None,
    multi_stream: bool,
) -> tuple[pa.RecordBatch, int]:
    """The block's reset rows as a batch of ``schema``, and the wall-clock time of the last.

    Reset rows of a multi-stream file also say whose they are (``agent``) and their game.
    """
    n = len(block.resets)
    episode_r, mono_r, seeds, rng, options, games, states, typed = zip(*block.resets, strict=True)
    times = np.fromiter(mono_r, dtype=np.int64, count=n) + wall_offset
    columns = {
        fmt.COL_EPISODE: pa.array(np.fromiter(episode_r, dtype=np.int64, count=n)),
        fmt.COL_ENV_INDEX: pa.array(np.full(n, env_index, dtype=np.int64)),
        fmt.COL_TIME: pa.array(times),
        fmt.COL_SEED: pa.array(seeds, pa.int64()),
        fmt.COL_RNG_STATE: pa.array(rng, pa.string()),
        fmt.COL_OPTIONS: pa.array(options, pa.string()),
        fmt.COL_OPTIONS_TYPED: pa.array(typed, pa.string()),
        fmt.COL_OBSERVATION: block.reset_obs.finish(),
        fmt.COL_INFO: _info_column(
            n,
            block.reset_info,
            block.reset_notes,
            lambda row: block.episodes.get(block.resets[row][0]),
        ),
        fmt.COL_NOTES: _notes_column(n, block.reset_notes),
    }
    if multi_stream:
        columns[fmt.COL_AGENT] = pa.array([agent] * n, pa.string())
        columns[fmt.COL_GAME] = pa.array(games, pa.int64())
    if fmt.COL_STATE in schema.names:
        columns[fmt.COL_STATE] = pa.array(states, pa.string())
    return _batch(columns, schema), int(times[-1])


def _batch(columns: dict[str, pa.Array], schema: pa.Schema) -> pa.RecordBatch:
    """A record batch of ``schema`` from its columns by name."""
    return pa.RecordBatch.from_arrays([columns[name] for name in schema.names], schema=schema)


def sparse_text(n: int, values: dict[int, Any], compiled: TextColumns | None = None) -> pa.Array:
    """``text_array([values.get(row) for row in range(n)])``: a block's outcomes, labels, infos.

    ``compiled`` (:class:`TextColumns`), when given, makes the buffers of rows in order with plain
    texts in C: the same array, without a Python object per row.

    >>> sparse_text(4, {1: "success", 3: None}).to_pylist()
    [None, 'success', None, None]
    """
    if not values:
        return pa.nulls(n, pa.string())
    parts = None if compiled is None else compiled.sparse_text(n, values)
    if parts is None:
        texts: list[Any] = [None] * n
        for row, value in values.items():
            texts[row] = value
        return text_array(texts)
    validity, offsets, data, nulls = parts
    return pa.StringArray.from_buffers(
        n,
        pa.py_buffer(offsets),
        pa.py_buffer(data),
        pa.py_buffer(validity) if nulls else None,
        nulls,
    )


def _info_column(
    rows: int,
    info: dict[int, dict[str, Any]],
    notes: dict[int, list[str]],
    episode_of: Callable[[int], Episode | None],
) -> pa.Array:
    """The ``info`` column of ``rows`` rows: each kept info as JSON (null where none).

    A value JSON cannot hold is written as its ``repr`` and noted ``info_unserializable`` in
    ``notes``, counted in the episode ``episode_of(row)`` (see :func:`~.notes.add_notes`).
    """
    values: dict[int, str] = {}
    for row, data in info.items():
        try:
            values[row] = to_json(data).decode()
        except Exception:  # TypeError, ValueError, RecursionError (a cycle), a raising __str__
            safe: dict[str, Any] = {}
            for key, value in data.items():
                name = key if isinstance(key, str) else short(key)
                try:
                    to_json(value)
                    safe[name] = to_jsonable(value)
                except Exception:
                    safe[name] = f"<unserializable {type(value).__name__}: {short(value)}>"
                    what = f"info[{short(key)}] is a {type(value).__name__}"
                    add_notes(episode_of(row), notes, row, [note("info_unserializable", what)])
            values[row] = to_json(safe).decode()
    return sparse_text(rows, values)


def _notes_column(rows: int, notes: dict[int, list[str]]) -> pa.Array:
    return sparse_text(rows, {row: to_json(items).decode() for row, items in notes.items()})
