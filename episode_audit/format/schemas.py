"""The Arrow schemas of an evidence file's columnar blocks, each defined once.

The recorder builds its step, reset and episode blocks from these definitions; the reader checks
every block it decodes against them; ``check`` and replay read the columns by these names.
A column's type is ``None`` where the space decides it (action, observation: see
:mod:`.spaces`). A column not ``nullable`` never holds a null: the reader refuses a block that
has one there (:func:`not_null_columns`).

>>> names = [c.name for c in STEP_COLUMNS]
>>> names[:4], names[-2:]
(['episode', 'step', 'time_ns', 'action'], ['info', 'notes'])
>>> required_columns(TOPIC_RESETS)["seed"]
DataType(int64)
>>> not_null_columns(TOPIC_STEPS)
('episode', 'step', 'time_ns', 'reward', 'terminated', 'truncated')
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import pyarrow as pa

from .columns import TERMS_TYPE
from .names import (
    COL_ACTION,
    COL_AGENT,
    COL_ENV_INDEX,
    COL_EPISODE,
    COL_GAME,
    COL_INFO,
    COL_LABEL,
    COL_NOTES,
    COL_OBSERVATION,
    COL_OPTIONS,
    COL_OPTIONS_TYPED,
    COL_OUTCOME,
    COL_REWARD,
    COL_RNG_STATE,
    COL_SEED,
    COL_STATE,
    COL_STEP,
    COL_TERMINATED,
    COL_TERMS,
    COL_TIME,
    COL_TRUNCATED,
    TOPIC_RESETS,
    TOPIC_STEPS,
)

__all__ = [
    "EPISODE_BLOCK_BASE",
    "EPISODE_BLOCK_COLUMNS",
    "EPISODE_BLOCK_SCHEMA",
    "EPISODE_OPTIONS_TYPED",
    "EPISODE_TABLE_SCHEMA",
    "RESET_COLUMNS",
    "RESET_OPTIONS_TYPED_COLUMN",
    "RESET_STATE_COLUMN",
    "RESET_STREAM_COLUMNS",
    "STEP_COLUMNS",
    "Column",
    "not_null_columns",
    "required_columns",
    "reset_schema",
    "step_schema",
]


@dataclass(frozen=True)
class Column:
    """One column of a block: its name, its Arrow type (``None``: the space's), its nulls."""

    name: str
    type: pa.DataType | None
    nullable: bool = True


STEP_COLUMNS: tuple[Column, ...] = (
    Column(COL_EPISODE, pa.int64(), nullable=False),
    Column(COL_STEP, pa.int64(), nullable=False),
    Column(COL_TIME, pa.int64(), nullable=False),
    Column(COL_ACTION, None),
    Column(COL_OBSERVATION, None),
    Column(COL_REWARD, pa.float64(), nullable=False),
    Column(COL_TERMS, TERMS_TYPE),
    Column(COL_TERMINATED, pa.bool_(), nullable=False),
    Column(COL_TRUNCATED, pa.bool_(), nullable=False),
    Column(COL_OUTCOME, pa.string()),
    Column(COL_LABEL, pa.string()),
    Column(COL_INFO, pa.string()),
    Column(COL_NOTES, pa.string()),
)
"""Columns of a step block (topic ``episode_audit/steps``), in order: one row per step."""

RESET_COLUMNS: tuple[Column, ...] = (
    Column(COL_EPISODE, pa.int64(), nullable=False),
    Column(COL_ENV_INDEX, pa.int64(), nullable=False),
    Column(COL_TIME, pa.int64(), nullable=False),
    Column(COL_SEED, pa.int64()),
    Column(COL_RNG_STATE, pa.string()),
    Column(COL_OPTIONS, pa.string()),
    Column(COL_OBSERVATION, None),
    Column(COL_INFO, pa.string()),
    Column(COL_NOTES, pa.string()),
)
"""Columns of a reset block (topic ``episode_audit/resets``), in order: one row per reset."""

RESET_STREAM_COLUMNS: tuple[Column, ...] = (
    Column(COL_AGENT, pa.string()),
    Column(COL_GAME, pa.int64()),
)
"""Reset columns multi-stream files add (vector, PettingZoo): whose reset, in which game."""

RESET_STATE_COLUMN = Column(COL_STATE, pa.string())
"""The reset column of files that snapshot state (optional: files without it read as before)."""

RESET_OPTIONS_TYPED_COLUMN = Column(COL_OPTIONS_TYPED, pa.string())
"""The reset column of options plain JSON does not hold exactly, tagged (``format/options.py``).

Optional (files without it read as before); the recorder writes it in every reset block,
right after ``options``, null but where a reset's options need it.
"""

_BLOCK_COLUMNS = {TOPIC_STEPS: STEP_COLUMNS, TOPIC_RESETS: RESET_COLUMNS}


def _schema(columns: Sequence[Column], space_fields: dict[str, pa.Field]) -> pa.Schema:
    return pa.schema(
        [
            space_fields[c.name] if c.type is None else pa.field(c.name, c.type, c.nullable)
            for c in columns
        ]
    )


def step_schema(action: pa.Field, observation: pa.Field) -> pa.Schema:
    """The schema of a stream's step blocks, given its action and observation fields.

    >>> step_schema(pa.field("action", pa.int64()), pa.field("observation", pa.int64())).field(
    ...     "reward"
    ... )
    pyarrow.Field<reward: double not null>
    """
    return _schema(STEP_COLUMNS, {COL_ACTION: action, COL_OBSERVATION: observation})


def reset_schema(observation: pa.Field, *, multi_stream: bool, state: bool = False) -> pa.Schema:
    """The schema of a stream's reset blocks.

    ``options_typed`` after ``options``; with ``agent`` and ``game`` if ``multi_stream``, and
    ``state`` last if ``state``.
    """
    at = [c.name for c in RESET_COLUMNS].index(COL_OPTIONS) + 1
    columns = (*RESET_COLUMNS[:at], RESET_OPTIONS_TYPED_COLUMN, *RESET_COLUMNS[at:])
    columns += RESET_STREAM_COLUMNS if multi_stream else ()
    columns += (RESET_STATE_COLUMN,) if state else ()
    return _schema(columns, {COL_OBSERVATION: observation})


def required_columns(topic: str) -> dict[str, pa.DataType | None]:
    """The columns every block of ``topic`` has, with their types (``None``: any type).

    Files of the same major version may add columns; these are the ones readers rely on.
    """
    return {c.name: c.type for c in _BLOCK_COLUMNS[topic]}


def not_null_columns(topic: str) -> tuple[str, ...]:
    """The columns of ``topic``'s blocks that must have no nulls (declared not ``nullable``).

    Those that locate rows (episode, step, env_index, time) and those every row has a value
    in (reward, terminated, truncated); the space columns' nulls are the space's to decide.
    """
    return tuple(c.name for c in _BLOCK_COLUMNS[topic] if not c.nullable)


EPISODE_TABLE_SCHEMA = pa.schema(
    [
        pa.field("episode", pa.int64(), nullable=False),
        pa.field(COL_ENV_INDEX, pa.int64()),
        pa.field(COL_AGENT, pa.string()),
        pa.field(COL_SEED, pa.int64()),
        pa.field(COL_RNG_STATE, pa.string()),
        pa.field(COL_OPTIONS, pa.string()),
        pa.field("outcome", pa.string(), nullable=False),
        pa.field("failure_label", pa.string()),
        pa.field("truncation_reason", pa.string()),
        pa.field("terminated", pa.bool_()),
        pa.field("truncated", pa.bool_()),
        pa.field("length", pa.int64(), nullable=False),
        pa.field("return", pa.float64()),
        pa.field("term_totals", TERMS_TYPE),
        pa.field("start_time_ns", pa.int64()),
        pa.field("end_time_ns", pa.int64()),
        pa.field("error_type", pa.string()),
        pa.field("error_message", pa.string()),
        pa.field("error_during", pa.string()),
        pa.field("notes", pa.int64()),
        pa.field(COL_GAME, pa.int64()),
        pa.field(COL_OPTIONS_TYPED, pa.string()),
        pa.field("ended", pa.bool_(), nullable=False),
    ]
)
"""The episodes table (:meth:`Evidence.episodes`): one row per episode.

``rng_state`` and ``options`` are compact JSON text; ``options_typed`` the options' tagged JSON
when plain JSON does not hold them exactly (``format/options.py``), else null; ``term_totals``
maps term -> total; ``ended`` is False for an episode a torn file cut off before its record.
"""

EPISODE_BLOCK_COLUMNS = pa.schema([f for f in EPISODE_TABLE_SCHEMA if f.name != "ended"])
"""Every column of an episode block a reader takes, in order (a block has some of them)."""
EPISODE_OPTIONS_TYPED = EPISODE_BLOCK_COLUMNS.field(COL_OPTIONS_TYPED)
"""Appended to an episode block that holds an episode whose options need their typed form."""
EPISODE_BLOCK_SCHEMA = pa.schema([f for f in EPISODE_BLOCK_COLUMNS if f.name != COL_OPTIONS_TYPED])
"""An episode block (topic ``episode_audit/episodes``) of a file that records games."""
EPISODE_BLOCK_BASE = pa.schema([f for f in EPISODE_BLOCK_SCHEMA if f.name != COL_GAME])
"""An episode block of any other file: the columns every episode block has."""
