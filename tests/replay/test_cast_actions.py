"""Actions the recorder cast to the space's dtype (``action_cast``): no ``diverged`` verdict.

A policy's float64 actions for a float32 ``Box`` (``np.clip(W @ obs, ...)``) are stored
float32: the env stepped values the file holds rounded, so a replay stepping the stored ones
can differ from the recording with nothing wrong in the env.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordParallelEvidence, RecordVectorEvidence, replay
from episode_audit.cli import app

CAST = (
    r"differed at step 0 \(\w+\) after the recorder cast its actions \(from step 0: dtype "
    r"float64 cast to float32\): the env stepped values the file holds rounded, so replay "
    r"cannot step the same ones; give env.step\(\) actions of the action space's dtype"
)


def _pendulum(path: Path, dtype: type) -> Path:
    """Two Pendulum-v1 episodes stepped with 0.1 in ``dtype``.

    (Pendulum computes in its action's dtype: even a float64 value a float32 holds exactly,
    0.25, steps other physics than its float32 cast.)
    """
    with RecordEvidence(gym.make("Pendulum-v1", max_episode_steps=20), path) as env:
        for seed in range(2):
            env.reset(seed=seed)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(np.array([0.1], dtype))
                done = terminated or truncated
    return path


def test_float64_actions_cast_when_recorded_are_not_replayable_not_diverged(
    tmp_path: Path,
) -> None:
    result = replay([_pendulum(tmp_path / "f64.mcap", np.float64)])
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    for episode in result.episodes:
        assert re.match(CAST, str(episode.reason)), episode.reason


def test_the_command_line_says_why_and_does_not_say_diverged(tmp_path: Path) -> None:
    path = _pendulum(tmp_path / "f64.mcap", np.float64)
    done = CliRunner().invoke(app, ["replay", str(path), "--format", "json"])
    assert done.exit_code == 1  # (nothing verified: the gate says so)
    episodes = json.loads(done.stdout)["episodes"]
    assert [e["status"] for e in episodes] == ["not_replayable"] * 2


def test_actions_of_the_spaces_dtype_replay_identical(tmp_path: Path) -> None:
    result = replay([_pendulum(tmp_path / "ok.mcap", np.float32)])
    assert [e.status for e in result.episodes] == ["identical"] * 2


def test_a_vector_recorders_cast_actions_are_not_replayable(tmp_path: Path) -> None:
    path = tmp_path / "vec.mcap"
    venv = gym.make_vec("Pendulum-v1", 2, vectorization_mode="sync", max_episode_steps=10)
    with RecordVectorEvidence(venv, path) as env:
        env.reset(seed=0)
        for _ in range(10):
            env.step(np.full((2, 1), 0.1, np.float64))
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert all("the recorder cast its actions" in str(e.reason) for e in result.episodes)


class Drift(ParallelEnv):  # type: ignore[misc]
    """Two agents push one float64 position: each sees it; a float32 ``Box`` action each."""

    metadata: dict[str, Any] = {"name": "drift_v0"}

    def __init__(self) -> None:
        self.possible_agents = ["a", "b"]
        self.agents: list[str] = []
        self.x = 0.0
        self.t = 0

    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, (1,), np.float64)

    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.agents, self.x, self.t = list(self.possible_agents), 0.0, 0
        return {a: np.array([self.x]) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> Any:
        self.t += 1
        self.x += sum(float(np.asarray(a).reshape(-1)[0]) for a in actions.values())
        done = self.t >= 3
        agents = list(self.agents)
        if done:
            self.agents = []
        obs = {a: np.array([self.x]) for a in agents}
        return (
            obs,
            dict.fromkeys(agents, 0.0),
            dict.fromkeys(agents, done),
            dict.fromkeys(agents, False),
            {a: {} for a in agents},
        )


def test_a_games_cast_actions_make_its_differences_not_replayable(tmp_path: Path) -> None:
    path = tmp_path / "drift.mcap"
    with RecordParallelEvidence(Drift(), path) as env:
        env.reset(seed=0)
        while env.agents:
            env.step({"a": np.array([0.1]), "b": np.array([0.2], np.float32)})
    result = replay([path], env_factory=Drift)
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    assert all("the recorder cast its actions" in str(e.reason) for e in result.episodes)
