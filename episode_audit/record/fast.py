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

import numpy as np

from ..format.spaces.buffers import _ArrayBuffer, _FlatArrayBuffer, _IntBuffer
from .block import Episode
from .episodes import EpisodeStream
from .native import NATIVE, PURE_PYTHON_ENV, compiled
from .stream import Stream

__all__ = [
    "PURE_PYTHON_ENV",
    "BeginAutoreset",
    "CompiledReset",
    "VectorStep",
    "compiled",
    "begin_autoreset_function",
    "end_batched_function",
    "reset_function",
    "step_function",
    "vector_step_function",
    "wrapper_step_function",
]

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


class WrapperStep(Protocol):
    """A recorder's ``step``, compiled (``_stepfast.WrapperStep``, ``csrc/wrapper.c``)."""

    def __call__(self, action: Any) -> Any:
        """The recorder's step: as ``RecordEvidence.step``, without a Python frame."""

    def inside_here(self) -> bool:
        """Whether this thread is inside a call of it (a flush from inside the env's step)."""


def wrapper_step_function(
    recorder: object, step: Callable[[Any, Any], None], python_step: Callable[..., Any]
) -> WrapperStep | None:
    """``recorder``'s ``step`` compiled, for its instance dict; ``None`` where it does not apply.

    ``step`` is the recorder's step function (:func:`step_function`); the compiled wrapper step
    applies when that is compiled. ``python_step`` is the class's ``step`` (a plain function),
    which the compiled one hands every call it does not take: gated, or with other arguments
    than one action.
    """
    if NATIVE is None or not isinstance(step, NATIVE.StepRecorder):
        return None
    wrapper: WrapperStep = NATIVE.WrapperStep(recorder, step, python_step)
    return wrapper


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


class VectorStep(Protocol):
    """The compiled batched vector step (``_stepfast.vector_step``)."""

    def __call__(
        self,
        obs_rows: np.ndarray[Any, Any],
        act_rows: np.ndarray[Any, Any],
        rew_rows: np.ndarray[Any, Any],
        time_rows: np.ndarray[Any, Any],
        t: int,
        obs: Any,
        actions: Any,
        rewards: Any,
        terminated: Any,
        truncated: Any,
        clock: Callable[[], int],
        endings_ok: bool,
    ) -> tuple[int, list[int]] | None:
        """Write a vector step into row ``t`` of the batch buffers, as ``_batch_step`` does.

        Only when every value goes in as it is (arrays of the buffers' dtype and row shape,
        one number reward and bool flags per sub-env; no ending unless ``endings_ok``): the
        time read from ``clock``, and the sub-envs whose episodes the step ended. Else
        ``None``: no clock read, nothing written.
        """


def vector_step_function() -> VectorStep | None:
    """The compiled batched vector step when the extension is used now (:func:`compiled`)."""
    if not compiled():
        return None
    step: VectorStep = NATIVE.vector_step
    return step


EndBatched = Callable[[EpisodeStream, int, bool, bool, dict[str, Any]], None]
"""``end_batched(stream, pending, terminated, truncated, info)``: see
:meth:`EpisodeStream.end_batched <episode_audit.record.episodes.EpisodeStream.end_batched>`."""


def end_batched_function() -> EndBatched:
    """:meth:`EpisodeStream.end_batched`, compiled when the extension is used now."""
    if not compiled():
        return EpisodeStream.end_batched
    end: EndBatched = NATIVE.end_batched
    return end


BeginAutoreset = Callable[[EpisodeStream, bytes, Any, int], "bool | None"]
"""``begin_autoreset(stream, rng_json, obs, start_ns)``: a vector sub-env's autoreset whose
info is not kept, recorded in C as ``NextStep.autoreset`` and ``SameStep._begin_next`` record
it (its episode begun from the RNG state ``rng_json``, its reset row): ``True``; ``None`` when
it is not taken (the stream has an open episode, or ``obs`` does not go into the reset column
as it is)."""


def begin_autoreset_function() -> BeginAutoreset | None:
    """The compiled autoreset when the extension is used now, else ``None``."""
    if not compiled():
        return None
    begin: BeginAutoreset = NATIVE.begin_autoreset
    return begin
