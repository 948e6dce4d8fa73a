"""Record PettingZoo environments: one episode stream per agent, games of agent-episodes.

- :class:`RecordParallelEvidence` — a ``BaseParallelWrapper`` over a ``ParallelEnv``.
- :class:`RecordAECEvidence` — a ``BaseWrapper`` over an ``AECEnv``; :class:`AECTurns`, its turn
  accounting, is shared with replay.
- :func:`env_id_of`, :func:`env_module_of`, :func:`is_pettingzoo_module`, :func:`is_registered`,
  :func:`make_registered`, :func:`wrappers_of` — how a recorded env is named and rebuilt.

This package is the only place that imports ``pettingzoo`` (``episode_audit`` imports it lazily,
so PettingZoo stays optional). Layout and AEC accounting: ``docs/format.md``, "PettingZoo files".
"""

from __future__ import annotations

from .aec import RecordAECEvidence
from .agents import agent_result
from .parallel import RecordParallelEvidence
from .registry import (
    KIND_AEC,
    KIND_PARALLEL,
    env_id_of,
    env_module_of,
    is_pettingzoo_module,
    is_registered,
    make_registered,
    wrappers_of,
)
from .turns import AECTurns

__all__ = [
    "KIND_AEC",
    "KIND_PARALLEL",
    "AECTurns",
    "RecordAECEvidence",
    "RecordParallelEvidence",
    "agent_result",
    "env_id_of",
    "env_module_of",
    "is_pettingzoo_module",
    "is_registered",
    "make_registered",
    "wrappers_of",
]
