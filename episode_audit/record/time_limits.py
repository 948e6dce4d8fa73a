"""The step limits of an env's Gymnasium ``TimeLimit`` wrappers: every one of them counts.

A wrapper chain may hold more than one ``TimeLimit``: ``TimeLimit(gym.make("Pendulum-v1"), 500)``
keeps the registered 200-step limit inside. Each counts the steps since the last reset and sets
``truncated`` when its count reaches its own limit, so the smallest ends the episode first, and a
truncation is the time limit's when any of them has reached its limit. Gymnasium's spec names the
outermost one only, and ``gym.make`` of a spec puts it right over the env, under every recorded
wrapper. That is the same limit only when no wrapper between steps the env more than once per
step (:data:`~episode_audit.format.wrappers.MULTI_STEP_WRAPPERS`: frame skipping, resets inside
a step): ``TimeLimit(MaxAndSkipObservation(env, 4), 30)`` truncates at its 30th step, the env's
120th. :func:`time_limits` finds them all, :func:`step_limit` says the smallest,
:func:`limit_places` where each counts, :func:`limited_spec` puts them in the spec a file records
(those under no multi-step wrapper as its ``max_episode_steps``, the smallest of them; each other
as a ``TimeLimit`` among its ``additional_wrappers``, where it was, so ``gym.make`` of the spec
rebuilds the chain), :func:`time_limit_hit` whether an episode has reached one,
:func:`plain_time_limit` whether replay may count the outermost itself, :func:`unread_limits`
why a vector recorder's streams cannot read them all (said in the file's layout).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec, WrapperSpec
from gymnasium.wrappers import TimeLimit

from ..format.wrappers import (
    LAYOUT_UNREAD_CAUSE,
    LAYOUT_UNREAD_LIMITS,
    UNREAD_IN_WORKERS,
    UNREAD_ZEROED,
    multi_step,
    worker_limits,
)

__all__ = [
    "LimitPlaces",
    "counted_limits",
    "limit_places",
    "limited_spec",
    "plain_time_limit",
    "step_limit",
    "time_limit_hit",
    "time_limits",
    "unread_limits",
]

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
    return tuple(w for w in _chain(env) if isinstance(w, TimeLimit))


def _chain(env: Any) -> list[Any]:
    """The wrappers around ``env`` (``env`` itself included), outermost first; never raises."""
    found: list[Any] = []
    try:
        for _ in range(_DEEPEST):
            if not isinstance(env, gym.Wrapper):
                break
            found.append(env)
            env = env.env
    except Exception:  # an env's own attribute access: the chain walked so far
        pass
    return found


def step_limit(env: Any) -> int | None:
    """The step limit in effect around ``env``: the smallest of its ``TimeLimit``s' limits.

    ``None`` when it has none (a limit that is not a positive int is not one).

    >>> import gymnasium as gym
    >>> step_limit(gym.wrappers.TimeLimit(gym.make("CartPole-v1"), 800))
    500
    """
    limits = [_limit(t) for t in time_limits(env)]
    return min([n for n in limits if n is not None], default=None)


@dataclasses.dataclass(frozen=True)
class LimitPlaces:
    """Where the ``TimeLimit``s around an env count (:func:`limit_places`).

    ``inner``: the smallest limit of those under no multi-step wrapper (they count the env's own
    steps, and are one limit wherever they are: what ``gym.make`` puts right over the env);
    ``placed``: each other one, innermost first, as ``(n, limit)`` with ``n`` the number of
    wrappers its env's spec records under it (its place among the spec's
    ``additional_wrappers``), ``n`` ``None`` when that spec cannot be read; ``counted``: the
    smallest limit of those with no multi-step wrapper over them (they count the steps of the
    env they were found around); ``under``: the class name of the multi-step wrapper over one
    that ``counted`` leaves out (``None``: it leaves out none); ``found``: whether there is any.
    """

    inner: int | None = None
    placed: tuple[tuple[int | None, int], ...] = ()
    counted: int | None = None
    under: str | None = None
    found: bool = False


def limit_places(env: Any) -> LimitPlaces:
    """Where each ``TimeLimit`` around ``env`` counts (a limit that is not a positive int: none).

    >>> import gymnasium as gym
    >>> skip = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1"), skip=4)
    >>> places = limit_places(gym.wrappers.TimeLimit(skip, 30))
    >>> places.inner, places.placed, places.counted, places.under
    (200, ((1, 30),), 30, 'MaxAndSkipObservation')
    >>> limit_places(gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 500))
    LimitPlaces(inner=200, placed=(), counted=200, under=None, found=True)
    """
    chain = _chain(env)
    multi = [multi_step(f"{type(w).__module__}:{type(w).__name__}") for w in chain]
    inner: list[int] = []
    placed: list[tuple[int | None, int]] = []
    counted: list[int] = []
    under: str | None = None
    for depth, wrapper in enumerate(chain):
        if not isinstance(wrapper, TimeLimit):
            continue
        limit = _limit(wrapper)
        if limit is None:
            continue
        over = [w for w, m in zip(chain[:depth], multi, strict=False) if m]
        if over:
            under = under or type(over[-1]).__name__
        else:
            counted.append(limit)
        if any(multi[depth + 1 :]):
            placed.append((_spec_wrappers(wrapper.env), limit))
        else:
            inner.append(limit)
    return LimitPlaces(
        min(inner, default=None),
        tuple(placed[::-1]),
        min(counted, default=None),
        under,
        any(isinstance(w, TimeLimit) for w in chain),
    )


def counted_limits(envs: Iterable[Any], fallback: int | None) -> list[int | None]:
    """Each of ``envs``' step limit in its own steps, for a stream to count.

    :class:`LimitPlaces` ``counted``; ``None`` where every ``TimeLimit`` is under a multi-step
    wrapper (it counts the env's own steps); ``fallback`` (the spec's) where none is found.

    >>> import gymnasium as gym
    >>> skip = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1"), skip=4)
    >>> counted_limits([gym.wrappers.TimeLimit(skip, 30), skip, skip.unwrapped], 7)
    [30, None, 7]
    """
    out: list[int | None] = []
    for env in envs:
        places = limit_places(env)
        out.append(fallback if places.counted is None and places.under is None else places.counted)
    return out


def unread_limits(
    vector_class: str, envs: Iterable[Any] | None, reset_by: str, instead: str
) -> dict[str, str]:
    """The layout entries saying why streams cannot read every sub-env's ``TimeLimit`` (or none).

    ``envs``: the sub-envs whose steps the streams count, ``None`` when they ran in the workers
    of ``vector_class``, which answer for the outermost ``TimeLimit`` only
    (:func:`~episode_audit.format.wrappers.worker_limits`). Else one under a multi-step wrapper
    counts the env's own steps, which the stream does not, and the reset inside a step
    (``reset_by``) zeroes its count before the recorder could read it (:class:`LimitPlaces`
    ``under``). ``instead``: how to record so that it can. Each cause is said as text
    (:data:`~episode_audit.format.wrappers.LAYOUT_UNREAD_LIMITS`) and as its code
    (:data:`~episode_audit.format.wrappers.LAYOUT_UNREAD_CAUSE`).
    """
    if envs is None:
        return {
            LAYOUT_UNREAD_LIMITS: worker_limits(vector_class),
            LAYOUT_UNREAD_CAUSE: UNREAD_IN_WORKERS,
        }
    for env in envs:
        under = limit_places(env).under
        if under is not None:
            why = (
                f"a sub-env's TimeLimit under {under} counts the env's own steps, and "
                f"{reset_by} zeroed its count before the recorder read it: its truncations are "
                f"recorded external; {instead} to replay such endings"
            )
            return {LAYOUT_UNREAD_LIMITS: why, LAYOUT_UNREAD_CAUSE: UNREAD_ZEROED}
    return {}


def _spec_wrappers(env: Any) -> int | None:
    """How many wrappers ``env``'s spec records (``additional_wrappers``), or ``None``."""
    try:
        return len(env.spec.additional_wrappers)
    except Exception:  # no spec, or one that cannot be read
        return None


