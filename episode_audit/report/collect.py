"""The episodes of opened evidence files as the two tables a report groups.

:func:`collect` returns one row per episode (or per PettingZoo game) with its group key, and one
row per (ended episode, reward term) with the term's episode total; ``row`` numbers the episodes
(it joins the two tables), ``episode`` is an episode's index in its file (a game's, with games),
``seed`` is an episode's reset seed, ``reward_wrappers`` the reward wrappers its file was
recorded over, with their settings (:func:`~.wrapped.file_setup`; null: none) and ``rng`` a
digest of the RNG state an unseeded reset began from. The key comes from ``by``:
:data:`BY_KEYS` or ``tag:NAME`` (:func:`is_by`, :func:`check_by`); an episode without a value
for it is in the group :data:`NONE_KEY`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.records import unstarted
from ..read import Evidence
from .games import OUTCOME_FIELDS, game_table
from .wrapped import file_setup

__all__ = [
    "BY_KEYS",
    "ENDED",
    "ERROR_KEY",
    "INCOMPLETE_KEY",
    "NONE_KEY",
    "SUCCESS_KEY",
    "check_by",
    "collect",
    "file_key",
    "file_rows",
    "is_by",
    "joined",
]

NONE_KEY = "(none)"
SUCCESS_KEY = "(success)"
INCOMPLETE_KEY = "(incomplete)"
ERROR_KEY = "(error)"

ENDED = (fmt.OUTCOME_SUCCESS, fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED)
"""The outcomes of the episodes rates count (the denominator)."""

BY_KEYS = ("file", "env", "env_index", "agent", "label", "all")
"""The ``by`` groupings besides ``tag:NAME``."""

_EPISODES_SCHEMA = pa.schema(
    [
        ("outcome", pa.string()),
        ("failure_label", pa.string()),
        ("truncation_reason", pa.string()),
        ("terminated", pa.bool_()),
        ("truncated", pa.bool_()),
        ("length", pa.int64()),
        ("return", pa.float64()),
        ("key", pa.string()),
        ("success_signal", pa.bool_()),
        ("seed", pa.int64()),
        ("rng", pa.int64()),
        ("row", pa.int64()),
        ("episode", pa.int64()),
        ("reward_wrappers", pa.string()),
    ]
)
_TERM_SCHEMA = pa.schema(
    [
        ("key", pa.string()),
        ("outcome", pa.string()),
        ("term", pa.string()),
        ("total", pa.float64()),
        ("row", pa.int64()),
    ]
)


def is_by(by: str) -> bool:
    """Whether ``by`` names a grouping.

    >>> is_by("env"), is_by("tag:policy"), is_by("tag:"), is_by("files")
    (True, True, False, False)
    """
    return by in BY_KEYS or (by.startswith("tag:") and len(by) > 4)


def check_by(by: str) -> None:
    """Raise :class:`~episode_audit.errors.ConfigurationError` unless ``by`` names a grouping."""
    if is_by(by):
        return
    raise ConfigurationError(
        f"by: expected 'file', 'env', 'tag:NAME', 'label', 'all', 'env_index' or 'agent', "
        f"actually: {by!r}"
    )


def collect(
    sources: Iterable[tuple[str, Evidence]], by: str, games: bool = False
) -> tuple[pa.Table, pa.Table]:
    """Return (episodes, terms): one row per episode, one row per (episode, term) total.

    Unstarted episodes (reset and never stepped, :func:`~episode_audit.format.records.unstarted`)
    are left out. With ``games``, one row per game of a PettingZoo file instead (see :mod:`.games`).
    """
    return joined([file_rows(name, ev, by, games) for name, ev in sources])


def _reports_success(ev: Evidence, table: pa.Table) -> bool:
    """Whether the file's env reports success: as its run-end record says, else by its episodes.

    A file without the count (torn, or recovered from a torn one) reports success when one of
    its episodes succeeded: a torn CartPole file is read as the finished one is (no success to
    report), not as an env whose successes never came.
    """
    said = ev.reports_success
    if said is not None:
        return said
    return bool(pc.any(pc.equal(table.column(fmt.COL_OUTCOME), fmt.OUTCOME_SUCCESS)).as_py())


FileRows = tuple[pa.Table | None, list[pa.Table]]
"""One file's part of :func:`collect`: its episode rows (``None``: none) and term rows."""


