"""The Evidence API: tables, column and episode selection, streaming, one episode."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest

from episode_audit import (
    ConfigurationError,
    EvidenceError,
    RecordVectorEvidence,
    open_evidence,
)
from episode_audit.read import Evidence


def test_episodes_steps_and_selection(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert ev.finished and ev.torn is None
    assert ev.run_end is not None and ev.run_end["status"] == "finished"
    episodes = ev.episodes()
    assert episodes.num_rows == 5  # 4 ended + the last reset, closed as incomplete
    assert episodes["outcome"].to_pylist()[:4] == ["failure"] * 4
    assert episodes["outcome"].to_pylist()[4] == "incomplete"
    steps = ev.steps(columns=["episode", "step", "reward"])
    assert steps.column_names == ["episode", "step", "reward"]
    assert steps.num_rows == sum(episodes["length"].to_pylist())
    only = ev.steps(episodes=[2])
    assert set(only["episode"].to_pylist()) == {2}
    assert only["step"].to_pylist() == list(range(only.num_rows))
    assert only.num_rows == episodes["length"].to_pylist()[2]


def test_episode_reads_only_its_own_rows(recorded: Path) -> None:
    ev = open_evidence(recorded)
    for record in ev.episodes().to_pylist():
        episode = ev.episode(record["episode"])
        assert episode.steps.num_rows == record["length"]
        assert episode.reset is not None and episode.reset["episode"] == record["episode"]
    with pytest.raises(EvidenceError, match="no episode 99"):
        ev.episode(99)


@pytest.mark.parametrize(
    ("select", "message"),
    [
        (
            lambda ev: ev.steps(columns=["rewards"]),
            r"^columns: no column 'rewards' in the steps of .*run\.mcap; its columns are "
            r"episode, step, .*reward",
        ),
        (
            lambda ev: next(ev.iter_step_batches(["nope"])),
            r"^columns: no column 'nope' in the steps of .*; its columns are episode, step",
        ),
        (
            lambda ev: ev.steps(columns="reward"),
            r"^columns: expected a list of names, got the string 'reward'; pass \['reward'\]$",
        ),
        (
            lambda ev: ev.steps(columns=[3]),
            r"^columns\[0\]: expected a name \(a str\), got 3 \(int\)$",
        ),
        (
            lambda ev: ev.episode("1"),
            r"^index: expected an episode index >= 0 \(an int\), got '1' \(str\)$",
        ),
        (
            lambda ev: ev.episode(True),
            r"^index: expected an episode index >= 0 \(an int\), got True \(bool\)$",
        ),
        (
            lambda ev: ev.steps(episodes=["1"]),
            r"^episodes: expected an episode index >= 0 \(an int\), got '1' \(str\)$",
        ),
        (
            lambda ev: ev.steps(episodes=2),
            r"^episodes: expected a list of episode indices, got 2; pass e\.g\. \[0, 3\]$",
        ),
    ],
)
def test_a_wrong_column_or_episode_is_a_configuration_error_saying_what_to_pass(
    recorded: Path, select: Callable[[Evidence], object], message: str
) -> None:
    with pytest.raises(ConfigurationError, match=message):
        select(open_evidence(recorded))


def test_episodes_given_as_numpy_integers_select_them(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert set(ev.steps(episodes=np.array([1, 2]))["episode"].to_pylist()) == {1, 2}
    assert ev.episode(np.int64(1)).index == 1


def test_each_episode_of_a_vector_file_has_its_reset_row(tmp_path: Path) -> None:
    # the sub-envs' reset blocks share a chunk: a later sub-env's episode came without its
    # reset row (None) when an earlier sub-env's block ended after its start
    path = tmp_path / "vector.mcap"
    with RecordVectorEvidence(
        gym.make_vec("CartPole-v1", 4, vectorization_mode="sync"), path
    ) as envs:
        envs.reset(seed=0)
        for _ in range(60):
            envs.step(envs.action_space.sample())
    ev = open_evidence(path)
    records = ev.episodes().to_pylist()
    assert len({r["env_index"] for r in records}) == 4 and len(records) > 4
    for episode in ev.iter_episodes():
        assert episode.reset is not None, episode.index
        assert episode.reset["episode"] == episode.index
        assert episode.reset["env_index"] == episode.record["env_index"]


def test_iter_step_batches_streams_blocks(recorded: Path) -> None:
    ev = open_evidence(recorded)
    batches = list(ev.iter_step_batches(columns=["reward"]))
    assert len(batches) > 2
    assert all(b.num_rows <= 16 for b in batches)


def test_tables_are_arrow(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert isinstance(ev.episodes(), pa.Table)
    assert isinstance(ev.steps(), pa.Table)
    assert isinstance(ev.resets(), pa.Table)
