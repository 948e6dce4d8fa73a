"""A user env with reward terms for the contract tests (copied into pytester projects).

``Walk``: step right (1) or left (0) from about 0; reaching +5 is success, -3 the failure
``"fell"``. Its reward is the sum of ``info["reward_terms"]``. Each keyword breaks one clause
of the contract on purpose.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class Walk(gym.Env[Any, Any]):
    """A one-dimensional walk with success, a labelled failure and named reward terms."""

    observation_space = spaces.Box(-10.0, 10.0, (1,), np.float32)
    action_space = spaces.Discrete(2)

    def __init__(
        self,
        *,
        bad_sum_at: int | None = None,
        own_time_limit: int | None = None,
        success_truncates: bool = False,
        noisy_reset: bool = False,
        falling_pays: bool = False,
    ) -> None:
        self.bad_sum_at = bad_sum_at  # the reward is not the sum of its terms at this step
        self.own_time_limit = own_time_limit  # a time limit reported as termination
        self.success_truncates = success_truncates  # success reported as truncation
        self.noisy_reset = noisy_reset  # reset ignores its seed
        self.falling_pays = falling_pays  # the failure out-earns success
        self.x = 0.0
        self.t = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        self.x = float(self.np_random.integers(-1, 2))
        if self.noisy_reset:  # a draw the seed does not fix: never the same twice
            self.x += float(np.random.default_rng().uniform(-0.4, 0.4))
        self.t = 0
        return np.array([self.x], np.float32), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        self.t += 1
        self.x += 1.0 if int(action) == 1 else -1.0
        terms = {"progress": 0.25 if int(action) == 1 else -0.25, "time": -0.125}
        success = self.x >= 5
        failure = "fell" if self.x <= -3 else None
        if success:
            terms["success_bonus"] = 1.0
        if failure:
            terms["fall_penalty"] = 5.0 if self.falling_pays else -1.0
        reward = sum(terms.values())
        if self.bad_sum_at == self.t - 1:
            reward += 0.5
        terminated = success or failure is not None
        truncated = False
        if self.own_time_limit is not None and self.t >= self.own_time_limit and not terminated:
            terminated = True
        if success and self.success_truncates:
            terminated, truncated = False, True
        info = {"reward_terms": terms, "success": success, "failure": failure}
        return np.array([self.x], np.float32), reward, terminated, truncated, info
