"""Capture and restore an environment's ``np_random`` state, so unseeded resets replay.

Gymnasium environments draw their reset noise from ``env.unwrapped.np_random``. When
``reset()`` is called without a seed, the recorder captures that generator's bit-generator
state just before the reset; replay restores it and calls ``reset(seed=None)``.

>>> import gymnasium as gym
>>> env = gym.make("CartPole-v1"); _ = env.reset(seed=3)
>>> state = capture_rng_state(env)
>>> first, _ = env.reset()
>>> restore_rng_state(env, state)
>>> again, _ = env.reset()
>>> bool((first == again).all())
True
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["capture_rng_state", "restore_rng_state"]


def capture_rng_state(env: Any) -> dict[str, Any] | None:
    """Return ``env.unwrapped.np_random.bit_generator.state``, or ``None`` if it has none.

    Reading ``np_random`` of a never-seeded Gymnasium env creates its generator (with fresh
    OS entropy), exactly as the env's own unseeded ``reset()`` would, so the captured state is
    the one that reset then uses.
    """
    try:
        generator = getattr(env, "unwrapped", env).np_random
        state = generator.bit_generator.state
    except Exception:
        return None
    return state if isinstance(state, dict) else None


def restore_rng_state(env: Any, state: dict[str, Any]) -> None:
    """Give ``env.unwrapped`` a generator in exactly ``state``.

    Raises ``ValueError`` when the state names an unknown bit generator.
    """
    name = state.get("bit_generator")
    bit_generator_cls = getattr(np.random, str(name), None)
    if not (
        isinstance(bit_generator_cls, type)
        and issubclass(bit_generator_cls, np.random.BitGenerator)
    ):
        raise ValueError(f"unknown bit generator {name!r} in the recorded RNG state")
    bit_generator = bit_generator_cls()
    bit_generator.state = state
    env.unwrapped.np_random = np.random.Generator(bit_generator)
