"""One Arrow block, decoded and checked."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest
from mcap.exceptions import McapError
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from typer.testing import CliRunner

from episode_audit import (
    CorruptEvidenceError,
    RecordAECEvidence,
    RecordEvidence,
    RecordParallelEvidence,
    RecordVectorEvidence,
    open_evidence,
)
from episode_audit.cli import app
from episode_audit.format import names as fmt
from episode_audit.format.schemas import not_null_columns
from episode_audit.read import blocks
from tests.support.envs import ScriptedEnv
from tests.support.hostile import replace_column, rewrite


def test_a_known_schema_message_still_has_its_batch_checked(recorded: Path) -> None:
    """The block after a good one shares its schema message bytes; its batch is still walked."""
    batch = open_evidence(recorded).steps().to_batches()[0]

    def stream(**options: Any) -> bytes:
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, batch.schema, options=pa.ipc.IpcWriteOptions(**options)) as w:
            w.write_batch(batch)
        return bytes(sink.getvalue())

    good, compressed = stream(), stream(compression="zstd")
    known = blocks._first_message_end(good)
    assert known is not None and good[:known] == compressed[:known]  # the same schema message
    where = Path("x.mcap")
    assert blocks._arrow_batch(good, where, fmt.TOPIC_STEPS).equals(batch)
    assert blocks._GOOD_SCHEMA_MESSAGES[fmt.TOPIC_STEPS] == good[:known]
    with pytest.raises(CorruptEvidenceError, match="uses Arrow IPC body compression"):
        blocks._arrow_batch(compressed, where, fmt.TOPIC_STEPS)
    # a stream cut inside its schema message is not taken for the known one
    with pytest.raises(CorruptEvidenceError, match="not a valid Arrow stream"):
        blocks._arrow_batch(good[: known - 1], where, fmt.TOPIC_STEPS)


def _with_a_null(column: str, row: int) -> Callable[[pa.RecordBatch], pa.RecordBatch]:
    """An edit that makes row ``row`` of ``column`` null (its validity bitmap rewritten)."""

    def edit(batch: pa.RecordBatch) -> pa.RecordBatch:
        values = batch.column(column).to_pylist()
        values[min(row, len(values) - 1)] = None
        return replace_column(batch, column, values)

    return edit


NEVER_NULL = [
    *((fmt.TOPIC_STEPS, name) for name in not_null_columns(fmt.TOPIC_STEPS)),
    *((fmt.TOPIC_RESETS, name) for name in not_null_columns(fmt.TOPIC_RESETS)),
    *((fmt.TOPIC_EPISODES, name) for name in ("episode", "outcome", "length")),
]


def _read(path: Path, topic: str) -> pa.Table:
    """The table of ``topic`` the reader reads from ``path``."""
    ev = open_evidence(path)
    tables = {
        fmt.TOPIC_STEPS: ev.steps,
        fmt.TOPIC_RESETS: ev.resets,
        fmt.TOPIC_EPISODES: ev.episodes,
    }
    return tables[topic]()


@pytest.mark.parametrize(("topic", "column"), NEVER_NULL)
def test_nulls_in_a_never_null_column_are_corruption_naming_topic_and_column(
    recorded: Path, tmp_path: Path, topic: str, column: str
) -> None:
    """Every column the schemas declare not nullable: a null there is refused by the reader."""
    edits = {
        fmt.TOPIC_STEPS: "steps",
        fmt.TOPIC_RESETS: "resets",
        fmt.TOPIC_EPISODES: "episodes",
    }
    path = rewrite(recorded, tmp_path / "nulls.mcap", **{edits[topic]: _with_a_null(column, 1)})
    where = "an episode block" if topic == fmt.TOPIC_EPISODES else f"a block on {topic}"
    match = rf"nulls\.mcap: {where} has \d+ null\(s\) in its '{column}' column, which the format "
    with pytest.raises(CorruptEvidenceError, match=match + "declares never null"):
        _read(path, topic)


@pytest.mark.parametrize("column", ["terminated", "truncated", "reward"])
def test_null_flags_and_rewards_are_one_error_line_in_every_command(
    recorded: Path, tmp_path: Path, column: str
) -> None:
    """Found by the issue's attacks: check exited 0, replay ended in a TypeError traceback,
    export in ArrowInvalid. Each command that reads steps exits 2 with one line naming file
    and column (``report`` reads only the episode records)."""
    path = rewrite(recorded, tmp_path / "flags.mcap", steps=_with_a_null(column, 3))
    runner = CliRunner()
    for argv in (
        ["check", str(path)],
        ["replay", str(path)],
        ["export", str(path), "--out", str(tmp_path / "out"), "--overwrite"],
    ):
        result = runner.invoke(app, argv)
        assert result.exit_code == 2, (argv, result.output, result.exception)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in result.stderr, argv
        assert str(path) in lines[0] and f"in its '{column}' column" in lines[0], argv


def _recordings(directory: Path) -> list[Path]:
    """A file of every recorder, with the values a recorder has to note or cast: a reward that
    is no number, flags that are no bools, an env that raises in step; vector autoresets;
    PettingZoo agents that die before the others."""
    import warnings

    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.butterfly import knights_archers_zombies_v11 as kaz
        from pettingzoo.classic import rps_v2, tictactoe_v3

    def odd_step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        obs = np.zeros(2, np.float32)
        if env.t == 4:
            raise RuntimeError("the env broke")
        reward = {1: "no number", 2: None}.get(env.t, 1.0)
        return obs, reward, np.array([env.t == 3]), "False" if env.t == 2 else False, {}

    single = directory / "single.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=odd_step), single, block_steps=2) as env:
        for seed in range(2):
            env.reset(seed=seed)
            for _ in range(4):
                try:
                    env.step(0)
                except RuntimeError:
                    break
    vector = directory / "vector.mcap"
    envs = gym.make_vec("CartPole-v1", 3, vectorization_mode="sync")
    with RecordVectorEvidence(envs, vector, block_steps=16) as envs:
        envs.reset(seed=0)
        envs.action_space.seed(0)
        for _ in range(40):
            envs.step(envs.action_space.sample())
    parallel = directory / "parallel.mcap"
    with RecordParallelEvidence(rps_v2.parallel_env(max_cycles=5), parallel) as penv:
        for seed in range(2):
            penv.reset(seed=seed)
            while penv.agents:
                penv.step({agent: penv.action_space(agent).sample() for agent in penv.agents})
    zombies = directory / "zombies.mcap"  # seed 1: archer_0 dies 5 steps before the others
    with RecordParallelEvidence(kaz.parallel_env(max_cycles=300, max_zombies=6), zombies) as penv:
        penv.reset(seed=1)
        for agent in penv.agents:
            penv.action_space(agent).seed(1)
        while penv.agents:
            penv.step({agent: penv.action_space(agent).sample() for agent in penv.agents})
    aec = directory / "aec.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), aec, block_steps=4) as aenv:
        for game in range(3):
            aenv.reset(seed=game)
            for agent in aenv.agent_iter():
                obs, _, terminated, truncated, _ = aenv.last()
                mask = obs["action_mask"]
                done = terminated or truncated
                aenv.step(None if done else aenv.action_space(agent).sample(mask))
    return [single, vector, parallel, zombies, aec]


def _messages(path: Path) -> Iterator[tuple[str, bytes]]:
    """Each message's topic and data, by mcap's linear scan up to a torn end (torn.mcap)."""
    topics: dict[int, str] = {}
    with open(path, "rb") as f:
        records = StreamReader(f).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except McapError:  # the torn end
                return
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                yield topics[record.channel_id], record.data


def test_no_recorder_and_no_fixture_writes_nulls_in_a_never_null_column(
    tmp_path: Path, repo: Path
) -> None:
    """The reader's refusal costs no legitimate file: every recorder's files (odd values too)
    and the format-1.0 fixtures, read block by block with pyarrow alone, have none."""
    files = sorted((repo / "fixtures").glob("*.mcap")) + _recordings(tmp_path)
    never_null = {
        fmt.TOPIC_STEPS: not_null_columns(fmt.TOPIC_STEPS),
        fmt.TOPIC_RESETS: not_null_columns(fmt.TOPIC_RESETS),
        fmt.TOPIC_EPISODES: ("episode", "outcome", "length"),
    }
    for path in files:
        seen: set[str] = set()
        for topic, data in _messages(path):
            if topic not in never_null:
                continue
            seen.add(topic)
            batch = pa.ipc.open_stream(data).read_next_batch()
            for name in never_null[topic]:
                assert batch.column(name).null_count == 0, (path.name, topic, name)
        assert {fmt.TOPIC_STEPS, fmt.TOPIC_RESETS} <= seen, path.name
        ev = open_evidence(path)  # and the reader reads each whole
        assert ev.steps().num_rows and ev.resets().num_rows and ev.episodes().num_rows
