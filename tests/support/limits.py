"""Envs whose TimeLimits count different steps, a frame skip between them (record/time_limits)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym

from episode_audit import RecordEvidence


def skipping_pendulum(limit: int | None = None) -> gym.Env[Any, Any]:
    """Pendulum in a 4-step frame skip, in a TimeLimit of ``limit`` steps over it (or none).

    The registered 200-step limit under the frame skip counts Pendulum's own steps: it ends an
    episode at the 50th step.
    """
    env = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1"), skip=4)
    return env if limit is None else gym.wrappers.TimeLimit(env, limit)


def record_two_episodes(path: Path, env: gym.Env[Any, Any], steps: int) -> Path:
    """``steps`` random steps after a reset with seed 0, then after one with seed 1."""
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for seed in (0, 1):
            rec.reset(seed=seed)
            for _ in range(steps):
                rec.step(rec.action_space.sample())
    return path
