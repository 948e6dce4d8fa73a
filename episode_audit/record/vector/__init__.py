"""Record a ``gymnasium.vector.VectorEnv``: one episode stream per sub-env, in one evidence file.

- :class:`RecordVectorEvidence` — a ``VectorWrapper`` over any vector env (``SyncVectorEnv``,
  ``AsyncVectorEnv``, ``gym.make_vec``) in any autoreset mode (``recorder.py``).
- :class:`ResetRngInfo` — a sub-env wrapper that reports the RNG state from just before an
  unseeded reset, for ``SAME_STEP`` autoresets on an ``AsyncVectorEnv`` (``rng.py``).

Inside: one autoreset strategy per mode (``modes.py``), the per-step path, batched when it can
be (``steps.py``), each sub-env's info (``infos.py``), ``reset()``'s arguments (``resets.py``).
How the modes are recorded: ``docs/format.md``, "Vector files"; the recorder:
``docs/recording.md``. Wrap the vector env itself (innermost): replay rebuilds one sub-env.
"""

from __future__ import annotations

from .recorder import RecordVectorEvidence
from .rng import ResetRngInfo

__all__ = ["RecordVectorEvidence", "ResetRngInfo"]
