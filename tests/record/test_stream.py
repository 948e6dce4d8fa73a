"""The multi-stream recording core (file.py, stream.py) and how the reader reads such files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from mcap.reader import make_reader

import episode_audit.record.file as evidence_file
from episode_audit import RecorderError, RecordEvidence, check, open_evidence
from episode_audit.format import names as fmt
from episode_audit.format.spaces import codec_for, describe_space
from episode_audit.record.file import EvidenceFile
from episode_audit.record.settings import DEFAULT_BLOCK_STEPS, RecorderSettings, run_info
from episode_audit.record.time_limits import time_limits
from episode_audit.record.values import recordable_options

STREAMS = 3


def _hand_rollouts(seed: int, stream: int, episodes: int) -> list[tuple[int, float]]:
    """(length, return) of each episode of one env stepped by hand, as the recording does."""
    env = gym.make("CartPole-v1", max_episode_steps=40)
    actions = np.random.default_rng(100 + stream)
    out = []
    env.reset(seed=seed + stream)
    for _ in range(episodes):
        length, ret, done = 0, 0.0, False
        while not done:
            _, r, term, trunc, _ = env.step(int(actions.integers(2)))
            length, ret, done = length + 1, ret + float(r), term or trunc
        out.append((length, ret))
        env.reset()
    return out


def _record_streams(path: Path, *, games: bool = False, episodes: int = 6) -> dict[str, Any]:
    """Several CartPole envs stepped in turn, each its own stream, flushed every few steps."""
    envs = [gym.make("CartPole-v1", max_episode_steps=40) for _ in range(STREAMS)]
    settings = RecorderSettings(block_steps=7, command_line=["test"])
    run = run_info(
        settings=settings,
        spec=envs[0].spec,
        observation_space=describe_space(envs[0].observation_space),
        action_space=describe_space(envs[0].action_space),
        layout={"kind": "vector", "num_envs": STREAMS, "agents": []},
    )
    file = EvidenceFile(path, run, settings, games=games)
    obs_codec = codec_for(envs[0].observation_space)
    act_codec = codec_for(envs[0].action_space)
    streams = [
        file.add_stream(obs_codec, act_codec, env_index=i, time_limits=time_limits(e))
        for i, e in enumerate(envs)
    ]
    file.start()
    with pytest.raises(RecorderError, match="streams are added before start"):
        file.add_stream(obs_codec, act_codec, env_index=9)
    actions = [np.random.default_rng(100 + i) for i in range(STREAMS)]
    done = [0] * STREAMS
    game = 0
    for i, (env, stream) in enumerate(zip(envs, streams, strict=True)):
        notes: list[str] = []
        episode = stream.begin(7 + i, None, None, notes, game=game)
        stream.record_reset(episode, *env.reset(seed=7 + i), notes)
    turn = 0
    while min(done) < episodes:
        i = turn % STREAMS
        turn += 1
        if done[i] >= episodes:
            continue
        env, stream = envs[i], streams[i]
        action = int(actions[i].integers(2))
        result = env.step(action)
        stream.step(action, result)
        if result[2] or result[3]:
            done[i] += 1
            game += 1
            if done[i] < episodes:
                notes = []
                from episode_audit.record.seeding import capture_rng_state

                episode = stream.begin(None, None, capture_rng_state(env), notes, game=game)
                stream.record_reset(episode, *env.reset(), notes)
        if turn % 5 == 0:
            file.flush()
    file.close()
    return {"path": path, "episodes": episodes}


@pytest.fixture(scope="module")
def multi(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("multi") / "multi.mcap"
    _record_streams(path)
    return path


def _assert_contiguous(steps: pa.Table) -> None:
    episode = steps["episode"].to_numpy()
    step = steps["step"].to_numpy()
    changes = np.flatnonzero(episode[1:] != episode[:-1]) + 1
    runs = episode[np.concatenate([[0], changes])] if episode.size else episode
    assert len(set(runs.tolist())) == len(runs), "an episode's rows are split"
    for start, stop in zip(
        np.concatenate([[0], changes]), np.append(changes, episode.size), strict=True
    ):
        assert step[start:stop].tolist() == list(range(stop - start))


def test_streams_share_one_file_with_global_episode_indices(multi: Path) -> None:
    ev = open_evidence(multi)
    assert ev.finished and ev.multi_stream
    episodes = ev.episodes()
    assert episodes.num_rows == STREAMS * 6
    assert episodes["episode"].to_pylist() == list(range(STREAMS * 6))
    assert set(episodes["outcome"].to_pylist()) <= {"failure", "truncated"}
    for i in range(STREAMS):
        mine = episodes.filter(pc.equal(episodes["env_index"], i))
        got = list(zip(mine["length"].to_pylist(), mine["return"].to_pylist(), strict=True))
        assert got == _hand_rollouts(7, i, 6)
        assert mine["seed"].to_pylist()[0] == 7 + i
        assert all(s is not None for s in mine["rng_state"].to_pylist()[1:])
    assert episodes["game"].null_count == episodes.num_rows  # no games recorded in this file
    # one step and one reset channel per stream, with env_index in their metadata
    with open(multi, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    for topic in (fmt.TOPIC_STEPS, fmt.TOPIC_RESETS):
        meta = [c.metadata for c in summary.channels.values() if c.topic == topic]
        assert [m["env_index"] for m in meta] == [str(i) for i in range(STREAMS)]
    resets = ev.resets()
    assert {"env_index", "agent", "game"} <= set(resets.column_names)
    by_episode = dict(
        zip(resets["episode"].to_pylist(), resets["env_index"].to_pylist(), strict=True)
    )
    assert by_episode == dict(
        zip(episodes["episode"].to_pylist(), episodes["env_index"].to_pylist(), strict=True)
    )


def test_steps_of_each_episode_come_out_contiguous_and_in_order(multi: Path) -> None:
    ev = open_evidence(multi)
    episodes = ev.episodes()
    steps = ev.steps()
    assert steps.num_rows == sum(episodes["length"].to_pylist())
    _assert_contiguous(steps)
    batches = list(open_evidence(multi).iter_step_batches(columns=["episode", "step"]))
    assert all(b.schema.names == ["episode", "step"] for b in batches)
    _assert_contiguous(pa.Table.from_batches(batches))
    for index in (0, 4, STREAMS * 6 - 1):
        one = ev.episode(index)
        assert one.steps["step"].to_pylist() == list(range(one.record["length"]))
        assert one.reset is not None and one.reset["env_index"] == one.record["env_index"]
    selected = ev.steps(episodes=[1, 5])
    _assert_contiguous(selected)
    assert set(selected["episode"].to_pylist()) == {1, 5}


def test_check_is_clean_on_a_multi_stream_file(multi: Path) -> None:
    result = check([multi])
    # what any CartPole recording gets (no failure labels, no reward terms), nothing else
    assert {f.code for f in result.findings} <= {"unlabeled_failure", "missing_terms"}


def test_torn_multi_stream_file_keeps_episodes_contiguous(multi: Path, tmp_path: Path) -> None:
    full = open_evidence(multi)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(multi.read_bytes()[: full._chunks[len(full._chunks) // 2].offset + 30])
    ev = open_evidence(torn)
    assert not ev.finished and ev.multi_stream
    steps = ev.steps()
    _assert_contiguous(steps)
    episodes = ev.episodes()
    assert steps.num_rows == sum(episodes["length"].to_pylist())
    cut = episodes.filter(pc.equal(episodes["ended"], False)).to_pylist()
    assert cut and all(r["outcome"] == "incomplete" for r in cut)
    assert {r["env_index"] for r in cut} <= set(range(STREAMS))


def test_games_are_recorded_on_episodes_and_resets(tmp_path: Path) -> None:
    path = tmp_path / "games.mcap"
    _record_streams(path, games=True, episodes=2)
    ev = open_evidence(path)
    episodes = ev.episodes()
    games = episodes["game"].to_pylist()
    assert games[:STREAMS] == [0] * STREAMS and None not in games
    resets = ev.resets()
    assert dict(
        zip(resets["episode"].to_pylist(), resets["game"].to_pylist(), strict=True)
    ) == dict(zip(episodes["episode"].to_pylist(), games, strict=True))
    # the JSON records say the same (null game fields are left out of single-env files)
    with open(path, "rb") as f:
        records = [
            json.loads(m.data)
            for _, c, m in make_reader(f).iter_messages(topics=[fmt.TOPIC_EPISODE_END])
        ]
    assert [r["game"] for r in sorted(records, key=lambda r: r["episode"])] == games


def test_single_env_files_keep_their_layout(tmp_path: Path) -> None:
    path = tmp_path / "single.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=1)
        env.step(0)
    ev = open_evidence(path)
    assert not ev.multi_stream
    assert ev.episodes()["game"].to_pylist() == [None]
    assert "agent" not in ev.resets().column_names  # reset blocks as format 1.0 always had
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert [c.topic for _, c in sorted(summary.channels.items())] == [
        fmt.TOPIC_STEPS,
        fmt.TOPIC_RESETS,
        fmt.TOPIC_EPISODE_END,
        fmt.TOPIC_EPISODES,
    ]


class _BigObservations(gym.Env[Any, int]):
    """100 000 float32 per observation: 400 kB a row."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (100_000,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: Any = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action: int) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        return self.observation_space.sample(), 1.0, False, False, {}


