"""The ended episodes' records: one JSON message each, and one Arrow episode block per flush.

:class:`EpisodeRecords` registers the two channels of a file's episode records (after every
stream's) and writes the episodes a flush found ended (``EvidenceFile.pending``). The common
record (no error, no options, a finite return) is written straight from the episode, in C when
the extension is built (:func:`.native.episode_json`), else by :func:`_plain_episode_json`:
the same bytes as the general encoding (:func:`_episode_record` through ``to_json``),
``tests/record/test_episode_records.py`` compares them. See ``docs/format.md``, "Episodes".
"""

from __future__ import annotations

import json
import operator
from itertools import chain
from typing import Any

import numpy as np
import pyarrow as pa

from ..format import names as fmt
from ..format.columns import map_column, terms_column
from ..format.records import EPISODE_SCHEMA, to_json
from ..format.schemas import EPISODE_BLOCK_BASE, EPISODE_BLOCK_SCHEMA, EPISODE_OPTIONS_TYPED
from . import native
from .block import Episode
from .counting import every_row_terms, repeated_text
from .writer import EvidenceWriter

__all__ = ["EpisodeRecords"]


class EpisodeRecords:
    """A file's episode records: their two channels, and how a flush writes them.

    ``games``: whether records carry a ``game`` (PettingZoo files). Whether the common records
    are written in C is decided when it is made (``EPISODE_AUDIT_PURE_PYTHON``).
    """

    def __init__(self, games: bool) -> None:
        self.games = games
        self.schema = EPISODE_BLOCK_SCHEMA if games else EPISODE_BLOCK_BASE
        self.compiled = native.compiled()
        self.json_channel = -1
        self.block_channel = -1
        """The episode block channel (``-1`` until :meth:`register`)."""

    def register(self, writer: EvidenceWriter) -> None:
        """Register the JSON record channel and the episode block channel, in that order."""
        self.json_channel = writer.register_json_channel(
            fmt.TOPIC_EPISODE_END, fmt.SCHEMA_EPISODE_END, EPISODE_SCHEMA
        )
        self.block_channel = writer.register_arrow_channel(
            fmt.TOPIC_EPISODES, fmt.SCHEMA_EPISODE_BLOCK, self.schema, {"agent": ""}
        )

    def write(
        self, writer: EvidenceWriter, ended: list[tuple[Episode, dict[str, Any]]], offset: int
    ) -> None:
        """Write the ``ended`` episodes (with their endings) and their episode block.

        ``offset`` turns the episodes' monotonic times into wall-clock ones.
        """
        games = self.games
        # (an error's record is never the common one: the C path declines it, so only the
        # Python path can meet an error action, and takes them out before the JSON)
        records = native.episode_json(ended, offset, games) if self.compiled else None
        raised: list[pa.Array | None] = []
        if records is not None:
            datas, ends = records
        else:
            raised = [ending.pop("error_action", None) for _, ending in ended]
            ends = [ending.pop("error_ns", ep.end_ns) + offset for ep, ending in ended]
            datas = [
                _episode_json(ep, ending, end, offset, games)
                for (ep, ending), end in zip(ended, ends, strict=True)
            ]
        writer.write_json_many(self.json_channel, datas, ends)
        columns = None if records is None else native.episode_columns(ended, offset, games)
        if columns is None:
            batch = _episode_batch(ended, ends, offset, games, self.schema)
            if any(action is not None for action in raised):
                batch = _with_error_actions(batch, raised)
        else:
            batch = _columns_batch(len(ended), columns, self.schema)
        writer.write_batch(self.block_channel, batch, ends[-1])


_MASKED = {"seed": "seed_mask", "game": "game_mask"}


def _with_error_actions(batch: pa.RecordBatch, raised: list[pa.Array | None]) -> pa.RecordBatch:
    """``batch`` with an ``error_action`` column: per episode, its action that raised, or null.

    ``raised`` holds one-row columns of the stream's action type (a single env's: one type).
    """
    kind = next(action for action in raised if action is not None).type
    column = pa.concat_arrays([pa.nulls(1, kind) if a is None else a for a in raised])
    return batch.append_column(pa.field(fmt.COL_ERROR_ACTION, kind), column)


