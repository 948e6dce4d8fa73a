"""Where reward terms, success, failure labels and truncation reasons come from.

:class:`RewardTerms` says how a step's named reward terms are read from ``info``;
:class:`EndingRules` turns a final step's ``terminated`` / ``truncated`` / ``info`` into one
outcome of the taxonomy (``success``, ``failure``, ``truncated``; ``incomplete`` and ``error``
are decided by the recorder).

>>> RewardTerms().extract({"reward_dist": -0.2, "reward_ctrl": -0.1, "x": 3})
{'reward_dist': -0.2, 'reward_ctrl': -0.1}
>>> EndingRules().classify(True, False, {"success": True}, time_limit_hit=False)
Ending(outcome='success', failure_label=None, truncation_reason=None)
>>> EndingRules().classify(False, True, {}, time_limit_hit=True)
Ending(outcome='truncated', failure_label=None, truncation_reason='time_limit')
"""

from __future__ import annotations

import math
import operator
from array import array
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

from . import format as fmt
from .columns import PLAIN_NUMBERS, error_text, text
from .errors import ConfigurationError

__all__ = [
    "Ending",
    "EndingRules",
    "RewardTerms",
    "find_time_limit",
    "plain_time_limit",
    "time_limit_hit",
]

TermsFn = Callable[[Mapping[str, Any]], Mapping[str, float] | None]


@dataclass(frozen=True)
class RewardTerms:
    """How the named reward terms of a step are found in its ``info``.

    ``source`` is one of:

    - ``"auto"`` (default): ``info["reward_terms"]`` when it is a mapping, else every
      ``info["reward_*"]`` key (Gymnasium MuJoCo v5 style), else no terms;
    - a sequence of info keys, e.g. ``("reward_forward", "reward_ctrl")``;
    - a callable ``info -> {name: value}``;
    - ``None``: record no terms.

    ``constants`` declares terms an environment adds outside its info (e.g. a constant survival
    bonus): ``check`` adds them to every step's terms sum; they are not written per step.
    """

    source: str | Sequence[str] | TermsFn | None = "auto"
    constants: Mapping[str, float] = field(default_factory=dict)
    prefix: str = "reward_"
    dict_key: str = "reward_terms"

    def __post_init__(self) -> None:
        src = self.source
        if isinstance(src, str) and src != "auto":
            raise ConfigurationError(
                f"reward terms source: expected 'auto', a list of info keys, a callable or None, "
                f"actually: {src!r}"
            )
        for name, value in self.constants.items():
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigurationError(
                    f"constant reward term {name!r}: expected a finite number, actually: {value!r}"
                )

    def extract(self, info: Mapping[str, Any]) -> dict[str, Any] | None:
        """Return the step's terms (values not yet validated), or ``None`` when it has none."""
        return self.extractor(info)

    def extract_many(
        self, infos: Sequence[Mapping[str, Any]]
    ) -> tuple[tuple[str, ...], np.ndarray[Any, np.dtype[np.float64]]] | None:
        """The terms of many steps at once: ``(names, values)``, a float64 row per step.

        Only when :meth:`extract` would give every step the same names in the same order,
        each value a plain number; ``None`` otherwise (then ask :meth:`extract` step by step).

        >>> names, values = RewardTerms().extract_many([{"reward_a": 1.0}, {"reward_a": 2}])
        >>> names, values.tolist()
        (('reward_a',), [[1.0], [2.0]])
        """
        if not infos or self.source is None:
            return None
        key_sets = set(map(tuple, infos))
        if len(key_sets) != 1:
            return None
        (keys,) = key_sets
        names = self.names_for(keys)
        if not names:
            return None
        values = np.empty((len(names), len(infos)), dtype=np.float64)
        for i, name in enumerate(names):  # column by column: no tuple per step
            column = list(map(operator.itemgetter(name), infos))
            if not set(map(type, column)) <= PLAIN_NUMBERS:
                return None
            values[i] = array("d", column)
        return names, values.T

    def names_for(self, keys: tuple[Any, ...]) -> tuple[str, ...] | None:
        """The names :meth:`extract` reads from an info whose keys are ``keys`` (in order).

        ``()`` when such an info has no terms; ``None`` when only :meth:`extract` can tell
        (a callable source, or a ``reward_terms`` dict in the info). The recorder asks once per
        key tuple, then reads every step's terms with one ``itemgetter``.

        >>> RewardTerms().names_for(("reward_dist", "x", "reward_ctrl"))
        ('reward_dist', 'reward_ctrl')
        >>> RewardTerms(["b", "a"]).names_for(("a", "b", "c")), RewardTerms().names_for(("x",))
        (('b', 'a'), ())
        >>> RewardTerms().names_for(("reward_terms",)) is None
        True
        """
        src = self.source
        if src is None:
            return ()
        if callable(src) and not isinstance(src, str):
            return None
        if src == "auto":
            return None if self.dict_key in keys else _prefixed(keys, self.prefix)
        present = set(keys)
        return tuple(dict.fromkeys(k for k in src if k in present))  # as extract(): once each

    @property
    def extractor(self) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
        """:meth:`extract` as a plain function, for the per-step paths (built once)."""
        built: Callable[[Mapping[str, Any]], dict[str, Any] | None] | None = self.__dict__.get(
            "_extractor"
        )
        if built is None:
            built = self._build_extractor()
            object.__setattr__(self, "_extractor", built)  # frozen: a cache, not state
        return built

    def _build_extractor(self) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
        src = self.source
        if src == "auto":
            return _auto_terms(self.dict_key, self.prefix)
        if src is None:
            return lambda info: None
        if callable(src):
            fn = src

            def from_callable(info: Mapping[str, Any]) -> dict[str, Any] | None:
                out = fn(info)
                return None if out is None else dict(out)

            return from_callable
        keys = tuple(src)
        return lambda info: {k: info[k] for k in keys if k in info} or None

    def describe(self) -> dict[str, Any]:
        """A JSON-able description for the run metadata."""
        src = self.source
        if callable(src) and not isinstance(src, str):
            kind: Any = f"callable:{getattr(src, '__qualname__', type(src).__name__)}"
        elif src is None or isinstance(src, str):
            kind = src
        else:
            kind = list(src)
        return {"source": kind, "constants": dict(self.constants)}