def test_large_rows_make_smaller_blocks_than_block_steps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Blocks are sized so one flush's chunk stays under the target (the reader refuses
    # records over 1 GiB); here the target is 2 MiB, so 5 rows of 400 kB per block.
    monkeypatch.setattr(evidence_file, "CHUNK_TARGET_BYTES", 2 << 20)
    path = tmp_path / "big.mcap"
    with RecordEvidence(_BigObservations(), path, flush_every_s=3600.0) as env:
        env.reset(seed=0)
        for _ in range(12):
            env.step(0)
    ev = open_evidence(path)
    sizes = [batch.num_rows for batch in ev.iter_step_batches()]
    assert sum(sizes) == 12
    assert ev.run.recorder["block_steps"] == DEFAULT_BLOCK_STEPS  # as configured
    with open(path, "rb") as f:
        blocks = [
            pa.ipc.open_stream(m.data).read_all().num_rows
            for _, c, m in make_reader(f).iter_messages()
            if c.topic == "episode_audit/steps"
        ]
    assert blocks == [5, 5, 2]


def test_begin_notes_options_it_cannot_hold_and_keeps_a_callers_rng_reason(
    tmp_path: Path,
) -> None:
    """Cyclic or too deep options raised RecursionError out of begin() (the recorder then lost
    the episode boundary); a caller's own rng_state_unavailable reason got a second, generic,
    false one beside it."""
    env = gym.make("CartPole-v1")
    settings = RecorderSettings(command_line=["test"])
    run = run_info(
        settings=settings,
        spec=env.spec,
        observation_space=describe_space(env.observation_space),
        action_space=describe_space(env.action_space),
        layout={"kind": "single"},
    )
    path = tmp_path / "begin.mcap"
    file = EvidenceFile(path, run, settings)
    stream = file.add_stream(codec_for(env.observation_space), codec_for(env.action_space))
    file.start()
    cyclic: dict[str, Any] = {"a": 1}
    cyclic["self"] = cyclic
    deep: Any = []
    for _ in range(5000):
        deep = [deep]
    for options in (cyclic, {"deep": deep}):
        notes: list[str] = []
        episode = stream.begin(1, recordable_options(options), None, notes)
        stream.record_reset(episode, *env.reset(seed=1), notes)
        stream.step(0, env.step(0))
    notes = ["rng_state_unavailable: the caller knows why"]
    episode = stream.begin(None, None, None, notes)
    stream.record_reset(episode, *env.reset(), notes)
    file.close()
    rows = open_evidence(path).resets().column("notes").to_pylist()
    assert [json.loads(r)[0].split(":")[0] for r in rows[:2]] == ["options_unserializable"] * 2
    assert json.loads(rows[2]) == ["rng_state_unavailable: the caller knows why"]