def _columns_batch(n: int, columns: dict[str, Any], schema: pa.Schema) -> pa.RecordBatch:
    """The episode block of common records from their columns (:func:`.native.episode_columns`).

    The same block as :func:`_episode_batch` makes of them
    (``tests/record/test_episode_records.py`` compares their bytes).
    """
    arrays = []
    for name in schema.names:
        kind = schema.field(name).type
        if name == "term_totals":
            arrays.append(_totals_column(columns[name]))
        elif name in _MASKED:
            arrays.append(pa.array(columns[name], kind, mask=columns[_MASKED[name]]))
        elif name in columns:
            arrays.append(pa.array(columns[name], kind))
        else:  # options and the error's fields: a common record has none
            arrays.append(pa.nulls(n, kind))
    return pa.RecordBatch.from_arrays(arrays, schema=schema)


def _totals_column(totals: list[Any]) -> pa.Array:
    """The ``term_totals`` column of the episodes' totals dicts (:func:`terms_column`'s).

    When every episode with totals has the same names in the same order (an env's terms; an
    episode ended before its first step has none), it is made without a pass per value: the
    names' text repeated (in C), the values in one array.
    """
    n = len(totals)
    names = next((tuple(t) for t in totals if t), None)
    if names is None or not all(type(t) is dict and (not t or tuple(t) == names) for t in totals):
        return terms_column(n, dict(enumerate(totals)))
    counts = np.fromiter(map(len, totals), np.int32, n)
    full = int(np.count_nonzero(counts))
    try:
        values = np.fromiter(
            chain.from_iterable(t.values() for t in totals), np.float64, full * len(names)
        )
    except (TypeError, ValueError):  # (a total that is not a number: the general path)
        return terms_column(n, dict(enumerate(totals)))
    keys = repeated_text(names, full, native.NATIVE)
    if full == n:
        return every_row_terms(n, len(names), keys, values)
    return map_column(counts, None, keys, values)


def _episode_json(
    episode: Episode, ending: dict[str, Any], end_ns: int, offset: int, games: bool
) -> bytes:
    """The JSON record of an ended episode (``ending``: what ``Stream.end_episode`` said).

    Optional fields that are null are left out (the JSON Schema marks them optional); the
    ``rng_state`` is already JSON (made once at reset): spliced in, not encoded again. The
    common record (no error, no options, a finite return) is written straight
    from the episode, the same bytes as :func:`~episode_audit.format.records.to_json` of it.
    """
    data = _plain_episode_json(episode, ending, end_ns, offset, games)
    if data is None:
        record = _episode_record(episode, ending, end_ns, offset, games)
        data = to_json({k: v for k, v in record.items() if v is not None})
    if episode.rng_json is not None:
        data = data[:-1] + b',"rng_state":' + episode.rng_json + b"}"
    return data


def _plain_episode_json(
    episode: Episode, ending: dict[str, Any], end_ns: int, offset: int, games: bool
) -> bytes | None:
    """The JSON record of a common episode, ``None`` for any other (see :func:`_episode_json`)."""
    ret, totals, agent = episode.ret, episode.totals, episode.agent
    if (
        ending["error"] is not None
        or episode.options is not None
        or type(ret) is not float
        or ret - ret != 0.0  # (NaN, an infinity: the general path's text for them)
        or (agent is not None and type(agent) is not str)
    ):
        return None
    seed, label, reason = episode.seed, ending["failure_label"], ending["truncation_reason"]
    game = episode.game if games else None
    agent_json = "" if agent is None else ',"agent":' + _quote(agent)
    seed_json = "" if seed is None else f',"seed":{seed:d}'
    label_json = "" if label is None else ',"failure_label":' + _quote(label)
    reason_json = "" if reason is None else ',"truncation_reason":' + _quote(reason)
    game_json = "" if game is None else f',"game":{game:d}'
    return (
        f'{{"episode":{episode.index:d},"env_index":{episode.env_index:d}{agent_json}'
        f'{seed_json},"outcome":{_quote(ending["outcome"])}{label_json}{reason_json}'
        f',"terminated":{_BOOL_JSON[ending["terminated"]]}'
        f',"truncated":{_BOOL_JSON[ending["truncated"]]}'
        f',"length":{episode.steps:d},"return":{ret!r}'
        f',"term_totals":{to_json(totals).decode() if totals else "{}"}'
        f',"start_time_ns":{episode.start_ns + offset:d},"end_time_ns":{end_ns:d}'
        f',"notes":{episode.notes:d}{game_json}}}'
    ).encode()


