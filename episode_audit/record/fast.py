"""The compiled step: :func:`step_function` gives a stream's step, compiled when it can be.

``episode_audit.record._stepfast`` (C, built with the package when a compiler is there) records
the common step — array or integer observations and actions, a number reward, ``bool`` flags, a
plain ``dict`` info whose terms the stream's plan reads — as :meth:`Stream.step
<episode_audit.record.stream.Stream.step>` does, and hands every other step to that method
untouched: the file is the same either way. ``EPISODE_AUDIT_PURE_PYTHON=1`` in the environment
(read when a recorder is made) keeps the pure-Python path. See ``docs/recording.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from ..format.spaces.buffers import _ArrayBuffer, _FlatArrayBuffer, _IntBuffer
from .block import Episode
from .native import NATIVE, PURE_PYTHON_ENV, compiled
from .stream import Stream

__all__ = ["PURE_PYTHON_ENV", "CompiledReset", "compiled", "reset_function", "step_function"]

_FAST_BUFFERS = (_FlatArrayBuffer, _ArrayBuffer, _IntBuffer)


def step_function(stream: Stream) -> Callable[[Any, Any], None]:
    """``stream``'s step (``step(action, result)``): the compiled one where it applies.

    It applies when the extension is built and not switched off, the stream does not keep
    info keys (``info_keys`` / ``keep_all_info``), and both columns are arrays or integers.
    """
    block = stream.block
    if (
        not compiled()
        or stream._track_info
        or type(block.obs) not in _FAST_BUFFERS
        or type(block.act) not in _FAST_BUFFERS
    ):
        return stream.step
    step: Callable[[Any, Any], None] = NATIVE.StepRecorder(stream)
    return step


class CompiledReset(Protocol):
    """The compiled reset of a stream: a seeded reset with no options, recorded in C."""

    def begin(self, seed: Any) -> Episode | None:
        """Begin the stream's next episode for a reset with this seed and no options.

        As ``EpisodeStream.begin(seed, None, None, [])`` for an int64 ``seed`` when the stream
        has no open episode: the new episode; else ``None``, nothing changed.
        """

    def reset_row(self, episode: Episode, result: Any) -> bool | None:
        """Record the reset row of ``episode``, then flush when due.

        As ``record_reset`` for what ``reset()`` returned: ``True``; else ``None``, nothing
        changed (the Python path records it).
        """


def reset_function(step: Callable[[Any, Any], None]) -> CompiledReset | None:
    """The compiled reset that goes with ``step`` (from :func:`step_function`), or ``None``."""
    if NATIVE is None or not isinstance(step, NATIVE.StepRecorder):
        return None
    reset: CompiledReset = step
    return reset
