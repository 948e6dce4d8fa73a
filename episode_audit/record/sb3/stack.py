"""What an SB3 ``VecEnv`` stack is made of, as the recorder needs it.

:class:`VecStack` finds the base VecEnv under the VecEnv wrappers the recorder wraps, which
of those change what a sub-env returns (then the file cannot be replayed one sub-env at a time),
where the sub-envs are (in this process: ``DummyVecEnv``; in workers: ``SubprocVecEnv``), one
sub-env's spec and each sub-env's step limit. Asking a worker for an attribute its env lacks
ends the worker, so an attribute is read from workers only after ``has_attr`` says it is there.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    VecCheckNan,
    VecEnv,
    VecEnvWrapper,
    VecMonitor,
    VecNormalize,
    VecVideoRecorder,
)

from ...format.wrappers import REWARD_CHANGING
from ..gym import entry_point, info_entry_point
from ..time_limits import counted_limits, limited_spec, unread_limits
from ..vector.recorder import sub_reward_wrappers, sub_wrappers
from ..vector.rng import REWARD_WRAPPERS, SPEC_IF_SENDABLE, ResetRngInfo
from ..vector.workers import SpecUnsendable, unsendable

__all__ = ["TRANSPARENT", "VecStack"]

TRANSPARENT: tuple[type[VecEnvWrapper], ...] = (VecMonitor, VecCheckNan, VecVideoRecorder)
"""VecEnv wrappers that never change a step (``VecNormalize`` too while it normalizes nothing)."""


def _changes_steps(wrapper: VecEnvWrapper) -> bool:
    if isinstance(wrapper, VecNormalize):
        return bool(wrapper.norm_obs or wrapper.norm_reward)
    return not isinstance(wrapper, TRANSPARENT)


class VecStack:
    """The VecEnv stack under a recorder: its base, its wrappers, its sub-envs.

    Args:
        venv: The VecEnv the recorder wraps.
    """

    def __init__(self, venv: VecEnv) -> None:
        wrappers: list[VecEnvWrapper] = []
        env: Any = venv
        while isinstance(env, VecEnvWrapper):
            wrappers.append(env)
            env = env.venv
        self.base: VecEnv = env
        """The VecEnv under every wrapper (whose sub-envs step)."""
        self.wrappers = [type(w).__name__ for w in wrappers]
        """The class names of the wrappers between the recorder and the base, outermost first."""
        self.changing = [type(w).__name__ for w in wrappers if _changes_steps(w)]
        """Those of them that change observations, rewards or spaces."""
        self.rewards = [
            entry_point(w) for w in wrappers[::-1] if isinstance(w, VecNormalize) and w.norm_reward
        ]
        """The entry points of those of them that change the reward, innermost first."""
        self._normalizers = [w for w in wrappers if isinstance(w, VecNormalize) and w.norm_obs]
        """The ``VecNormalize`` wrappers that normalise observations, outermost first."""
        self.local = env if isinstance(env, DummyVecEnv) else None
        """The base if its sub-envs live in this process (``DummyVecEnv``)."""
        self.direct = not wrappers
        """Whether the recorder wraps the base itself."""
        self._asked: list[str] | None = None  # (the workers' reward wrappers, once asked)

    def notes(self) -> list[str]:
        """Run notes on the stack: the wrappers under the recorder, and what they change."""
        if not self.wrappers:
            return []
        out = [
            f"the recorder sits over {', '.join(self.wrappers)} (outermost first), "
            f"over {type(self.base).__name__}"
        ]
        if self.changing:
            out.append(self.replay_note())
        if self._normalizers:
            clip = max(float(w.clip_obs) for w in self._normalizers)
            out.append(
                "VecNormalize normalises the observations and keeps the env's observation "
                f"space: the space recorded is its range, [-{clip:g}, {clip:g}], float32"
            )
        return out

    def observation_space(self, space: gym.Space[Any]) -> gym.Space[Any]:
        """The space of the observations the recorder receives, declared ``space`` or not.

        ``VecNormalize`` (normalising observations) keeps the env's ``observation_space`` while
        returning float32 values clipped to ``±clip_obs``: the Box it normalises (each Box of a
        Dict among its ``norm_obs_keys``) becomes that range, as Gymnasium's
        ``NormalizeObservation`` widens its space, so that ``check`` does not blame the env for
        values the env never returned.
        """
        if not self._normalizers:
            return space
        clip = max(float(w.clip_obs) for w in self._normalizers)
        keys = self._normalizers[0].norm_obs_keys
        if isinstance(space, gym.spaces.Dict):
            return gym.spaces.Dict(
                {
                    k: _clipped_box(s, clip) if keys is None or k in keys else s
                    for k, s in space.spaces.items()
                }
            )
        return _clipped_box(space, clip)

    def replay_note(self) -> str:
        """Why the file's episodes cannot be replayed on their own (wrappers that change steps)."""
        return (
            f"{', '.join(self.changing)} under the recorder changed what the sub-envs returned "
            "(observations, rewards or spaces): one sub-env cannot replay it; record with "
            "RecordVecEnvEvidence directly over the DummyVecEnv / SubprocVecEnv, under "
            "those wrappers"
        )

    def reward_wrappers(self, spec: Any) -> list[str]:
        """The wrappers that change the reward under the recorder, innermost first.

        A sub-env's, then the VecEnv wrappers' (``VecNormalize``). A sub-env's are walked in
        this process, else named by its ``spec`` (:func:`~..vector.recorder.sub_reward_wrappers`);
        when the spec names none (or is unknown), the workers are asked which reward-changing
        wrapper classes their sub-envs have (:func:`worker_reward_wrappers`).
        """
        inner = sub_reward_wrappers(self.local, spec)
        if not inner and self.local is None:
            inner = self._asked_reward_wrappers()
        return inner + self.rewards

    def sub_wrappers(self, spec: Any) -> list[str]:
        """The entry points of a sub-env's wrappers, as far as they are known.

        Walked in this process, else named by its ``spec``
        (:func:`~..vector.recorder.sub_wrappers`); when the spec names no reward-changing
        wrapper (or is unknown), with those the workers say their sub-envs have
        (:func:`worker_reward_wrappers`, their order unknown), so a ``NormalizeReward`` in a
        worker is warned of as one the spec names is.
        """
        known = sub_wrappers(self.local, spec)
        if self.local is None and not sub_reward_wrappers(None, spec):
            known += self._asked_reward_wrappers()
        return known

    def _asked_reward_wrappers(self) -> list[str]:
        """:func:`worker_reward_wrappers` of the base, asked once."""
        if self._asked is None:
            self._asked = worker_reward_wrappers(self.base)
        return list(self._asked)

    def info_of(self) -> str:
        """The entry point of the object whose infos the recorder reads the terms from."""
        if self.local is not None and self.local.envs:
            return info_entry_point(self.local.envs[0])
        return entry_point(self.base)

    def sub_env_spec(self) -> Any:
        """One sub-env's spec (what replay rebuilds), or ``None``."""
        try:
            if self.local is not None:
                return limited_spec(self.local.envs[0].spec, self.local.envs[0])
            return worker_spec(self.base)
        except Exception:
            return None

    def unread_limits(self) -> dict[str, str]:
        """The layout entries saying why the streams cannot read every sub-env's ``TimeLimit``.

        A ``SubprocVecEnv``'s workers (any base without sub-envs in this process) answer for the
        outermost only, and a ``DummyVecEnv`` resets a sub-env inside the step that ended its
        episode, zeroing the counts (a stream counting the steps misses one under a frame skip).
        """
        return unread_limits(
            type(self.base).__name__,
            None if self.local is None else self.local.envs,
            "DummyVecEnv's reset inside its step",
            "record a gymnasium SyncVectorEnv in NextStep mode",
        )

    def step_limits(self, n: int, spec: Any) -> list[int | None]:
        """Each sub-env's step limit in its own steps, for its stream to count.

        A ``DummyVecEnv``'s sub-envs are searched for their ``TimeLimit``s
        (:func:`~..time_limits.counted_limits`: the smallest of those over no multi-step
        wrapper, none when each is under one, the spec's when there is none). A
        ``SubprocVecEnv``'s workers are asked for the outermost's (a worker's chain cannot be
        walked), else the spec's.
        """
        limits: list[int | None] = [getattr(spec, "max_episode_steps", None)] * n
        found: list[Any] = []
        try:
            if self.local is not None:
                return counted_limits(self.local.envs, limits[0])[:n]
            if self.base.has_attr("_max_episode_steps"):
                found = list(self.base.get_attr("_max_episode_steps"))
        except Exception:  # the spec's limit, then
            found = []
        for i, limit in enumerate(found[:n]):
            if isinstance(limit, (int, np.integer)) and not isinstance(limit, bool):
                limits[i] = int(limit)
        return limits