_quote = json.encoder.encode_basestring_ascii  # (json.dumps' strings: ASCII, escaped)
_BOOL_JSON = {False: "false", True: "true"}


def _episode_record(
    episode: Episode, ending: dict[str, Any], end_ns: int, offset: int, games: bool
) -> dict[str, Any]:
    """The episode record of an ended episode, as a dict (its JSON: :func:`_episode_json`)."""
    record = {
        "episode": episode.index,
        "env_index": episode.env_index,
        "agent": episode.agent,
        "seed": episode.seed,
        "options": episode.options,
        **ending,
        "length": episode.steps,
        "return": episode.ret,
        "term_totals": episode.totals,
        "start_time_ns": episode.start_ns + offset,
        "end_time_ns": end_ns,
        "notes": episode.notes,
    }
    if games:
        record["game"] = episode.game
    return record


# The episode block's columns read from each episode (and its ending), by column name.
_FROM_EPISODE = {
    "episode": "index",
    "env_index": "env_index",
    "agent": "agent",
    "seed": "seed",
    "rng_state": "rng_json",  # (JSON bytes, taken as UTF-8 text)
    "options": "options_json",
    "options_typed": "options_typed",
    "length": "steps",
    "return": "ret",
    "start_time_ns": "start_ns",
    "notes": "notes",
    "game": "game",
    "term_totals": "totals",
}
_FROM_ENDING = ("outcome", "failure_label", "truncation_reason", "terminated", "truncated", "error")
_episode_fields = operator.attrgetter(*_FROM_EPISODE.values())
_ending_fields = operator.itemgetter(*_FROM_ENDING)


def _episode_batch(
    ended: list[tuple[Episode, dict[str, Any]]],
    ends: list[int],
    offset: int,
    games: bool,
    schema: pa.Schema,
) -> pa.RecordBatch:
    """The episode block of the ``ended`` episodes (``ends``: their end times).

    One pass reads each episode's fields; ``zip`` turns those rows into columns.
    """
    n = len(ended)
    rows = [_episode_fields(ep) + _ending_fields(e) for ep, e in ended]
    columns: dict[str, Any] = dict(
        zip([*_FROM_EPISODE, *_FROM_ENDING], zip(*rows, strict=True), strict=True)
    )
    columns["start_time_ns"] = [t + offset for t in columns["start_time_ns"]]
    columns["end_time_ns"] = ends
    if not games:
        columns["game"] = None
    typed = columns.pop(fmt.COL_OPTIONS_TYPED)
    errors = columns.pop("error")
    errors = [e or {} for e in errors] if any(e is not None for e in errors) else None
    for key in ("type", "message", "during"):
        columns[f"error_{key}"] = None if errors is None else [e.get(key) for e in errors]
    arrays = [
        terms_column(n, dict(enumerate(columns[name])))
        if name == "term_totals"
        else pa.nulls(n, schema.field(name).type)
        if columns[name] is None
        else pa.array(columns[name], schema.field(name).type)
        for name in schema.names
    ]
    batch = pa.RecordBatch.from_arrays(arrays, schema=schema)
    if any(t is not None for t in typed):  # (only then: other blocks have no such column)
        batch = batch.append_column(EPISODE_OPTIONS_TYPED, pa.array(typed, pa.string()))
    return batch
