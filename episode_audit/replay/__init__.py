"""The replay wing: re-run recorded episodes and say where they diverge, if they do."""

from .run import replay, replay_evidence
from .single import Divergence, EpisodeReplay, ReplayResult, build_env

__all__ = [
    "Divergence",
    "EpisodeReplay",
    "ReplayResult",
    "build_env",
    "replay",
    "replay_evidence",
]
