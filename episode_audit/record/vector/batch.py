"""The vector steps batched for the sub-envs' streams: preallocated rows, handed over in bulk.

:class:`Batch` holds what :class:`~.steps.VectorSteps` writes in place for each batched step
(observations, actions, rewards and the step's time, a row per sub-env; the reward terms in
:class:`~.terms.TermColumns`) and hands each sub-env's rows to its stream at once
(:meth:`Batch.drain`), leaving out the rows of the steps a sub-env spent only resetting.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..stream import Stream
from .terms import TermColumns

__all__ = ["BATCH_BYTES", "BATCH_STEPS", "Batch"]

BATCH_STEPS = 1024
"""Most vector steps batched before their rows are handed to the streams (each hand-over costs
~25 us a sub-env besides its rows: 256 steps cost the vector x8 CartPole bench ~0.01x more)."""

BATCH_BYTES = 8 << 20
"""Most bytes of observations and actions batched: fewer steps when the rows are big (8
Atari frames a step: ~10 steps, not 1 024)."""


class Batch:
    """Rows of vector steps batched for ``streams``, written in place, handed over in bulk.

    ``obs`` is ``None`` until :meth:`hold` gives the dtypes and shapes of the steps' values.
    The buffers go on from one :meth:`drain` to the next (the streams' buffers copy the rows
    they take: ``ColumnBuffer.extend``, or ``append`` row by row), so their memory is not new
    to the process at each drain (new memory faults a page at a time on first write, which for
    camera frames costs more than copying them). ``length`` steps are written, of ``rows``
    there is room for.
    ``terms``: the steps' reward terms, ``None`` when steps with infos are not batched.
    """

    __slots__ = (
        "_reset_envs",
        "_reset_steps",
        "_skip",
        "_streams",
        "act",
        "length",
        "obs",
        "rew",
        "rows",
        "terms",
        "time",
    )

    def __init__(self, streams: list[Stream], terms: TermColumns | None) -> None:
        self._streams = streams
        self.terms = terms
        self.length = 0
        self.rows = 0
        self.obs: np.ndarray[Any, Any] | None = None
        self.act: np.ndarray[Any, Any] = np.empty(0)
        self.rew: np.ndarray[Any, Any] = np.empty(0)
        self.time: np.ndarray[Any, Any] = np.empty(0)
        self._skip = [0] * len(streams)  # per sub-env, the batched steps it spent resetting
        # the (batched step, sub-env) pairs where the sub-env only reset: no row of its own
        self._reset_steps: list[int] = []
        self._reset_envs: list[int] = []

    def hold(self, obs: np.ndarray[Any, Any], actions: np.ndarray[Any, Any]) -> None:
        """Hand over what is batched; new buffers of these dtypes and shapes.

        For as many steps as :data:`BATCH_STEPS` and :data:`BATCH_BYTES` allow.
        """
        self.drain()  # (and the term batch with them)
        rows = max(1, min(BATCH_STEPS, BATCH_BYTES // max(1, obs.nbytes + actions.nbytes)))
        self.rows = rows
        self.obs = np.empty((rows, *obs.shape), dtype=obs.dtype)
        self.act = np.empty((rows, *actions.shape), dtype=actions.dtype)
        self.rew = np.empty((rows, len(self._streams)), dtype=np.float64)
        self.time = np.empty(rows, dtype=np.int64)

    def only_reset(self, t: int, i: int) -> int:
        """Batched step ``t`` only reset sub-env ``i`` (no row of its own); its pending rows."""
        self._skip[i] += 1
        self._reset_steps.append(t)
        self._reset_envs.append(i)
        return self.length - self._skip[i]

    def pending_rows(self, i: int) -> int:
        """Rows batched for sub-env ``i`` and not yet handed to its stream."""
        return self.length - self._skip[i]

    def drain(self) -> None:
        """Hand the batched rows over to each sub-env's stream (before any other row)."""
        t = self.length
        if not t or self.obs is None:
            return
        obs, act = self.obs[:t], self.act[:t]
        rew, times = self.rew[:t], self.time[:t]
        reset_steps, reset_envs = self._reset_steps, self._reset_envs
        terms = None if self.terms is None else self.terms.take()
        self.length = 0
        if not reset_steps:
            for i, stream in enumerate(self._streams):
                first = len(stream.block.times)
                stream.extend(obs[:, i], act[:, i], rew[:, i], times)
                if terms is not None:
                    terms.hand_over(stream.block, first, slice(0, t), i)
            return
        self._skip = [0] * len(self._streams)
        self._reset_steps, self._reset_envs = [], []
        stepped = np.ones((t, len(self._streams)), dtype=np.bool_)
        stepped[reset_steps, reset_envs] = False
        for i, stream in enumerate(self._streams):
            rows = np.flatnonzero(stepped[:, i])
            first = len(stream.block.times)
            stream.extend(obs[rows, i], act[rows, i], rew[rows, i], times[rows])
            if terms is not None:
                terms.hand_over(stream.block, first, rows, i)
