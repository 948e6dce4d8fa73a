"""The record wing: wrappers that write evidence files while an env runs.

Public: :class:`RecordEvidence` (Gymnasium), :class:`RecordVectorEvidence` and
:class:`ResetRngInfo` (vector envs), ``RecordParallelEvidence`` and ``RecordAECEvidence``
(PettingZoo, imported on first use), ``RecordVecEnvEvidence``, ``RecordEvalCallback`` and
``record_evaluation`` (Stable-Baselines3, :mod:`.sb3`, imported on first use), their options
(:class:`RecorderOptions`, checked by :class:`RecorderSettings`), the rules that read an
env's info: :class:`RewardTerms`, :class:`EndingRules`, :class:`Ending`, and state snapshots
beyond the seed: :class:`StateAdapter`, :func:`register_state_adapter`. How recording works:
``docs/recording.md``.
"""

from __future__ import annotations

from . import adapters as adapters  # registers the shipped state adapters
from .gym import RecordEvidence
from .rules import Ending, EndingRules, RewardTerms
from .settings import RecorderOptions, RecorderSettings
from .state import StateAdapter, register_state_adapter
from .vector import RecordVectorEvidence, ResetRngInfo

__all__ = [
    "Ending",
    "EndingRules",
    "RecordAECEvidence",
    "RecordEvalCallback",
    "RecordEvidence",
    "RecordParallelEvidence",
    "RecordVecEnvEvidence",
    "RecordVectorEvidence",
    "RecorderOptions",
    "RecorderSettings",
    "ResetRngInfo",
    "RewardTerms",
    "StateAdapter",
    "record_evaluation",
    "register_state_adapter",
]


def __getattr__(name: str) -> object:
    # the extras' packages (optional): imported only when asked for
    if name in ("RecordAECEvidence", "RecordParallelEvidence"):
        from . import pettingzoo

        return getattr(pettingzoo, name)
    if name in ("RecordEvalCallback", "RecordVecEnvEvidence", "record_evaluation"):
        from . import sb3

        return getattr(sb3, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