def limited_spec(spec: EnvSpec | None, env: Any) -> EnvSpec | None:
    """``spec`` with the ``TimeLimit``s around ``env`` each where ``gym.make`` rebuilds it.

    Gymnasium's spec of a chain names the outermost ``TimeLimit``'s limit only, and
    ``gym.make`` puts it right over the env. The file's spec has as its ``max_episode_steps``
    the smallest limit of those that count the env's own steps (:class:`LimitPlaces`
    ``inner``; ``None`` when every one is over a multi-step wrapper), and each of the others as
    a ``TimeLimit`` among its ``additional_wrappers``, where it was. A chain without a
    ``TimeLimit`` found in it keeps the spec's own limit; one whose placed ``TimeLimit``'s spec
    cannot be read has the smallest of all as its limit.

    >>> import gymnasium as gym
    >>> env = gym.wrappers.TimeLimit(gym.make("CartPole-v1"), 800)
    >>> env.spec.max_episode_steps, limited_spec(env.spec, env).max_episode_steps
    (800, 500)
    >>> skip = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1"), skip=4)
    >>> spec = limited_spec(skip.spec, gym.wrappers.TimeLimit(skip, 30))
    >>> spec.max_episode_steps, [(w.name, w.kwargs) for w in spec.additional_wrappers]
    (200, [('MaxAndSkipObservation', {'skip': 4}), ('TimeLimit', {'max_episode_steps': 30})])
    """
    places = limit_places(env)
    if spec is None or not places.found:
        return spec
    if any(n is None for n, _ in places.placed):
        limit = step_limit(env)
        if limit is None or spec.max_episode_steps == limit:
            return spec
        return dataclasses.replace(spec, max_episode_steps=limit)
    if not places.placed:
        if places.inner is None or spec.max_episode_steps == places.inner:
            return spec
        return dataclasses.replace(spec, max_episode_steps=places.inner)
    wrappers = list(spec.additional_wrappers)
    for n, limit in places.placed[::-1]:  # (outermost first: an index counts those under it)
        assert n is not None
        entry = WrapperSpec("TimeLimit", _TIME_LIMIT, {"max_episode_steps": limit})
        wrappers.insert(min(n, len(wrappers)), entry)
    return dataclasses.replace(
        spec, max_episode_steps=places.inner, additional_wrappers=tuple(wrappers)
    )


_TIME_LIMIT = f"{TimeLimit.__module__}:{TimeLimit.__name__}"
"""The entry point of Gymnasium's ``TimeLimit`` (``gymnasium.wrappers.common:TimeLimit``)."""


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
