"""The episodes table: from episode blocks or JSON end records, and rows of cut-off episodes.

:func:`_build_episodes` makes :meth:`Evidence.episodes`'s table (:data:`EPISODE_SCHEMA`). A file
with Arrow episode blocks gives it from them (:func:`_episode_blocks`); an older one from its
JSON end records, parsed a group at a time when the fast parse can vouch for them and one by
one (:func:`_episode_record`, with its checks and messages) when not. Episodes without an end
record (cut off by a torn file) get a row from their reset row and their steps' counts.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import CorruptEvidenceError
from ..format import names as fmt
from ..format.schemas import EPISODE_BLOCK_COLUMNS, EPISODE_BLOCK_SCHEMA
from ..format.schemas import EPISODE_TABLE_SCHEMA as EPISODE_SCHEMA
from .blocks import _arrow_batch, _check_episode_block, _episode_part, _nulls_problem, _one_line
from .passes import _decode_kept, _StepStats
from .storage import Source

MAX_JSON_BYTES = 1 << 20
"""Largest JSON episode record or metadata value the reader accepts: 1 MiB."""

EPISODE_COLUMNS: tuple[str, ...] = tuple(EPISODE_SCHEMA.names)
"""Columns of :meth:`Evidence.episodes`; ``ended`` is False for episodes a torn file cut off."""

_RESET_START_COLUMNS = [
    fmt.COL_EPISODE,
    fmt.COL_ENV_INDEX,
    fmt.COL_AGENT,
    fmt.COL_GAME,
    fmt.COL_TIME,
    fmt.COL_SEED,
    fmt.COL_RNG_STATE,
    fmt.COL_OPTIONS,
    fmt.COL_OPTIONS_TYPED,
]

# Configured as json.loads's own decoder; scan_once(text, index) -> (value, end index).
_SCAN_ONCE: Any = json.JSONDecoder().scan_once  # type: ignore[attr-defined]
_COMPACT = json.JSONEncoder(separators=(",", ":"))  # as json.dumps(..., separators=(",", ":"))
_OUTCOMES = frozenset(fmt.OUTCOMES)
_NOT_NULL = tuple(f.name for f in EPISODE_BLOCK_SCHEMA if not f.nullable)
"""The columns of an episode block that must have no nulls (episode, outcome, length)."""
_NO_ERROR: dict[str, Any] = {}
_NO_TERMS: tuple[tuple[str, float], ...] = ()
_GROUP = 128  # end records parsed at a time (few parsed objects alive: less GC work)
_SPLIT_VALUE = "\x00episode-audit:split\x00"
_SPLIT = f",{_COMPACT.encode(_SPLIT_VALUE)},"


class _Irregular(Exception):
    """The fast parse cannot vouch for a record: parse them one by one instead."""


def _number(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, str):
        return float(value)  # "nan", "inf", "-inf"
    return float(value)


def _build_episodes(
    path: Source,
    records: list[pa.RecordBatch | bytes],
    *,
    arrow: bool,
    finished: bool,
    resets: Callable[[], pa.Table],
    step_stats: Callable[[], _StepStats],
) -> pa.Table:
    """The episodes table from the episode records a pass kept (Arrow blocks if ``arrow``).

    ``resets`` gives the resets table; ``step_stats`` counts the steps, asked only when an
    episode has no end record (or the file is torn).
    """
    if arrow:
        table = _episode_blocks(records, path)
        episodes = table.column("episode").to_numpy()
        increasing = bool((episodes[1:] > episodes[:-1]).all())
        if finished and increasing:
            reset = resets().column(fmt.COL_EPISODE).to_numpy()
            if bool(np.isin(reset, episodes).all()):
                return table  # the common case: the blocks are the table
        ended = set(episodes.tolist())
        starts = _starts(resets(), ended)
        columns = {name: table.column(name).to_pylist() for name in EPISODE_COLUMNS}
    else:
        # JSON records: the pass kept them as bytes
        columns = _end_record_columns(records, path)
        ended = set(columns["episode"])
        starts = _starts(resets(), ended)
    stats = _StepStats()
    if not finished or any(index not in ended for index in starts):
        stats = step_stats()
    return _episode_table(path, columns, starts, stats)


def _starts(resets: pa.Table, ended: set[int]) -> dict[int, Any]:
    """Reset rows (the last one of each episode) of the episodes without an end record.

    Every reset episode is a key; the value is None for those with an end record.
    """
    if resets.num_rows == 0:
        return {}
    episodes = resets.column(fmt.COL_EPISODE).to_pylist()
    starts: dict[int, Any] = dict.fromkeys(episodes)
    rows = [i for i, e in enumerate(episodes) if e not in ended]
    if rows:
        present = [c for c in _RESET_START_COLUMNS if c in resets.column_names]
        picked = resets.select(present).take(pa.array(rows, pa.int64()))
        for row in picked.to_pylist():
            starts[int(row["episode"])] = row
    return starts


def _episode_record(data: bytes, path: Source) -> dict[str, Any]:
    if len(data) > MAX_JSON_BYTES:
        raise CorruptEvidenceError(
            path, f"episode record of {len(data)} bytes exceeds the 1 MiB limit"
        )
    try:
        record = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CorruptEvidenceError(path, f"episode record is not valid JSON: {exc}") from None
    except RecursionError:
        raise CorruptEvidenceError(
            path, "episode record is not valid JSON: nested too deeply"
        ) from None
    if not isinstance(record, dict):
        raise CorruptEvidenceError(path, "episode record is not a JSON object")
    for key, kind in (("episode", int), ("outcome", str), ("length", int)):
        if not isinstance(record.get(key), kind) or isinstance(record.get(key), bool):
            raise CorruptEvidenceError(
                path, f"episode record lacks {key!r} of type {kind.__name__}: {str(record)[:120]}"
            )
    if record["outcome"] not in fmt.OUTCOMES:
        raise CorruptEvidenceError(
            path, f"episode record has unknown outcome {record['outcome']!r}"
        )
    return record


def _episode_blocks(blocks: list[pa.RecordBatch | bytes], path: Source) -> pa.Table:
    """The episode Arrow blocks as one table of :data:`EPISODE_SCHEMA` (``ended`` all true).

    ``blocks`` are raw blocks or those :func:`_episode_part` already decoded.
    """
    parts = _decode_kept(blocks, _episode_part, path)
    # (each part has the base columns and the optional ones its block had, in table order)
    kinds = {tuple(part.schema.names) for part in parts}
    if len(kinds) == 1:  # the common case: every block alike
        table = pa.Table.from_batches(parts).combine_chunks()
    else:
        table = pa.Table.from_batches(
            [_filled(part) for part in parts], schema=EPISODE_BLOCK_COLUMNS
        ).combine_chunks()
    for at, field in enumerate(EPISODE_BLOCK_COLUMNS):
        if field.name not in table.column_names:  # a column no block had: null
            table = table.add_column(at, field, pa.nulls(table.num_rows, field.type))
    for name in _NOT_NULL:
        nulls = table.column(name).null_count
        if nulls:
            raise CorruptEvidenceError(path, _nulls_problem("an episode block", nulls, name))
    unknown = pc.filter(
        table.column("outcome"),
        pc.invert(pc.is_in(table.column("outcome"), pa.array(fmt.OUTCOMES, pa.string()))),
    )
    if len(unknown):
        raise CorruptEvidenceError(
            path, f"an episode block has unknown outcome {unknown[0].as_py()!r}"
        )
    ended = pa.array(np.ones(table.num_rows, dtype=np.bool_))
    return table.append_column(EPISODE_SCHEMA.field("ended"), ended)


def _filled(part: pa.RecordBatch) -> pa.RecordBatch:
    """An episode block's part with every block column, null where its block had none."""
    names, n = part.schema.names, part.num_rows
    arrays = [
        part.column(f.name) if f.name in names else pa.nulls(n, f.type)
        for f in EPISODE_BLOCK_COLUMNS
    ]
    return pa.RecordBatch.from_arrays(arrays, schema=EPISODE_BLOCK_COLUMNS)