def _prefixed(keys: Sequence[Any], prefix: str) -> tuple[str, ...]:
    """The keys that are names starting with ``prefix``, in order."""
    return tuple(k for k in keys if isinstance(k, str) and k.startswith(prefix))


def _auto_terms(dict_key: str, prefix: str) -> Callable[[Mapping[str, Any]], dict[str, Any] | None]:
    """The ``"auto"`` rule: ``info[dict_key]`` if it is there, else the ``prefix*`` keys.

    Which keys carry the prefix is remembered per key tuple (envs return the same keys step
    after step), so a step costs a tuple and a lookup, not a scan of every key.
    """
    names_of: dict[tuple[Any, ...], tuple[str, ...]] = {}

    def extract(info: Mapping[str, Any]) -> dict[str, Any] | None:
        terms = info.get(dict_key)
        if terms is not None:
            return dict(terms)
        if not info:
            return None
        keys = tuple(info)
        names = names_of.get(keys)
        if names is None:
            names = _prefixed(keys, prefix)
            if len(names_of) < 64:  # bounded: an env with ever-new keys is scanned each time
                names_of[keys] = names
        return {k: info[k] for k in names} if names else None

    return extract


class Ending(NamedTuple):
    """The outcome of an episode that ended by ``terminated`` or ``truncated``."""

    outcome: str
    failure_label: str | None
    truncation_reason: str | None


