"""CartPole files recorded over Gymnasium's reward wrappers, and one over none.

The recorder sits over the wrapper, so the file holds the wrapper's rewards: ``check`` notes
``rewards_changed``, and ``report`` / ``compare`` say the returns are not the env's.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

from episode_audit import RecordEvidence

Wrap = Callable[[gym.Env[Any, Any]], gym.Env[Any, Any]]

WRAPS: dict[str, Wrap | None] = {
    "plain": None,
    "normalized": lambda env: gym.wrappers.NormalizeReward(env),
    "scaled": lambda env: gym.wrappers.TransformReward(env, lambda r: 10.0 * float(r)),
    "halved": lambda env: gym.wrappers.TransformReward(env, lambda r: 0.5 * float(r)),
    "clipped": lambda env: gym.wrappers.ClipReward(env, -1.0, 1.0),
    "clipped_half": lambda env: gym.wrappers.ClipReward(env, -1.0, 0.5),
}
"""The envs under the recorder, by name: CartPole alone, under NormalizeReward, TransformReward
(by a lambda: the file cannot say which), ClipReward to 1 (CartPole's rewards unchanged) and to
0.5 (halved)."""


def record_cartpole(path: Path, wrap: str = "plain", episodes: int = 8, seed: int = 0) -> Path:
    """Record ``episodes`` of random CartPole, episode ``i`` reset with ``seed + i``."""
    env: gym.Env[Any, Any] = gym.make("CartPole-v1")
    wrapper = WRAPS[wrap]
    if wrapper is not None:
        env = wrapper(env)
    with RecordEvidence(env, path) as recorded:
        recorded.action_space.seed(seed)
        for i in range(episodes):
            recorded.reset(seed=seed + i)
            while not any(recorded.step(recorded.action_space.sample())[2:4]):  # to its end
                pass
    return path