def _end_record_columns(records: list[bytes], path: Source) -> dict[str, list[Any]]:
    """Parse and check the episode end records; return their columns, in file order.

    Records are parsed :data:`_GROUP` at a time, each group from one string, and turned into
    column values at once (so few parsed objects are alive at a time). Whenever the fast parse
    cannot vouch for giving exactly what ``json.loads`` of each record would (non-ASCII bytes,
    whitespace around a record, anything invalid or unexpected), the group is parsed record by
    record with the checks and error messages of :func:`_episode_record`.
    """
    columns: dict[str, list[Any]] = {name: [] for name in EPISODE_COLUMNS}
    for first in range(0, len(records), _GROUP):
        group = records[first : first + _GROUP]
        try:
            parsed = _parse_joined(group)
        except _Irregular:
            parsed = [_episode_record(data, path) for data in group]
        for name, values in _record_columns(parsed).items():
            columns[name].extend(values)
    return columns


def _parse_joined(records: list[bytes]) -> list[dict[str, Any]]:
    if any(len(data) > MAX_JSON_BYTES for data in records):
        raise _Irregular
    blob = b"\n".join(records)
    if not blob.isascii():
        raise _Irregular
    # ASCII: byte and character offsets agree, and json.loads would decode each record as UTF-8.
    text = blob.decode("ascii")
    scan = _SCAN_ONCE
    parsed: list[dict[str, Any]] = []
    append = parsed.append
    pos = 0
    try:
        for data in records:
            stop = pos + len(data)
            # A record that starts with "{" and parses as one value up to its last byte is
            # what json.loads parses it to: the scanner stops at the object's closing brace.
            if not data.startswith(b"{"):
                raise _Irregular
            record, end = scan(text, pos)
            if end != stop:
                raise _Irregular
            append(record)
            pos = stop + 1
    except (StopIteration, ValueError, RecursionError):
        raise _Irregular from None
    types = {type(r.get("episode")) for r in parsed} | {type(r.get("length")) for r in parsed}
    if parsed and types != {int}:
        raise _Irregular
    if not all(type(r.get("outcome")) is str and r["outcome"] in _OUTCOMES for r in parsed):
        raise _Irregular
    return parsed


