"""Sub-envs whose RNG a worker process cannot send: ``np_random`` raising, or not pickling.

At module level so that ``AsyncVectorEnv`` / ``SubprocVecEnv`` workers find them.
"""

from __future__ import annotations

import threading
from typing import Any

import gymnasium as gym
from gymnasium.envs.classic_control import CartPoleEnv

from episode_audit import ResetRngInfo

LIMIT = 5
"""Every episode is truncated after this many steps (when not over before)."""


class LockedGenerator:
    """A NumPy generator holding a lock: it draws as the generator does, but does not pickle."""

    def __init__(self, generator: Any) -> None:
        self.generator = generator
        self.lock = threading.Lock()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["generator"], name)


class LockedRngCartPole(CartPoleEnv):
    """CartPole whose ``np_random`` is a :class:`LockedGenerator` after every reset."""

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        if isinstance(self._np_random, LockedGenerator):
            self._np_random = self._np_random.generator
        result = super().reset(seed=seed, options=options)
        self._np_random = LockedGenerator(self._np_random)  # type: ignore[assignment]
        return result


class SealedGenerator(LockedGenerator):
    """A :class:`LockedGenerator` whose ``bit_generator`` (and so its state) cannot be read."""

    @property
    def bit_generator(self) -> Any:
        raise RuntimeError("sealed")


class SealedRngCartPole(CartPoleEnv):
    """CartPole drawing from a :class:`SealedGenerator`: its RNG state cannot be read at all."""

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        if isinstance(self._np_random, LockedGenerator):
            self._np_random = self._np_random.generator
        result = super().reset(seed=seed, options=options)
        self._np_random = SealedGenerator(self._np_random)  # type: ignore[assignment]
        return result


class RaisingRng(gym.Wrapper[Any, Any, Any, Any]):
    """A wrapper whose ``np_random`` raises (the env below it draws from its own)."""

    @property
    def np_random(self) -> Any:  # type: ignore[override]
        raise RuntimeError("np_random is private here")


def locked_rng() -> gym.Env[Any, Any]:
    """CartPole with a generator that does not pickle, episodes of at most :data:`LIMIT`."""
    return gym.wrappers.TimeLimit(LockedRngCartPole(), LIMIT)


def raising_rng() -> gym.Env[Any, Any]:
    """CartPole under a wrapper whose ``np_random`` raises, episodes of at most :data:`LIMIT`."""
    return RaisingRng(gym.wrappers.TimeLimit(CartPoleEnv(), LIMIT))


def rng_locked_rng() -> gym.Env[Any, Any]:
    """:func:`locked_rng` in :class:`ResetRngInfo`."""
    return ResetRngInfo(locked_rng())


def rng_raising_rng() -> gym.Env[Any, Any]:
    """:func:`raising_rng` in :class:`ResetRngInfo`."""
    return ResetRngInfo(raising_rng())


def rng_sealed_rng() -> gym.Env[Any, Any]:
    """:class:`SealedRngCartPole` in a limit of :data:`LIMIT`, in :class:`ResetRngInfo`."""
    return ResetRngInfo(gym.wrappers.TimeLimit(SealedRngCartPole(), LIMIT))


class KwargCartPole(CartPoleEnv):
    """CartPole taking any keyword argument (kept in its spec's kwargs, as ``gym.make`` keeps
    them): ``gym.make(KWARG_ID, lock=lambda: 1)`` makes a spec that does not pickle."""

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        super().__init__(render_mode=render_mode)
        self.kwargs = kwargs


KWARG_ID = "EpisodeAuditKwargCartPole-v0"
""":class:`KwargCartPole`, registered with a limit of :data:`LIMIT`."""

if KWARG_ID not in gym.registry:
    gym.register(KWARG_ID, entry_point=KwargCartPole, max_episode_steps=LIMIT)


def lambda_kwarg() -> gym.Env[Any, Any]:
    """:class:`KwargCartPole` made with a lambda among its kwargs: its spec does not pickle."""
    return gym.make(KWARG_ID, lock=lambda: 1)


def raising_rng_made() -> gym.Env[Any, Any]:
    """CartPole made by ``gym.make`` under a wrapper whose ``np_random`` raises."""
    return RaisingRng(gym.make("CartPole-v1", max_episode_steps=LIMIT))


def locked_rng_made() -> gym.Env[Any, Any]:
    """:class:`LockedRngCartPole` made by ``gym.make``: a generator that does not pickle."""
    return gym.make(LOCKED_ID)


LOCKED_ID = "EpisodeAuditLockedRngCartPole-v0"

if LOCKED_ID not in gym.registry:
    gym.register(LOCKED_ID, entry_point=LockedRngCartPole, max_episode_steps=LIMIT)
