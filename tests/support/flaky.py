"""An env whose step raises, and the loop that catches it and steps on, for replay's tests.

:class:`Flaky` raises ``RuntimeError`` on the third step of every episode reset with an odd
seed (once: the step after it goes on). Importing this module registers it as
``EpisodeAuditFlaky-v0`` (its observation counts every step the env ever took, the one that
raised included: state across episodes) and ``EpisodeAuditFlakyFresh-v0`` (no such count: each
episode's steps depend on its seed alone). :func:`record_flaky` records the loop a user's
training loop would run: it catches the error and keeps stepping the same env.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from episode_audit import RecordEvidence

FLAKY = "EpisodeAuditFlaky-v0"
FLAKY_FRESH = "EpisodeAuditFlakyFresh-v0"


class Flaky(gym.Env[np.ndarray, np.int64]):
    """Deterministic, seeded; step ``raise_at`` of an odd-seeded episode raises, once.

    The observation: the step within the episode, every step taken so far (``persist``: else
    0), and a draw of ``np_random`` at the reset. An episode terminates after ``length`` steps.
    """

    observation_space = gym.spaces.Box(-1e9, 1e9, (3,), np.float64)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, raise_at: int = 3, length: int = 6, persist: bool = True) -> None:
        self.raise_at, self.length, self.persist = raise_at, length, persist
        self.t = self.total = 0
        self.odd = self.raised = False
        self.draw = 0.0

    def _obs(self) -> np.ndarray:
        return np.array([self.t, self.total if self.persist else 0, self.draw], np.float64)

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        self.t, self.raised = 0, False
        self.odd = seed is not None and seed % 2 == 1
        self.draw = float(self.np_random.random())
        return self._obs(), {}

    def step(self, action: Any) -> Any:
        self.t += 1
        self.total += 1
        if self.odd and self.t == self.raise_at and not self.raised:
            self.raised = True
            raise RuntimeError(f"flaky at step {self.t}")
        return self._obs(), float(action) + self.t, self.t >= self.length, False, {}


gym.register(FLAKY, entry_point=Flaky)
gym.register(FLAKY_FRESH, entry_point=Flaky, kwargs={"persist": False})


def record_flaky(path: Path, env_id: str = FLAKY, episodes: int = 4) -> Path:
    """Record ``episodes`` episodes (seeds 0, 1, …); the loop catches the error and steps on.

    Episode 1 (seed 1) ends ``error`` after 2 steps; the loop's next 3 steps (the last one
    terminated) are rows after its end.
    """
    with RecordEvidence(gym.make(env_id), path) as env:
        for seed in range(episodes):
            env.reset(seed=seed)
            done, k = False, 0
            while not done:
                k += 1
                try:
                    _, _, term, trunc, _ = env.step(k % 2)
                except RuntimeError:
                    continue  # the user's loop: caught, and the same env stepped on
                done = term or trunc
    return path