def file_rows(name: str, ev: Evidence, by: str, games: bool = False) -> FileRows:
    """The rows :func:`collect` takes from one file (``name``: its group key by file)."""
    table = ev.episodes()
    unstarted_rows = unstarted(table)
    if unstarted_rows.any():  # reset and never stepped: no episode to count
        table = table.filter(pa.array(~unstarted_rows))
    if games:
        table = game_table(table)
    n = table.num_rows
    if n == 0:
        return None, []
    key = _keys(name, ev, table, by, games)
    signal = pa.array([_reports_success(ev, table)] * n, pa.bool_())
    seed = table.column("seed") if "seed" in table.column_names else pa.nulls(n, pa.int64())
    row = pa.array(np.arange(n, dtype=np.int64))  # within the file: joined() numbers them all
    episodes = (
        table.select(list(OUTCOME_FIELDS))
        .append_column("key", key)
        .append_column("success_signal", signal)
        .append_column("seed", pc.cast(seed, pa.int64()))
        .append_column("rng", _rng_digests(table, n))
        .append_column("row", row)
        .append_column("episode", pc.cast(table.column("episode"), pa.int64()))
        .append_column("reward_wrappers", pa.array([file_setup(ev)] * n, pa.string()))
    )
    return episodes, _term_rows(table, key, row, ev)


def _rng_digests(table: pa.Table, n: int) -> pa.Array:
    """Per episode, a 63-bit digest of the RNG state its unseeded reset began from (else null).

    Two episodes that began from the same state began alike, as two with the same seed did:
    ``compare`` pairs them (a vector env's autoreset episodes carry no seed).
    """
    if "rng_state" not in table.column_names:
        return pa.nulls(n, pa.int64())
    digests = [
        None
        if state is None
        else int.from_bytes(hashlib.blake2b(state.encode(), digest_size=8).digest(), "little") >> 1
        for state in table.column("rng_state").to_pylist()
    ]
    return pa.array(digests, pa.int64())


def _shifted(table: pa.Table, first: int) -> pa.Table:
    """``table`` with its ``row`` numbers (an episode's, within its file) counted from ``first``."""
    i = table.schema.get_field_index("row")
    return table.set_column(i, "row", pc.add(table.column("row"), pa.scalar(first, pa.int64())))


def joined(rows: Iterable[FileRows]) -> tuple[pa.Table, pa.Table]:
    """The files' rows (of :func:`file_rows`) as the two tables of :func:`collect`."""
    parts: list[pa.Table] = []
    term_parts: list[pa.Table] = []
    first = 0  # the row number of the file's first episode
    for episodes, terms in rows:
        if episodes is None:
            continue
        parts.append(_shifted(episodes, first))
        term_parts.extend(_shifted(t, first) for t in terms)
        first += episodes.num_rows
    if not parts:
        return _EPISODES_SCHEMA.empty_table(), _TERM_SCHEMA.empty_table()
    terms_table = pa.concat_tables(term_parts) if term_parts else _TERM_SCHEMA.empty_table()
    return pa.concat_tables(parts), terms_table


def file_key(name: str, ev: Evidence, by: str) -> str | None:
    """The group key every episode of the file ``name`` has for ``by``, if its run says it.

    By file, env, ``tag:NAME`` and all; ``None`` for the groupings each episode has its own
    key for (label, env index, agent).
    """
    if by == "file":
        return name
    if by == "env":
        return ev.run.env_id or NONE_KEY
    if by == "all":
        return "all"
    if by.startswith("tag:"):
        value = (ev.run.tags or {}).get(by[4:])
        return NONE_KEY if value is None else str(value)
    return None