SuccessFn = Callable[[Mapping[str, Any]], bool]
FailureFn = Callable[[Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class EndingRules:
    """How success, failure labels and truncation reasons are read from the final ``info``.

    Defaults follow the conventions of SB3 and Gymnasium-Robotics: ``info["success"]`` or
    ``info["is_success"]`` for success, ``info["failure"]`` for a failure label (a string; any
    other truthy value means a failure without a label), ``info["truncation_reason"]`` for an
    env-given truncation reason. ``success_fn`` / ``failure_fn`` replace the key lookups.

    A terminated episode is a ``success`` when the success predicate holds, else a ``failure``
    (``unlabeled`` when no label is given). A truncated, not terminated, episode is
    ``truncated`` with the env-given reason, else ``time_limit`` when Gymnasium's TimeLimit
    fired, else ``external``. When both flags are set, the task ending counts and the
    truncation reason is kept beside it.
    """

    success_keys: Sequence[str] = ("success", "is_success")
    failure_key: str = "failure"
    truncation_reason_key: str = "truncation_reason"
    success_fn: SuccessFn | None = None
    failure_fn: FailureFn | None = None

    def is_success(self, info: Mapping[str, Any]) -> bool:
        """Whether the success predicate holds for this final ``info``."""
        if self.success_fn is not None:
            return bool(self.success_fn(info))
        for key in self.success_keys:
            value = info.get(key)
            if value is not None:
                return bool(value)
        return False

    def failure_label(self, info: Mapping[str, Any]) -> str:
        """The failure label of a terminal failure (``unlabeled`` when none is given)."""
        if self.failure_fn is not None:
            label = self.failure_fn(info)
        else:
            label = info.get(self.failure_key)
        if isinstance(label, str) and label:
            return text(label)
        return fmt.UNLABELED

    def truncation_reason(self, info: Mapping[str, Any], *, time_limit_hit: bool) -> str:
        """The reason a truncated episode was cut off."""
        reason = info.get(self.truncation_reason_key)
        if isinstance(reason, str) and reason:
            return text(reason)
        return fmt.REASON_TIME_LIMIT if time_limit_hit else fmt.REASON_EXTERNAL

    def classify(
        self, terminated: bool, truncated: bool, info: Mapping[str, Any], *, time_limit_hit: bool
    ) -> Ending:
        """Classify a final step (at least one of the flags must be set)."""
        reason = self.truncation_reason(info, time_limit_hit=time_limit_hit) if truncated else None
        if terminated:
            if self.is_success(info):
                return Ending(fmt.OUTCOME_SUCCESS, None, reason)
            return Ending(fmt.OUTCOME_FAILURE, self.failure_label(info), reason)
        if truncated:
            return Ending(fmt.OUTCOME_TRUNCATED, None, reason)
        raise ConfigurationError("classify() needs terminated or truncated to be set")

    def classify_or_note(
        self, terminated: bool, truncated: bool, info: Any, *, time_limit_hit: bool
    ) -> tuple[Ending, str | None]:
        """:meth:`classify` and ``None``, or the ending by the flags alone and why.

        The second is for a final ``info`` that cannot be read: not a mapping, a success
        value whose truth is ambiguous, a ``success_fn`` that raises.

        The recorder and replay both classify this way, so neither raises over an env's info.

        >>> import numpy as np
        >>> ending, why = EndingRules().classify_or_note(
        ...     True, False, {"success": np.ones(2)}, time_limit_hit=False
        ... )
        >>> ending.outcome, ending.failure_label, why[:40]
        ('failure', 'unlabeled', 'ValueError: The truth value of an array ')
        """
        try:
            if not isinstance(info, Mapping):
                raise TypeError(f"info is a {type(info).__name__}, not a dict")
            return self.classify(terminated, truncated, info, time_limit_hit=time_limit_hit), None
        except Exception as exc:
            why = error_text(exc)
        # by the flags alone: the default rules over an empty info (no user functions)
        return _BY_FLAGS.classify(terminated, truncated, {}, time_limit_hit=time_limit_hit), why

    def describe(self) -> dict[str, Any]:
        """A JSON-able description for the run metadata."""
        return {
            "success_keys": list(self.success_keys),
            "failure_key": self.failure_key,
            "truncation_reason_key": self.truncation_reason_key,
            "success_fn": _fn_name(self.success_fn),
            "failure_fn": _fn_name(self.failure_fn),
        }


_BY_FLAGS = EndingRules()
"""Rules that read nothing from an info: with an empty one, the ending the flags alone give."""


def _fn_name(fn: Callable[..., Any] | None) -> str | None:
    return None if fn is None else getattr(fn, "__qualname__", type(fn).__name__)


def find_time_limit(env: Any) -> TimeLimit[Any, Any] | None:
    """The outermost Gymnasium ``TimeLimit`` wrapper around ``env``, if any."""
    current = env
    while isinstance(current, gym.Wrapper):
        if isinstance(current, TimeLimit):
            return current
        current = current.env
    return None


def plain_time_limit(env: Any) -> tuple[Any, int] | None:
    """``(inner env, max_episode_steps)`` when ``env`` is exactly Gymnasium's ``TimeLimit``.

    Its reset only zeroes a counter, and its step only counts and sets ``truncated`` on the
    ``max_episode_steps``-th step: a loop that resets and steps the inner env and counts the
    same way gets what the wrapper returns, without a wrapper call per step. A subclass may
    do more, so only the class itself qualifies.

    >>> import gymnasium as gym
    >>> inner, limit = plain_time_limit(gym.make("CartPole-v1", disable_env_checker=True))
    >>> type(inner).__name__, limit
    ('OrderEnforcing', 500)
    >>> plain_time_limit(gym.make("CartPole-v1").unwrapped) is None
    True
    """
    if type(env) is not TimeLimit:
        return None
    limit = getattr(env, "_max_episode_steps", None)
    if type(limit) is not int or limit <= 0:
        return None
    return env.env, limit


def time_limit_hit(time_limit: TimeLimit[Any, Any] | None) -> bool:
    """Whether ``time_limit`` has reached its maximum number of steps in this episode."""
    if time_limit is None:
        return False
    elapsed = getattr(time_limit, "_elapsed_steps", None)
    limit = getattr(time_limit, "_max_episode_steps", None)
    return elapsed is not None and limit is not None and elapsed >= limit