def _clipped_box(space: gym.Space[Any], clip: float) -> gym.Space[Any]:
    """A float32 Box of ``space``'s shape within ``±clip`` (``space`` itself if not a Box)."""
    if not isinstance(space, gym.spaces.Box):
        return space
    return gym.spaces.Box(-clip, clip, space.shape, np.float32)


_REWARD_KINDS: tuple[type[gym.Wrapper[Any, Any, Any, Any]], ...] = (
    gym.RewardWrapper,
    *(
        getattr(gym.wrappers, name)
        for name in sorted(REWARD_CHANGING)
        if hasattr(gym.wrappers, name)
    ),
)
"""The Gymnasium wrapper classes that change the reward (``RewardWrapper``, and those
:data:`~episode_audit.format.wrappers.REWARD_CHANGING` names): what workers are asked about."""


def worker_reward_wrappers(base: VecEnv) -> list[str]:
    """The entry points of the reward-changing wrappers of ``base``'s sub-envs, as known.

    With :class:`~..vector.rng.ResetRngInfo` outermost in sub-env 0, it names them, innermost
    first (:data:`~..vector.rng.REWARD_WRAPPERS`). Otherwise asked with SB3's
    ``env_is_wrapped`` (a walk of each worker's chain giving a bool: never an object, which a
    worker that cannot pickle it dies of): the :data:`_REWARD_KINDS` any sub-env is wrapped in.
    A class found stands for its bases (``ClipReward`` is a ``TransformReward``, each a
    ``RewardWrapper``); their order in the chain is unknown. None when the workers cannot be
    asked.
    """
    try:
        if _rng_info_outermost(base):
            return [str(w) for w in base.env_method(REWARD_WRAPPERS, indices=[0])[0]]
        found = [kind for kind in _REWARD_KINDS if any(base.env_is_wrapped(kind))]
    except Exception:  # a VecEnv that cannot say: none known
        return []
    found = [k for k in found if not any(o is not k and issubclass(o, k) for o in found)]
    return [f"{k.__module__}:{k.__qualname__}" for k in found]


