"""What a vector env's worker processes can be asked without ending them.

A worker of Gymnasium's ``AsyncVectorEnv`` or SB3's ``SubprocVecEnv`` asked for an attribute
ends when reading it raises or its value does not pickle (the worker sends it pickled), and the
user's loop dies with it. Sub-envs with :class:`~.rng.ResetRngInfo` outermost answer safely
through it; for the others the recorder asks only when it knows the answer is safe:

- :func:`rng_unaskable` — for an ``AsyncVectorEnv``, from a sub-env built in this process by
  the same env function: ``np_random`` is asked for only when every class in its chain keeps
  Gymnasium's own ``np_random`` and attribute lookup (the answer is then the generator
  ``reset(seed=...)`` made, which pickles), and when that sub-env's ``np_random`` pickles, as
  built and after a seeded reset (a class may put an object of its own in Gymnasium's private
  ``_np_random``). One that puts it there only later (at a step, at an unseeded reset) is not
  seen: such a sub-env needs :class:`~.rng.ResetRngInfo` (docs/recording.md).
- :func:`unsendable` — for an SB3 ``VecEnv``, asked of the workers: SB3's ``env_is_wrapped``
  walks a worker's wrappers calling ``isinstance(wrapper, cls)`` and sends a bool; the classes
  here (:class:`Answering`, :class:`SpecUnsendable`, :class:`RngUnsendable`) answer that
  ``isinstance`` in the worker by reading the attribute there and trying to pickle it.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym

from ..._jobs import unpicklable

__all__ = ["Answering", "RngUnsendable", "SpecUnsendable", "rng_unaskable", "unsendable"]

_LOOKUPS = ("np_random", "get_wrapper_attr", "has_wrapper_attr", "__getattr__", "__getattribute__")
"""What a worker runs to answer ``np_random``: a class replacing any of them runs its own code."""


def _replaced(cls: type, base: type) -> str | None:
    """The first of :data:`_LOOKUPS` that ``cls`` defines otherwise than ``base``, if any."""
    for name in _LOOKUPS:
        if inspect.getattr_static(cls, name, None) is not inspect.getattr_static(base, name, None):
            return name
    return None


def rng_unaskable(env: Any) -> str | None:
    """Why a worker's sub-env like ``env`` could end if asked for ``np_random``; else ``None``.

    ``env``: a sub-env built in this process by the worker's env function (``None``: none
    could be). Read off the classes of its chain, outermost first: each wrapper must keep
    ``gymnasium.Wrapper``'s ``np_random`` and attribute lookup, and the env
    ``gymnasium.Env``'s.

    >>> import gymnasium as gym
    >>> rng_unaskable(gym.make("CartPole-v1")) is None
    True
    >>> rng_unaskable(None)
    'no sub-env could be built here to look at its classes'
    """
    if env is None:
        return "no sub-env could be built here to look at its classes"
    top = env
    try:
        chain: list[tuple[type, type]] = []
        while isinstance(env, gym.Wrapper):
            chain.append((type(env), gym.Wrapper))
            env = env.env
        chain.append((type(env), gym.Env))
        why = _unaskable_classes(chain)
    except Exception:  # (a class's own attribute machinery): unknown
        return "its classes cannot be looked at here"
    return why if why is not None else _unsendable_rng(top)


def _unsendable_rng(env: Any) -> str | None:
    """Why ``env``'s ``np_random`` would not reach this process from a worker; else ``None``.

    Read as a worker reads it (``get_wrapper_attr``), once as built and once after a seeded
    reset (an env may put its own object in Gymnasium's private ``_np_random`` in either), and
    pickled and read back as its pipe does. The reset's warnings (Gymnasium's env checker) are the
    worker's to give, not repeated here.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for reset in (False, True):
                if reset:
                    env.reset(seed=0)
                why = unpicklable(env.get_wrapper_attr("np_random"), back=True)
                if why is not None:
                    return f"its np_random does not pickle ({why:.60})"
    except Exception as exc:  # (the env's own code): unknown
        return f"reading its np_random after a reset here raised {type(exc).__name__}"
    return None


def _unaskable_classes(chain: list[tuple[type, type]]) -> str | None:
    """:func:`rng_unaskable` of a sub-env's classes, each with the Gymnasium class it must keep."""
    for cls, base in chain:
        if not issubclass(cls, base):
            return f"{cls.__name__:.60} is not a {base.__name__}"
        name = _replaced(cls, base)
        if name is not None:
            return f"{cls.__name__:.60} replaces Gymnasium's {name}"
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
