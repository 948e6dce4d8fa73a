"""The replay wing: re-run recorded episodes and say where they diverge, if they do.

:func:`replay` (files) and :func:`replay_evidence` (one open file) give a
:class:`ReplayResult`: an :class:`EpisodeReplay` per episode, with its :class:`Divergence` if
it diverged. :func:`build_env` builds the env a file's episodes replay in; :func:`replay_options`
checks the options. How replay works: docs/replay.md.
"""

from .envs import build_env
from .results import Divergence, EpisodeReplay, ReplayResult
from .run import replay, replay_evidence, replay_options

__all__ = [
    "Divergence",
    "EpisodeReplay",
    "ReplayResult",
    "build_env",
    "replay",
    "replay_evidence",
    "replay_options",
]
