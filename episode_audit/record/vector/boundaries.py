"""Where a vector recorder's episodes begin by ``reset()`` and end by an error.

:class:`Boundaries` is the part of :class:`~.steps.VectorSteps` (which builds on it) that is
not the step: the episodes a ``reset()`` begins, and the episodes a ``reset()`` or a vector
step that raised ends ``error``. Every sub-env's batched rows are handed over first, so each
boundary falls at the row it belongs to.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..file import EvidenceFile
from ..stream import Stream
from ..values import RecordedOptions
from .batch import Batch
from .modes import Autoreset
from .rng import RngState, SubEnvRng

__all__ = ["Boundaries"]


class Boundaries:
    """A vector recorder's resets and failures, over its streams, batch and autoreset strategy.

    ``idle`` (the sub-envs without a running episode, ``None`` when not known) is set to
    ``None`` at every boundary: the steps work it out again.
    """

    _file: EvidenceFile
    _streams: list[Stream]
    _autoreset: Autoreset
    _batch: Batch
    idle: set[int] | None

    def record_reset(
        self,
        indices: Sequence[int],
        seeds: Sequence[Any],
        options: Sequence[RecordedOptions | None],
        states: dict[int, RngState | None],
        rng: SubEnvRng,
        result: tuple[list[Any], list[Any], str | None],
        start: int,
    ) -> None:
        """Begin the episodes a ``reset()`` began: sub-envs ``indices``, with their arguments.

        ``seeds`` and ``options`` hold each sub-env's, ``states`` the RNG states read before the
        reset (an unseeded sub-env's reset info may hold its own: :class:`ResetRngInfo`);
        ``result`` is each sub-env's reset observation and info, and the ``info_unmasked`` note.
        """
        rows, infos, unmasked = result
        streams, autoreset = self._streams, self._autoreset
        self.idle = None
        for i in indices:
            state = states.get(i)
            if seeds[i] is None:
                state = rng.from_info(infos[i], i) or state
            streams[i].block.pending = self._batch.pending_rows(i)
            streams[i].end_open()
            autoreset.begin(
                i, seeds[i], options[i], state, rows[i], infos[i], start, None, unmasked
            )
        autoreset.were_reset(indices)
        if self._file.due():
            self._file.auto_flush()

    def reset_failed(
        self,
        indices: Sequence[int],
        seeds: Sequence[Any],
        options: Sequence[RecordedOptions | None],
        states: dict[int, RngState | None],
        exc: Exception,
    ) -> None:
        """``reset()`` raised ``exc``: each sub-env of ``indices`` gets an episode ended ``error``.

        Never raises (the loop sees the env's error, not the recorder's).
        """
        self.idle = None
        try:
            for i in indices:
                self._streams[i].block.pending = self._batch.pending_rows(i)
                self._autoreset.begin_failed(i, seeds[i], options[i], states.get(i), exc)
            self._file.flush()
        except Exception as trouble:
            self._file.trouble(trouble)

    def step_failed(self, exc: Exception) -> None:
        """The vector step raised ``exc``: end the open episodes as ``error`` (``step``).

        An autoreset that raised is first recorded where it belongs: as a ``reset()`` that
        raised, an episode of its sub-env ended ``error`` during ``reset``, with the RNG state
        the reset started from (the strategy's ``failed_autoresets``).
        """
        self.idle = None
        try:
            self._batch.drain()
            self._autoreset.failed_autoresets(exc)
        except Exception as trouble:  # the loop sees the env's error, not the recorder's
            self._file.trouble(trouble)
        self._file.end_with_error(self._streams, exc, "step")