def _record_columns(recs: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """The episodes-table values of checked end records (as the rows of ``from_pylist``).

    A record with a value that cannot be converted gets an :class:`_Unconvertible` in its
    ``ended`` column: it is an error only if no later record of its episode replaces it.
    """
    try:
        return _columns_of(recs)
    except (AttributeError, TypeError, ValueError, OverflowError):
        pass
    columns: dict[str, list[Any]] = {name: [] for name in EPISODE_COLUMNS}
    for r in recs:
        try:
            one = _columns_of([r])
        except (AttributeError, TypeError, ValueError, OverflowError) as exc:
            one = _columns_of([{k: r[k] for k in ("episode", "outcome", "length")}])
            one["ended"] = [_Unconvertible(f"{type(exc).__name__}: {exc}")]
        for name, values in one.items():
            columns[name].extend(values)
    return columns


def _columns_of(recs: list[dict[str, Any]]) -> dict[str, list[Any]]:
    errors = [r.get("error") or _NO_ERROR for r in recs]
    return {
        "episode": [r["episode"] for r in recs],
        "env_index": [r.get("env_index", 0) for r in recs],
        "agent": [r.get("agent") for r in recs],
        "seed": [r.get("seed") for r in recs],
        "rng_state": _json_column([r.get("rng_state") for r in recs]),
        "options": _json_column([r.get("options") for r in recs]),
        "outcome": [r["outcome"] for r in recs],
        "failure_label": [r.get("failure_label") for r in recs],
        "truncation_reason": [r.get("truncation_reason") for r in recs],
        "terminated": [bool(r.get("terminated", False)) for r in recs],
        "truncated": [bool(r.get("truncated", False)) for r in recs],
        "length": [r["length"] for r in recs],
        "return": [v if type(v) is float else _number(v) for v in [r.get("return") for r in recs]],
        "term_totals": [
            [(str(k), _number(v)) for k, v in t.items()] if t else _NO_TERMS
            for t in [r.get("term_totals") for r in recs]
        ],
        "start_time_ns": [r.get("start_time_ns") for r in recs],
        "end_time_ns": [r.get("end_time_ns") for r in recs],
        "error_type": [e.get("type") for e in errors],
        "error_message": [e.get("message") for e in errors],
        "error_during": [e.get("during") for e in errors],
        "notes": [r.get("notes", 0) for r in recs],
        "game": [r.get("game") for r in recs],
        "options_typed": [None] * len(recs),  # (blocks only: docs/format.md)
        "ended": [True] * len(recs),
    }


@dataclass(frozen=True)
class _Unconvertible:
    """In place of an end record whose values could not be converted (why)."""

    why: str


def _episode_table(
    path: Source, columns: dict[str, list[Any]], starts: dict[int, Any], stats: _StepStats
) -> pa.Table:
    """Order the end records' columns by episode and add the episodes that have none."""
    episodes = columns["episode"]
    increasing = all(a < b for a, b in pairwise(episodes))
    ended = set(episodes)
    missing = (starts.keys() | stats.lengths.keys()) - ended
    if missing or not increasing:
        position = {e: i for i, e in enumerate(episodes)}  # a later duplicate wins
        order = sorted(ended | missing)
        source = [position.get(e, -1) for e in order]
        for name, values in columns.items():
            values.append(None)  # what -1 picks, overwritten below
            columns[name] = [values[i] for i in source]
        for pos, index in enumerate(order):
            if index in missing:
                for name, value in _incomplete_row(index, starts.get(index), stats).items():
                    columns[name][pos] = value
    for kept in columns["ended"]:
        if isinstance(kept, _Unconvertible):
            raise CorruptEvidenceError(path, f"episode records have wrong types: {kept.why}")
    try:
        return pa.Table.from_arrays(
            [columns[name] for name in EPISODE_COLUMNS], schema=EPISODE_SCHEMA
        )
    except (pa.ArrowException, TypeError, ValueError, OverflowError) as exc:
        raise CorruptEvidenceError(
            path, f"episode records have wrong types: {_one_line(exc)}"
        ) from None


def _incomplete_row(index: int, start: dict[str, Any] | None, stats: _StepStats) -> dict[str, Any]:
    """The row of an episode without an end record: from its reset row and its steps."""
    start = start or {}
    return {
        "episode": index,
        "env_index": start.get("env_index", 0),
        "agent": start.get("agent"),
        "seed": start.get("seed"),
        "rng_state": start.get("rng_state"),
        "options": start.get("options"),
        "outcome": fmt.OUTCOME_INCOMPLETE,
        "failure_label": None,
        "truncation_reason": None,
        "terminated": False,
        "truncated": False,
        "length": stats.lengths.get(index, 0),
        "return": stats.returns.get(index, 0.0),
        "term_totals": None,
        "start_time_ns": start.get(fmt.COL_TIME),
        "end_time_ns": stats.last_time.get(index, start.get(fmt.COL_TIME)),
        "error_type": None,
        "error_message": None,
        "error_during": None,
        "notes": None,
        "game": start.get("game"),
        "options_typed": start.get(fmt.COL_OPTIONS_TYPED),
        "ended": False,
    }


def _json_column(values: list[Any]) -> list[str | None]:
    """``_json_or_none`` of each value, all encoded in one call.

    The values are encoded as one JSON array with a sentinel string between them, and the text
    split at ``,<sentinel>,``. Inside an encoded value a quote after a comma always opens a
    string, so the separator occurs there only where a list holds the sentinel string itself
    (not first, not last); then the count is off and each value is encoded alone.
    """
    present = [v for v in values if v is not None]
    if not present:
        return [None] * len(values)
    encode = _COMPACT.encode
    texts: list[str | None] = []
    if len(present) > 1:
        spaced: list[Any] = [_SPLIT_VALUE] * (2 * len(present) - 1)
        spaced[::2] = present
        texts = list(encode(spaced)[1:-1].split(_SPLIT))
    if len(texts) != len(present):
        texts = [encode(v) for v in present]
    if len(present) == len(values):
        return texts
    it = iter(texts)
    return [None if v is None else next(it) for v in values]


def _error_actions(blocks: list[bytes], path: Source, action: pa.DataType) -> pa.Table:
    """The ``error_action`` column's values of the episode blocks, by episode.

    Only rows of episodes ended ``error`` during ``step`` count; ``action`` is the type of the
    steps' action column, which the column must have. See :meth:`Evidence.error_actions`.
    """
    episodes: list[pa.Array] = []
    actions: list[pa.Array] = []
    for data in blocks:
        batch = _arrow_batch(data, path, fmt.TOPIC_EPISODES)
        _check_episode_block(batch.schema, path)
        if fmt.COL_ERROR_ACTION not in batch.schema.names:
            continue
        column = batch.column(fmt.COL_ERROR_ACTION)
        if not column.type.equals(action):
            raise CorruptEvidenceError(
                path,
                f"an episode block's {fmt.COL_ERROR_ACTION!r} is {column.type}, expected "
                f"{action} (the steps' action type)",
            )
        raised = pc.and_(
            pc.equal(batch.column(fmt.COL_OUTCOME), fmt.OUTCOME_ERROR),
            pc.equal(batch.column("error_during"), "step"),
        )
        episodes.append(pc.filter(batch.column(fmt.COL_EPISODE), raised))
        actions.append(pc.filter(column, raised))
    return pa.table(
        {
            fmt.COL_EPISODE: pa.concat_arrays(episodes) if episodes else pa.array([], pa.int64()),
            fmt.COL_ACTION: pa.concat_arrays(actions) if actions else pa.nulls(0, action),
        }
    )
