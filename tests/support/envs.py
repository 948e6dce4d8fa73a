"""Small configurable environments for edge cases (after Gymnasium's tests/testing_env.py)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

StepFn = Callable[["ScriptedEnv", Any], tuple[Any, Any, Any, Any, Any]]
ResetFn = Callable[["ScriptedEnv"], tuple[Any, Any]]


class ScriptedEnv(gym.Env[Any, Any]):
    """An env whose reset/step are given as functions; t counts steps since reset."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        step_fn: StepFn | None = None,
        reset_fn: ResetFn | None = None,
        observation_space: gym.Space[Any] | None = None,
        action_space: gym.Space[Any] | None = None,
    ) -> None:
        self.observation_space = (
            gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
            if observation_space is None
            else observation_space
        )
        self.action_space = gym.spaces.Discrete(3) if action_space is None else action_space
        self._step_fn = step_fn
        self._reset_fn = reset_fn
        self.t = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        self.t = 0
        if self._reset_fn is not None:
            return self._reset_fn(self)
        return self.np_random.uniform(-1, 1, 2).astype(np.float32), {}

    def step(self, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        self.t += 1
        if self._step_fn is not None:
            return self._step_fn(self, action)
        obs = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        return obs, 1.0, False, False, {}
