"""The step limits of an env's Gymnasium ``TimeLimit`` wrappers: every one of them counts.

A wrapper chain may hold more than one ``TimeLimit``: ``TimeLimit(gym.make("Pendulum-v1"), 500)``
keeps the registered 200-step limit inside. Each counts the steps since the last reset and sets
``truncated`` when its count reaches its own limit, so the smallest ends the episode first, and a
truncation is the time limit's when any of them has reached its limit. Gymnasium's spec names the
outermost one only. :func:`time_limits` finds them all, :func:`step_limit` says the limit in
effect, :func:`limited_spec` puts it in the spec a file records, :func:`time_limit_hit` says
whether an episode has reached one, :func:`plain_time_limit` whether replay may count the
outermost itself.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec
from gymnasium.wrappers import TimeLimit

__all__ = ["limited_spec", "plain_time_limit", "step_limit", "time_limit_hit", "time_limits"]

_DEEPEST = 64
"""Wrappers walked at most (a chain longer than this is not searched further)."""


def time_limits(env: Any) -> tuple[TimeLimit[Any, Any], ...]:
    """Every Gymnasium ``TimeLimit`` around ``env`` (``env`` itself included), outermost first.

    Never raises: a chain that cannot be walked gives what was walked.

    >>> import gymnasium as gym
    >>> env = gym.wrappers.TimeLimit(gym.make("CartPole-v1"), 800)
    >>> [t._max_episode_steps for t in time_limits(env)], time_limits(env.unwrapped)
    ([800, 500], ())
    """
    found: list[TimeLimit[Any, Any]] = []
    try:
        for _ in range(_DEEPEST):
            if not isinstance(env, gym.Wrapper):
                break
            if isinstance(env, TimeLimit):
                found.append(env)
            env = env.env
    except Exception:  # an env's own attribute access: the chain walked so far
        pass
    return tuple(found)


def step_limit(env: Any) -> int | None:
    """The step limit in effect around ``env``: the smallest of its ``TimeLimit``s' limits.

    ``None`` when it has none (a limit that is not a positive int is not one).

    >>> import gymnasium as gym
    >>> step_limit(gym.wrappers.TimeLimit(gym.make("CartPole-v1"), 800))
    500
    """
    limits = [_limit(t) for t in time_limits(env)]
    return min([n for n in limits if n is not None], default=None)


def limited_spec(spec: EnvSpec | None, env: Any) -> EnvSpec | None:
    """``spec`` with the step limit in effect around ``env`` (:func:`step_limit`) as its own.

    Gymnasium's spec of a chain with more than one ``TimeLimit`` names the outermost's limit;
    the file records the one that ends episodes, which ``gym.make`` of the spec rebuilds. A
    chain without a ``TimeLimit`` found in it keeps the spec's own limit.

    >>> import gymnasium as gym
    >>> env = gym.wrappers.TimeLimit(gym.make("CartPole-v1"), 800)
    >>> env.spec.max_episode_steps, limited_spec(env.spec, env).max_episode_steps
    (800, 500)
    """
    limit = step_limit(env)
    if spec is None or limit is None or spec.max_episode_steps == limit:
        return spec
    return dataclasses.replace(spec, max_episode_steps=limit)


def time_limit_hit(limits: Iterable[TimeLimit[Any, Any]]) -> bool:
    """Whether any of ``limits`` has reached its maximum number of steps in this episode."""
    for time_limit in limits:
        elapsed = getattr(time_limit, "_elapsed_steps", None)
        limit = getattr(time_limit, "_max_episode_steps", None)
        try:
            if elapsed is not None and limit is not None and elapsed >= limit:
                return True
        except TypeError:  # counts that do not compare: not a limit reached
            continue
    return False


def plain_time_limit(env: Any) -> tuple[Any, int] | None:
    """``(inner env, max_episode_steps)`` when ``env`` is exactly Gymnasium's ``TimeLimit``.

    Its reset only zeroes a counter, and its step only counts and sets ``truncated`` on the
    ``max_episode_steps``-th step: a loop that resets and steps the inner env and counts the
    same way gets what the wrapper returns, without a wrapper call per step. A subclass may
    do more, so only the class itself qualifies. ``TimeLimit``s inside the inner env still
    count (:func:`time_limits` of it).

    >>> import gymnasium as gym
    >>> inner, limit = plain_time_limit(gym.make("CartPole-v1", disable_env_checker=True))
    >>> type(inner).__name__, limit
    ('OrderEnforcing', 500)
    >>> plain_time_limit(gym.make("CartPole-v1").unwrapped) is None
    True
    """
    if type(env) is not TimeLimit:
        return None
    limit = _limit(env)
    return None if limit is None else (env.env, limit)


def _limit(time_limit: TimeLimit[Any, Any]) -> int | None:
    """A ``TimeLimit``'s limit, when it is a positive int."""
    limit = getattr(time_limit, "_max_episode_steps", None)
    return limit if type(limit) is int and limit > 0 else None