def _keys(name: str, ev: Evidence, table: pa.Table, by: str, games: bool) -> pa.Array:
    """Per episode of ``table`` (of the file ``name``), its group key for ``by``."""
    n = table.num_rows
    key = file_key(name, ev, by)
    if key is not None:
        return pa.array([key] * n, pa.string())
    if by == "label":
        return _label_keys(table)
    if by == "env_index":  # vector files: one group per sub-env index
        return pc.cast(table.column("env_index"), pa.string()).combine_chunks()
    # by agent: PettingZoo files, one group per agent
    if games:
        raise ConfigurationError("by='agent' and games=True: a game has many agents")
    return pc.fill_null(table.column("agent"), NONE_KEY).combine_chunks()


def _label_keys(table: pa.Table) -> pa.Array:
    """Per episode, its key for ``by="label"``."""
    outcome = table.column("outcome")
    failure = pc.fill_null(table.column("failure_label"), fmt.UNLABELED)
    reason = pc.fill_null(table.column("truncation_reason"), fmt.REASON_EXTERNAL)
    truncated = pc.binary_join_element_wise("(truncated:", reason, ")", "")
    keys = pc.case_when(
        pc.make_struct(
            pc.equal(outcome, fmt.OUTCOME_SUCCESS),
            pc.equal(outcome, fmt.OUTCOME_FAILURE),
            pc.equal(outcome, fmt.OUTCOME_TRUNCATED),
            pc.equal(outcome, fmt.OUTCOME_ERROR),
        ),
        SUCCESS_KEY,
        failure,
        truncated,
        ERROR_KEY,
        INCOMPLETE_KEY,
    )
    return keys.combine_chunks() if isinstance(keys, pa.ChunkedArray) else keys


def _term_rows(table: pa.Table, key: pa.Array, row: pa.Array, ev: Evidence) -> list[pa.Table]:
    """Per (episode, term): the term's episode total, for ended episodes only."""
    ended = pc.is_in(table.column("outcome"), pa.array(ENDED)).to_numpy(zero_copy_only=False)
    if not ended.any():
        return []
    mask = pa.array(ended)
    outcome = table.column("outcome").combine_chunks().filter(mask)
    keys = key.filter(mask)
    rows = row.filter(mask)
    out: list[pa.Table] = []
    totals = table.column("term_totals").combine_chunks().filter(mask)
    if len(totals) and totals.null_count < len(totals):
        # Offsets, not pc.list_parent_indices: that kernel aborts the process on map arrays
        # (pyarrow 26).
        offsets = totals.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        parents = pa.array(np.repeat(np.arange(len(totals)), np.diff(offsets)))
        out.append(
            pa.table(
                {
                    "key": keys.take(parents),
                    "outcome": outcome.take(parents),
                    "term": totals.keys.slice(lo, hi - lo),
                    "total": totals.items.slice(lo, hi - lo),
                    "row": rows.take(parents),
                },
                schema=_TERM_SCHEMA,
            )
        )
    return out + _constant_rows(ev, table, mask, keys, outcome, rows)


def _constant_rows(
    ev: Evidence,
    table: pa.Table,
    mask: pa.Array,
    keys: pa.Array,
    outcome: pa.Array,
    rows: pa.Array,
) -> list[pa.Table]:
    """Per (ended episode, declared constant term): the constant times the episode's length."""
    constants = (ev.run.reward_terms or {}).get("constants") or {}
    if not constants:
        return []
    steps = pc.cast(table.column("length").combine_chunks().filter(mask), pa.float64())
    return [
        pa.table(
            {
                "key": keys,
                "outcome": outcome,
                "term": pa.array([str(name)] * len(keys), pa.string()),
                "total": pc.multiply(steps, float(value)),
                "row": rows,
            },
            schema=_TERM_SCHEMA,
        )
        for name, value in constants.items()
        if isinstance(value, (int, float))
    ]
