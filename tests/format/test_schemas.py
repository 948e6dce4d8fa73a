"""The block schemas are defined once: what the recorder writes is what the reader requires."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pyarrow as pa

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.format import names as fmt
from episode_audit.format.schemas import (
    EPISODE_TABLE_SCHEMA,
    RESET_COLUMNS,
    RESET_STREAM_COLUMNS,
    STEP_COLUMNS,
    Column,
    not_null_columns,
    required_columns,
    reset_schema,
    step_schema,
)


def _record(path: Path, vector: bool = False) -> None:
    if vector:
        envs = gym.make_vec("CartPole-v1", num_envs=2, vectorization_mode="sync")
        with RecordVectorEvidence(envs, path) as rec:
            rec.reset(seed=1)
            for _ in range(3):
                rec.step(rec.action_space.sample())
        return
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=1)
        env.step(0)


def _reset_names(columns: tuple[Column, ...]) -> list[str]:
    """The names of ``columns``, the optional ``options_typed`` the recorder writes after
    ``options``."""
    names = [c.name for c in columns]
    names.insert(names.index(fmt.COL_OPTIONS) + 1, fmt.COL_OPTIONS_TYPED)
    return names


def test_the_recorder_writes_the_step_and_reset_columns_in_their_order(tmp_path: Path) -> None:
    _record(tmp_path / "one.mcap")
    ev = open_evidence(tmp_path / "one.mcap")
    assert ev.steps_schema.names == [c.name for c in STEP_COLUMNS]
    assert ev.resets().schema.names == _reset_names(RESET_COLUMNS)
    assert ev.episodes().schema.equals(EPISODE_TABLE_SCHEMA)


def test_multi_stream_reset_blocks_add_agent_and_game(tmp_path: Path) -> None:
    _record(tmp_path / "vec.mcap", vector=True)
    names = open_evidence(tmp_path / "vec.mcap").resets().schema.names
    assert names == _reset_names(RESET_COLUMNS + RESET_STREAM_COLUMNS)


def test_the_written_types_are_the_defined_ones(tmp_path: Path) -> None:
    _record(tmp_path / "one.mcap")
    schema = open_evidence(tmp_path / "one.mcap").steps_schema
    expected = step_schema(schema.field(fmt.COL_ACTION), schema.field(fmt.COL_OBSERVATION))
    assert schema.equals(expected)


def test_reset_schema_takes_the_space_field() -> None:
    obs = pa.field(fmt.COL_OBSERVATION, pa.list_(pa.float32(), 4))
    assert reset_schema(obs, multi_stream=False).field(fmt.COL_OBSERVATION).equals(obs)
    assert reset_schema(obs, multi_stream=True).names[-2:] == [fmt.COL_AGENT, fmt.COL_GAME]


def test_required_and_not_null_columns_come_from_the_same_definition() -> None:
    required = required_columns(fmt.TOPIC_STEPS)
    assert list(required) == [c.name for c in STEP_COLUMNS]
    assert required[fmt.COL_ACTION] is None and required[fmt.COL_REWARD] == pa.float64()
    assert not_null_columns(fmt.TOPIC_STEPS) == (
        *(fmt.COL_EPISODE, fmt.COL_STEP, fmt.COL_TIME),
        *(fmt.COL_REWARD, fmt.COL_TERMINATED, fmt.COL_TRUNCATED),
    )
    assert not_null_columns(fmt.TOPIC_RESETS) == (fmt.COL_EPISODE, fmt.COL_ENV_INDEX, fmt.COL_TIME)
    # what the writer declares is what the reader requires
    schema = step_schema(pa.field("action", pa.int64()), pa.field("observation", pa.int64()))
    assert not_null_columns(fmt.TOPIC_STEPS) == tuple(f.name for f in schema if not f.nullable)
