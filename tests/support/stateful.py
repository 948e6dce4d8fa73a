"""Envs and wrappers with state beyond an episode, for replay's verdict tests.

``EpisodeCount`` keeps a count of resets and adds it to every observation; ``counted_cartpole``
is the env factory that builds CartPole in it (as --env-factory MODULE:CALLABLE). The others are
factories of envs that differ from CartPole's recording, or are nondeterministic on purpose.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np


class EpisodeCount(gym.ObservationWrapper[Any, Any, Any], gym.utils.RecordConstructorArgs):
    """Adds the number of resets so far to the observation: state across episodes."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.ObservationWrapper.__init__(self, env)
        self.resets = 0

    def reset(self, **kwargs: Any) -> Any:
        self.resets += 1
        return super().reset(**kwargs)

    def observation(self, observation: Any) -> Any:
        return (observation + np.float32(self.resets)).astype(np.float32)


def counted_cartpole() -> gym.Env[Any, Any]:
    """CartPole (at most 8 steps an episode) in :class:`EpisodeCount`."""
    return EpisodeCount(gym.make("CartPole-v1", max_episode_steps=8))


def normalized_cartpole() -> gym.Env[Any, Any]:
    """CartPole (at most 8 steps an episode) in a fresh NormalizeObservation."""
    return gym.wrappers.NormalizeObservation(gym.make("CartPole-v1", max_episode_steps=8))


def cartpole8() -> gym.Env[Any, Any]:
    """CartPole, at most 8 steps an episode (a vector env's sub-env)."""
    return gym.make("CartPole-v1", max_episode_steps=8)


def mountain_car5() -> gym.Env[Any, Any]:
    """MountainCar, at most 5 steps an episode (another env than CartPole)."""
    return gym.make("MountainCar-v0", max_episode_steps=5)


class RandomModuleReset(gym.Wrapper[Any, Any, Any, Any]):
    """Adds a draw of the ``random`` module (not the env's RNG) to the reset observation."""

    def reset(self, **kwargs: Any) -> Any:
        import random

        obs, info = self.env.reset(**kwargs)
        return (obs + np.float32(random.random())).astype(np.float32), info


class MutatesOutsideAnyAdapter(gym.Wrapper[Any, Any, Any, Any]):
    """Adds the number of steps any instance ever took to the reward: state no adapter knows
    (a class attribute, so the replay's wrapper goes on from where the recording's stopped)."""

    steps = 0

    def step(self, action: Any) -> Any:
        obs, reward, term, trunc, info = self.env.step(action)
        type(self).steps += 1
        return obs, float(reward) + type(self).steps, term, trunc, info


def random_module_cartpole() -> gym.Env[Any, Any]:
    """CartPole whose reset observation draws from the ``random`` module."""
    return RandomModuleReset(gym.make("CartPole-v1", max_episode_steps=8))


def mutating_cartpole() -> gym.Env[Any, Any]:
    """CartPole in :class:`MutatesOutsideAnyAdapter`."""
    return MutatesOutsideAnyAdapter(gym.make("CartPole-v1", max_episode_steps=8))
