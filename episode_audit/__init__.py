"""episode-audit: auditable reinforcement-learning episodes.

Record every step of a Gymnasium environment — seed, action, observation, reward and its named
terms, ``terminated`` / ``truncated``, and why each episode ended — to an MCAP evidence file;
read it back as Arrow tables.

>>> import episode_audit
>>> episode_audit.FORMAT_VERSION
'1.0'
"""

import typing as _typing

from . import tasks as _tasks  # noqa: F401 - registers the reference tasks' Gymnasium ids
from ._version import __version__
from .check import CheckResult, Finding, check
from .compare import CompareGates, Comparison, compare
from .errors import (
    ConfigurationError,
    CorruptEvidenceError,
    EpisodeAuditError,
    EpisodeAuditWarning,
    EvidenceError,
    NotEvidenceError,
    RecorderError,
    RecorderTroubleWarning,
    RecorderWarning,
    ReplayError,
    UnclosedRecorderWarning,
    UnsupportedVersionError,
    WorkerError,
    WorkerWarning,
)
from .export import export
from .format import FORMAT_VERSION, EpisodeRanges, RunInfo
from .read import EPISODE_COLUMNS, DamagedRegion, EpisodeEvidence, Evidence, open_evidence
from .record import (
    Ending,
    EndingRules,
    RecordEvidence,
    RecordVectorEvidence,
    ResetRngInfo,
    RewardTerms,
    StateAdapter,
    register_state_adapter,
)
from .recover import RecoveryResult, recover
from .replay import ReplayResult, replay
from .report import Gates, Report, report

if (
    _typing.TYPE_CHECKING
):  # (for type checkers: at run time these are loaded on first access, below)
    from .record.pettingzoo import RecordAECEvidence, RecordParallelEvidence
    from .record.sb3 import RecordEvalCallback, RecordVecEnvEvidence, record_evaluation

__all__ = [
    "CheckResult",
    "CompareGates",
    "Comparison",
    "ConfigurationError",
    "CorruptEvidenceError",
    "DamagedRegion",
    "EPISODE_COLUMNS",
    "Ending",
    "EndingRules",
    "EpisodeAuditError",
    "EpisodeAuditWarning",
    "EpisodeEvidence",
    "EpisodeRanges",
    "Evidence",
    "EvidenceError",
    "FORMAT_VERSION",
    "Finding",
    "Gates",
    "NotEvidenceError",
    "RecordAECEvidence",
    "RecordEvalCallback",
    "RecordEvidence",
    "RecordParallelEvidence",
    "RecordVecEnvEvidence",
    "RecordVectorEvidence",
    "RecorderError",
    "RecorderTroubleWarning",
    "RecorderWarning",
    "RecoveryResult",
    "ReplayError",
    "ReplayResult",
    "Report",
    "ResetRngInfo",
    "RewardTerms",
    "RunInfo",
    "StateAdapter",
    "UnclosedRecorderWarning",
    "UnsupportedVersionError",
    "WorkerError",
    "WorkerWarning",
    "__version__",
    "check",
    "compare",
    "export",
    "open_evidence",
    "record_evaluation",
    "recover",
    "register_state_adapter",
    "replay",
    "report",
]

# The PettingZoo and SB3 recorders import pettingzoo / stable_baselines3 (optional extras):
# loaded on first access.
_LAZY = {
    "RecordAECEvidence": "record.pettingzoo",
    "RecordEvalCallback": "record.sb3",
    "RecordParallelEvidence": "record.pettingzoo",
    "RecordVecEnvEvidence": "record.sb3",
    "record_evaluation": "record.sb3",
}
_EXTRAS = {
    "record.pettingzoo": ("pettingzoo", "pettingzoo"),
    "record.sb3": ("stable_baselines3", "sb3"),
}
"""By lazy module: the package it imports, and the extra that installs it."""


def __getattr__(name: str) -> object:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'episode_audit' has no attribute {name!r}")
    import importlib

    try:
        loaded = importlib.import_module(f".{module}", __name__)
    except ModuleNotFoundError as exc:
        package, extra = _EXTRAS[module]
        if (exc.name or "").partition(".")[0] != package:
            raise
        raise ModuleNotFoundError(
            f"episode_audit.{name} needs the {package!r} package; install it with "
            f"pip install 'episode-audit[{extra}]'",
            name=package,
        ) from None
    return getattr(loaded, name)


def __dir__() -> list[str]:
    """The module's names, the lazily loaded ones of ``__all__`` included (for completion)."""
    return sorted(set(globals()) | set(__all__))
