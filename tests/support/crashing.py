"""A real CartPole whose env raises in chosen episodes: their outcome is ``error``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym

from episode_audit import RecordEvidence


class Crashing(gym.Wrapper[Any, Any, Any, Any]):
    """Raises at the third step of each episode whose reset seed ``crash`` accepts."""

    def __init__(self, env: gym.Env[Any, Any], crash: Any) -> None:
        super().__init__(env)
        self.crash, self.steps, self.seed_ = crash, 0, None

    def reset(self, **kwargs: Any) -> Any:
        self.steps, self.seed_ = 0, kwargs.get("seed")
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> Any:
        self.steps += 1
        if self.steps == 3 and self.crash(self.seed_):
            raise RuntimeError("the env crashed")
        return self.env.step(action)


def crashing_cartpole(path: Path, episodes: int, crash: Any = lambda seed: False) -> Path:
    """``episodes`` of CartPole (20 steps at most), episode ``i`` seeded ``i``; the episodes
    ``crash`` names end in ``error``."""
    env = Crashing(gym.make("CartPole-v1", max_episode_steps=20), crash)
    with RecordEvidence(env, path) as recorded:
        recorded.action_space.seed(0)
        for seed in range(episodes):
            recorded.reset(seed=seed)
            try:
                while not any(recorded.step(recorded.action_space.sample())[2:4]):
                    pass
            except RuntimeError:
                pass
    return path
