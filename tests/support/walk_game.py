"""A PettingZoo game of :class:`~tests.support.walk.Walk` walkers, for the contract tests."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from tests.support.walk import Walk


class WalkGame(ParallelEnv):  # type: ignore[misc]
    """A PettingZoo ``ParallelEnv`` of walkers: each ends on its own, like :class:`Walk`.

    ``max_cycles`` cuts the game off (``info["truncation_reason"] = "time_limit"``);
    ``cutoff_terminates`` reports that cutoff as termination instead.
    """

    metadata: dict[str, Any] = {"name": "walk_game_v0"}

    def __init__(self, *, max_cycles: int = 20, cutoff_terminates: bool = False) -> None:
        self.possible_agents = ["left", "right"]
        self.agents: list[str] = []
        self.max_cycles = max_cycles
        self.cutoff_terminates = cutoff_terminates
        self.x: dict[str, float] = {}
        self.t = 0
        self.rng = np.random.default_rng()

    def observation_space(self, agent: str) -> spaces.Box:
        return Walk.observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return spaces.Discrete(2)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.x = {a: float(self.rng.integers(-1, 2)) for a in self.agents}
        self.t = 0
        return {a: np.array([self.x[a]], np.float32) for a in self.agents}, {
            a: {} for a in self.agents
        }

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], ...]:
        self.t += 1
        obs, rewards, terminated, truncated, infos = {}, {}, {}, {}, {}
        for agent, action in actions.items():
            self.x[agent] += 1.0 if int(action) == 1 else -1.0
            terms = {"progress": 0.25 if int(action) == 1 else -0.25}
            success = self.x[agent] >= 3
            failure = "fell" if self.x[agent] <= -3 else None
            cut = self.t >= self.max_cycles and not (success or failure)
            obs[agent] = np.array([self.x[agent]], np.float32)
            rewards[agent] = sum(terms.values())
            terminated[agent] = success or failure is not None or (cut and self.cutoff_terminates)
            truncated[agent] = cut and not self.cutoff_terminates
            infos[agent] = {"reward_terms": terms, "success": success, "failure": failure}
            if truncated[agent]:
                infos[agent]["truncation_reason"] = "time_limit"
        self.agents = [a for a in self.agents if not (terminated[a] or truncated[a])]
        return obs, rewards, terminated, truncated, infos
