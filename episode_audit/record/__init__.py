"""The record wing: wrappers that write evidence files while an env runs.

Public: :class:`RecordEvidence` (Gymnasium), :class:`RecordVectorEvidence` and
:class:`ResetRngInfo` (vector envs), ``RecordParallelEvidence`` and ``RecordAECEvidence``
(PettingZoo, imported on first use), their options (:class:`RecorderOptions`, checked by
:class:`RecorderSettings`), and the rules that read an env's info: :class:`RewardTerms`,
:class:`EndingRules`, :class:`Ending`; state snapshots beyond the seed:
:class:`StateAdapter`, :func:`register_state_adapter`. How recording works: ``docs/recording.md``.
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
    "RecordEvidence",
    "RecordParallelEvidence",
    "RecordVectorEvidence",
    "RecorderOptions",
    "RecorderSettings",
    "ResetRngInfo",
    "RewardTerms",
    "StateAdapter",
    "register_state_adapter",
]


def __getattr__(name: str) -> object:
    if name not in ("RecordAECEvidence", "RecordParallelEvidence"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from . import pettingzoo  # imports pettingzoo (optional): only when asked for

    return getattr(pettingzoo, name)
