"""An env whose observation Dict holds a Gymnasium space of its own class (like MiniGrid's).

``MissionSpace`` is a text-like space episode-audit does not know; ``mission_env`` is the env
factory (as --env-factory MODULE:CALLABLE) that builds the env replay compares against.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

MISSIONS = ("go to the red door", "pick up the key", "open the box")


class MissionSpace(spaces.Space[str]):
    """One of a few mission strings: a space of its own class, not a ``spaces.Text``."""

    def __init__(self, missions: tuple[str, ...] = MISSIONS, seed: int | None = None) -> None:
        super().__init__(dtype=str, seed=seed)
        self.missions = missions

    def sample(self, mask: Any = None, probability: Any = None) -> str:
        return self.missions[int(self.np_random.integers(len(self.missions)))]

    def contains(self, x: Any) -> bool:
        return isinstance(x, str) and x in self.missions

    def to_jsonable(self, sample_n: Any) -> list[Any]:
        """Each mission as ``{"mission": text}`` (not what a plain JSON of the value would be)."""
        return [{"mission": x} for x in sample_n]

    def from_jsonable(self, sample_n: list[Any]) -> list[str]:
        """The inverse of :meth:`to_jsonable`."""
        return [str(x["mission"]) for x in sample_n]

    def __repr__(self) -> str:
        return f"MissionSpace({len(self.missions)} missions)"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, MissionSpace) and other.missions == self.missions


class MissionEnv(gym.Env[dict[str, Any], int]):
    """A walk on a line toward a goal, with a mission drawn at each reset."""

    def __init__(self) -> None:
        self.observation_space = spaces.Dict(
            {
                "pos": spaces.Box(-10.0, 10.0, shape=(2,), dtype=np.float32),
                "mission": MissionSpace(),
            }
        )
        self.action_space = spaces.Discrete(3)
        self._pos = np.zeros(2, dtype=np.float32)
        self._mission = MISSIONS[0]
        self._t = 0

    def _obs(self) -> dict[str, Any]:
        return {"pos": self._pos.copy(), "mission": self._mission}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        self._pos = self.np_random.uniform(-1.0, 1.0, size=2).astype(np.float32)
        self._mission = MISSIONS[int(self.np_random.integers(len(MISSIONS)))]
        self._t = 0
        return self._obs(), {}

    def step(self, action: int) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        self._pos[0] += float(action) - 1.0 + float(self.np_random.normal(0.0, 0.1))
        self._t += 1
        terminated = bool(abs(self._pos[0]) > 3.0)
        return self._obs(), -abs(float(self._pos[0])), terminated, self._t >= 10, {}


def mission_env() -> gym.Env[Any, Any]:
    """The :class:`MissionEnv`."""
    return MissionEnv()
