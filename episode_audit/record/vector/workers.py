"""What a vector env's worker processes can be asked without ending them.

A worker of Gymnasium's ``AsyncVectorEnv`` or SB3's ``SubprocVecEnv`` asked for an attribute
ends when reading it raises or its value does not pickle (the worker sends it pickled), and the
user's loop dies with it. Sub-envs with :class:`~.rng.ResetRngInfo` outermost answer safely
through it; for the others the recorder asks only when it knows the answer is safe:

- :func:`rng_unaskable` — for an ``AsyncVectorEnv``, from the sub-env's spec, read in this
  process: ``np_random`` is asked for only when the spec names every class in the sub-env and
  each keeps Gymnasium's own ``np_random`` and attribute lookup, and the env is one of
  Gymnasium's own (whose generator is always one ``seeding.np_random`` made, which pickles).
- :func:`unsendable` — for an SB3 ``VecEnv``, asked of the workers: SB3's ``env_is_wrapped``
  walks a worker's wrappers calling ``isinstance(wrapper, cls)`` and sends a bool; the classes
  here (:class:`Answering`, :class:`SpecUnsendable`, :class:`RngUnsendable`) answer that
  ``isinstance`` in the worker by reading the attribute there and trying to pickle it.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator

from ..._jobs import unpicklable

__all__ = ["Answering", "RngUnsendable", "SpecUnsendable", "rng_unaskable", "unsendable"]

_LOOKUPS = ("np_random", "get_wrapper_attr", "has_wrapper_attr", "__getattr__", "__getattribute__")
"""What a worker runs to answer ``np_random``: a class replacing any of them runs its own code."""

_GYMNASIUM_ENVS = "gymnasium.envs."


def _loaded(entry_point: Any) -> Any:
    return load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point


def _replaced(cls: type, base: type) -> str | None:
    """The first of :data:`_LOOKUPS` that ``cls`` defines otherwise than ``base``, if any."""
    for name in _LOOKUPS:
        if inspect.getattr_static(cls, name, None) is not inspect.getattr_static(base, name, None):
            return name
    return None


def rng_unaskable(spec: Any) -> str | None:
    """Why a worker's sub-env made by ``spec`` could end if asked for ``np_random``; else ``None``.

    Read in this process from the classes the spec names (its entry point, its
    ``additional_wrappers``; those ``gym.make`` adds are Gymnasium's): each must keep
    Gymnasium's ``np_random`` and attribute lookup, and the env must be one of Gymnasium's own.
    A class of one's own may put anything in ``np_random`` (a generator holding a lock).

    >>> import gymnasium as gym
    >>> rng_unaskable(gym.spec("CartPole-v1")) is None
    True
    >>> rng_unaskable(None)
    'its spec is unknown'
    """
    if spec is None:
        return "its spec is unknown"
    try:
        env = _loaded(spec.entry_point)
        wrappers = [_loaded(w.entry_point) for w in spec.additional_wrappers or ()]
    except Exception:
        return "a class its spec names cannot be loaded here"
    try:
        return _unaskable_classes(env, wrappers)
    except Exception:  # (a class's own attribute machinery): unknown
        return "its classes cannot be looked at here"


def _unaskable_classes(env: Any, wrappers: list[Any]) -> str | None:
    """:func:`rng_unaskable` of an env class and its wrapper classes (innermost first)."""
    if not (isinstance(env, type) and issubclass(env, gym.Env)):
        return "its spec's entry point is not a gymnasium.Env class"
    if not env.__module__.startswith(_GYMNASIUM_ENVS):
        return f"{env.__name__} is not one of Gymnasium's own envs"
    for cls, base in [(env, gym.Env), *((w, gym.Wrapper) for w in wrappers)]:
        if not (isinstance(cls, type) and issubclass(cls, base)):
            return f"{getattr(cls, '__name__', cls)!s:.60} is not a {base.__name__} class"
        name = _replaced(cls, base)
        if name is not None:
            return f"{cls.__name__} replaces Gymnasium's {name}"
    return None


class _Probe(type):
    """The metaclass whose ``isinstance`` runs in a worker (SB3's ``env_is_wrapped``)."""

    attribute: str | None

    def __instancecheck__(cls, instance: Any) -> bool:
        name = cls.attribute
        if name is None:
            return True
        try:
            value = instance.get_wrapper_attr(name)
        except Exception:
            return True
        return unpicklable(value) is not None


class Answering(metaclass=_Probe):
    """Every wrapper is one: a worker saying so runs the probes' ``isinstance``."""

    attribute: ClassVar[str | None] = None


class SpecUnsendable(metaclass=_Probe):
    """A wrapper whose ``spec`` raises or does not pickle."""

    attribute: ClassVar[str | None] = "spec"


class RngUnsendable(metaclass=_Probe):
    """A wrapper whose ``np_random`` raises or does not pickle."""

    attribute: ClassVar[str | None] = "np_random"


def unsendable(base: Any, probe: type, indices: Sequence[int]) -> dict[int, str | None]:
    """Why each sub-env ``indices`` of SB3 VecEnv ``base`` may not be asked for an attribute.

    ``None`` when its worker can send ``probe``'s attribute (a sub-env's ``spec`` for
    :class:`SpecUnsendable`, its ``np_random`` for :class:`RngUnsendable`).
    Asked with ``env_is_wrapped``, whose answer is a bool per worker: whether the probes ran
    (:class:`Answering`; not for a sub-env without wrappers, nor a VecEnv that answers
    otherwise), then whether any wrapper's attribute raised or did not pickle.
    """
    ask = list(indices)
    try:
        answering = list(base.env_is_wrapped(Answering, indices=ask))
        failing = list(base.env_is_wrapped(probe, indices=ask))
        if not len(answering) == len(failing) == len(ask):
            raise ValueError("an answer per sub-env")
    except Exception as exc:
        return dict.fromkeys(ask, f"asking its worker first raised {type(exc).__name__}")
    out: dict[int, str | None] = {}
    for i, says, fails in zip(ask, answering, failing, strict=True):
        if says is not True:
            out[i] = "no wrapper in it answers whether it can be sent"
        elif fails is not False:
            out[i] = "reading it raises or it does not pickle"
        else:
            out[i] = None
    return out