def worker_spec(base: VecEnv) -> Any:
    """Sub-env 0's spec, asked of a worker only when it can send it; else ``None``.

    A ``SubprocVecEnv``'s worker that fails in answering (it cannot pickle a lambda among the
    env's ``make()`` kwargs or a wrapper's, ``TransformObservation(env, lambda o: ...)``, or
    reading the spec raises) ends, breaking the VecEnv. So it is asked first what it answers
    safely (SB3's ``env_is_wrapped``, a bool). Outermost in the sub-env,
    :class:`~..vector.rng.ResetRngInfo` says whether the spec pickles (``episode_audit_spec``);
    else the wrappers say it in the worker (:func:`~..vector.workers.unsendable`: a sub-env
    without wrappers is not asked).
    """
    if _rng_info_outermost(base):
        return base.env_method(SPEC_IF_SENDABLE, indices=[0])[0][1]
    if unsendable(base, SpecUnsendable, [0])[0] is not None:
        return None
    return base.get_attr("spec", indices=[0])[0]


def _rng_info_outermost(base: VecEnv) -> bool:
    """Whether sub-env 0 of ``base`` is a :class:`~..vector.rng.ResetRngInfo` (it answers safely).

    Asked with ``env_is_wrapped`` first: with ResetRngInfo in it, the outermost is a wrapper,
    which has ``class_name``.
    """
    if not base.env_is_wrapped(ResetRngInfo, indices=[0])[0]:
        return False
    return bool(base.env_method("class_name", indices=[0])[0] == ResetRngInfo.__name__)
