"""Record Stable-Baselines3 training and evaluation (the ``sb3`` extra: ``stable_baselines3``).

- :class:`RecordVecEnvEvidence` — a ``VecEnvWrapper`` recording every sub-env of any SB3
  ``VecEnv`` (``DummyVecEnv``, ``SubprocVecEnv``, under ``VecNormalize`` …) to one file
  (``recorder.py``; SB3's step read as Gymnasium's in ``results.py``; the stack in ``stack.py``).
- :func:`record_evaluation` and :class:`RecordEvalCallback` — each evaluation to a file of its
  own, tagged with the checkpoint and the training step (``evaluation.py``).

``import episode_audit`` does not import this package: it loads on first use of a name.
Recipes: ``docs/recording.md``, "Stable-Baselines3".
"""

from __future__ import annotations

from .evaluation import RecordEvalCallback, record_evaluation
from .recorder import RecordVecEnvEvidence

__all__ = ["RecordEvalCallback", "RecordVecEnvEvidence", "record_evaluation"]
