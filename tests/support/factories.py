"""Env factories the CLI tests pass as --env-factory MODULE:CALLABLE."""

from __future__ import annotations

from typing import Any

import gymnasium as gym


def heavy_cartpole() -> gym.Env[Any, Any]:
    """CartPole with a heavier pole: same reset, different dynamics."""
    env = gym.make("CartPole-v1")
    cp: Any = env.unwrapped
    cp.masspole = 0.3
    cp.total_mass = cp.masspole + cp.masscart
    cp.polemass_length = cp.masspole * cp.length
    return env


def raises() -> gym.Env[Any, Any]:
    """An env factory with a bug (for the CLI's one-line error)."""
    raise RuntimeError("boom from factory")


def not_an_env() -> Any:
    """An env factory that returns something else."""
    return "CartPole-v1"


def crashing_policy(env: gym.Env[Any, Any], seed: int) -> Any:
    """A --policy factory whose policy raises on its third call (a bug in the policy)."""
    calls = [0]

    def act(obs: Any) -> Any:
        calls[0] += 1
        if calls[0] == 3:
            raise ValueError("policy bug")
        return env.action_space.sample()

    return act


def slow_cartpole() -> gym.Env[Any, Any]:
    """CartPole that takes a while to build (a replay to interrupt)."""
    import time

    time.sleep(0.5)
    return gym.make("CartPole-v1")
