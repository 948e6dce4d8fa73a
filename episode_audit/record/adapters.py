"""The state adapters episode-audit ships (registered on import; see :mod:`.state`).

- :class:`RunningStatsAdapter` — Gymnasium's ``NormalizeObservation`` / ``NormalizeReward``,
  their vector forms, and Stable-Baselines3's ``VecNormalize``: running mean / variance /
  count, the discounted returns the reward forms carry, and whether they still update.
- :class:`AleAdapter` — an ALE ``AtariEnv``'s emulator state with its RNG (sticky actions and
  the reset draw from it, not from ``np_random``): ALE's own serialized bytes.

Optional libraries (Stable-Baselines3, ale-py) are named by ``"module:Class"``: nothing is
imported until such an env is snapshot.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..format.state import StateValue
from .state import register_state_adapter

__all__ = ["AleAdapter", "RunningStatsAdapter"]


def _value(value: Any) -> StateValue:
    """A number as it is, anything else as a numpy array (a numpy scalar: 0-d).

    A Python float stays one: numpy 2 computes with it differently from a ``numpy.float64``.
    """
    return value if type(value) in (int, float) else np.asarray(value)


def _set_value(obj: Any, attr: str, value: StateValue) -> None:
    """Set ``obj.attr`` to a recorded value, as the type the attribute has now."""
    now = getattr(obj, attr)
    if isinstance(now, np.ndarray) or isinstance(value, np.ndarray):
        array = np.array(value)
        if array.shape != np.shape(now):
            raise ValueError(f"{attr} has shape {array.shape}, the rebuilt one {np.shape(now)}")
        value = array if isinstance(now, np.ndarray) else array[()]
    elif type(value) not in (int, float):
        raise ValueError(f"{attr} is not a number")
    setattr(obj, attr, value)


def _rms_state(prefix: str, rms: Any) -> dict[str, StateValue]:
    return {f"{prefix}.{attr}": _value(getattr(rms, attr)) for attr in ("mean", "var", "count")}


def _set_rms(prefix: str, rms: Any, state: Mapping[str, StateValue]) -> None:
    for attr in ("mean", "var", "count"):
        _set_value(rms, attr, state[f"{prefix}.{attr}"])


@dataclass(frozen=True)
class RunningStatsAdapter:
    """Running statistics (``RunningMeanStd``) and the plain values beside them.

    ``stats``: the attributes holding a ``RunningMeanStd`` (a dict of them for SB3's Dict
    observations); ``arrays``: numpy arrays and numbers the wrapper carries across episodes;
    ``flags``: booleans (whether it still updates its statistics); ``versioned``: arrays only
    some versions of the wrapper have (kept when there, and restored only into a wrapper that
    has them too).
    """

    name: str
    stats: tuple[str, ...]
    arrays: tuple[str, ...] = ()
    flags: tuple[str, ...] = ()
    needed: Literal["always", "unseeded"] = "always"
    versioned: tuple[str, ...] = ()

    def get_state(self, obj: Any) -> Mapping[str, StateValue]:
        """The statistics, arrays and flags of ``obj``."""
        state: dict[str, StateValue] = {}
        for attr in self.stats:
            rms = getattr(obj, attr, None)
            if rms is None:  # (SB3's VecNormalize has no obs_rms with norm_obs=False)
                continue
            if isinstance(rms, Mapping):  # SB3 VecNormalize over a Dict space
                for key, one in rms.items():
                    state.update(_rms_state(f"{attr}[{key}]", one))
                state[f"{attr}.keys"] = [str(k) for k in rms]
            else:
                state.update(_rms_state(attr, rms))
        for attr in self.arrays:
            state[attr] = _value(getattr(obj, attr))
        for attr in self.versioned:
            if hasattr(obj, attr):
                state[attr] = _value(getattr(obj, attr))
        for attr in self.flags:
            state[attr] = bool(getattr(obj, attr))
        return state

    def set_state(self, obj: Any, state: Mapping[str, StateValue]) -> None:
        """Put :meth:`get_state`'s values back into ``obj`` (shapes must match)."""
        for attr in self.stats:
            rms = getattr(obj, attr, None)
            if rms is None:
                continue
            if isinstance(rms, Mapping):
                if state.get(f"{attr}.keys") != [str(k) for k in rms]:
                    raise ValueError(f"{attr} has other keys than the recorded ones")
                for key, one in rms.items():
                    _set_rms(f"{attr}[{key}]", one, state)
            else:
                _set_rms(attr, rms, state)
        for attr in self.arrays:
            _set_value(obj, attr, state[attr])
        for attr in self.versioned:
            if (attr in state) != hasattr(obj, attr):
                only = "the recorded state has" if attr in state else "the rebuilt wrapper has"
                raise ValueError(f"only {only} {attr} (another version of its library)")
            if attr in state:
                _set_value(obj, attr, state[attr])
        for attr in self.flags:
            setattr(obj, attr, bool(state[attr]))


@dataclass(frozen=True)
class AleAdapter:
    """An ALE ``AtariEnv``: its emulator state, RNG included (``cloneState(include_rng=True)``).

    Needed by unseeded episodes only: a seeded ``reset()`` reseeds the emulator and reloads
    the ROM. The bytes are ALE's own serialization, restored by ``ALEState(bytes)``.
    """

    name: str = "ale_py.AtariEnv"
    needed: Literal["always", "unseeded"] = "unseeded"

    def get_state(self, obj: Any) -> Mapping[str, StateValue]:
        """The emulator state with its RNG, serialized."""
        return {"ale_state": bytes(obj.ale.cloneState(include_rng=True).serialize())}

    def set_state(self, obj: Any, state: Mapping[str, StateValue]) -> None:
        """Restore the emulator state (and RNG)."""
        from ale_py import ALEState

        data = state["ale_state"]
        if not isinstance(data, bytes):
            raise ValueError("ale_state is not bytes")
        obj.ale.restoreState(ALEState(data))


def _register() -> None:
    normalize_obs = RunningStatsAdapter(
        "gymnasium.NormalizeObservation", ("obs_rms",), flags=("_update_running_mean",)
    )
    normalize_reward = RunningStatsAdapter(
        "gymnasium.NormalizeReward",
        ("return_rms",),
        ("discounted_reward",),
        ("_update_running_mean",),
    )
    vector_normalize_reward = RunningStatsAdapter(
        "gymnasium.vector.NormalizeReward",
        ("return_rms",),
        ("accumulated_reward",),
        ("_update_running_mean",),
        versioned=("_prev_dones",),  # (Gymnasium >= 1.3)
    )
    vector_normalize_obs = RunningStatsAdapter(
        "gymnasium.vector.NormalizeObservation", ("obs_rms",), flags=("_update_running_mean",)
    )
    vec_normalize = RunningStatsAdapter(
        "stable_baselines3.VecNormalize", ("obs_rms", "ret_rms"), ("returns",), ("training",)
    )
    for target, adapter in (
        ("gymnasium.wrappers.stateful_observation:NormalizeObservation", normalize_obs),
        ("gymnasium.wrappers.stateful_reward:NormalizeReward", normalize_reward),
        (
            "gymnasium.wrappers.vector.stateful_observation:NormalizeObservation",
            vector_normalize_obs,
        ),
        ("gymnasium.wrappers.vector.stateful_reward:NormalizeReward", vector_normalize_reward),
        ("stable_baselines3.common.vec_env.vec_normalize:VecNormalize", vec_normalize),
        ("ale_py.env:AtariEnv", AleAdapter()),
    ):
        register_state_adapter(target, adapter)


_register()
