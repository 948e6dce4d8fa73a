"""Replay's verdicts: per-sub-env replay, causes classified before comparing, real divergence."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit import RecordVectorEvidence
from episode_audit.replay import replay
from tests.support.stateful import counted_cartpole


def record_vector(path: Path, vectorization: str, n: int = 3, steps: int = 60) -> Path:
    """Random steps of ``n`` CartPoles, each in its own episode counter."""
    make = gym.vector.SyncVectorEnv if vectorization == "sync" else gym.vector.AsyncVectorEnv
    envs: Any = make([counted_cartpole] * n)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=11)
        rec.action_space.seed(3)
        for _ in range(steps):
            rec.step(rec.action_space.sample())
    return path


@pytest.mark.parametrize("vectorization", ["sync", "async"])
def test_each_sub_env_replays_in_its_own_env_in_recorded_order(
    tmp_path: Path, vectorization: str
) -> None:
    path = record_vector(tmp_path / "v.mcap", vectorization)
    result = replay([path], env_factory=counted_cartpole)
    statuses = [(e.episode, e.status, e.divergence) for e in result.episodes]
    assert len(statuses) > 12
    assert all(s == "identical" for _, s, _ in statuses), statuses
