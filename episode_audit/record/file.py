"""One evidence file being recorded: its streams, episode records, flushes and close.

- :class:`EvidenceFile` — owns the writer, the run metadata, the episode channels, the clock,
  flush timing, counts and ``close()``; streams are added with ``add_stream``.
- The episode records of ended episodes are written at each flush (one JSON message each and
  one Arrow block, ``docs/format.md``, "Episode records").
- Files whose recorder was never closed are finished when the recorder is collected, or when
  the interpreter exits normally.
- Disk trouble (a refused flush, a close that cannot finish) is the recorder's trouble: warned
  once in one line, said in the run-end record, never raised into the training loop.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Sequence
from types import FrameType
from typing import Any, Protocol

from gymnasium.wrappers import TimeLimit

from .._version import __version__
from ..errors import (
    ConfigurationError,
    RecorderError,
    RecorderTroubleWarning,
    UnclosedRecorderWarning,
)
from ..format import names as fmt
from ..format.columns import error_text, prepare_pyarrow
from ..format.records import MAX_JSON_TEXT, RunInfo
from ..format.spaces import SpaceCodec
from . import native, signals
from .block import Episode
from .endings import NO_ACTION
from .episode_records import EpisodeRecords
from .run_end import run_end_record
from .settings import RecorderSettings
from .stream import Stream
from .writer import EvidenceWriter

__all__ = ["CHUNK_TARGET_BYTES", "EvidenceFile", "FileRecorder"]

CHUNK_TARGET_BYTES = 32 << 20
"""Largest uncompressed chunk the recorder aims for: a flush comes after at most this many
bytes of step rows over every stream, whatever ``block_steps`` says (large observations), so
the rows a recorder holds stay small and files stay far inside the reader's 1 GiB record cap
(``read.chunks.MAX_RECORD_BYTES``)."""

_TROUBLE_TEXT = 500  # characters of the first trouble kept in the run-end record
_CLOSE_WAIT_S = 10.0  # longest close() waits for another thread's step() or reset() to end


class _Owner(Protocol):
    def close(self) -> None: ...


class FileRecorder:
    """What every recorder does with its evidence file (``_file``, which the recorder opens).

    ``flush()``, from any thread; finishing the file once, on the recorder's ``close()``, or as
    a recorder dropped with its file still open is collected (warned of when it warns,
    ``_warns_unclosed``).

    Threads: the recorder's ``step()`` and ``reset()`` take no lock. They set ``_busy`` (one
    attribute store), then read the gate, ``if self._gated: self._enter()``, and clear ``_busy``
    as they return or raise. ``flush()`` and ``close()`` set the gate under a lock, then read
    ``_busy``: if it is clear, they write while the gate holds new calls back (a thread that
    reads the gate set clears ``_busy`` while it waits at the lock); if a thread is inside,
    ``flush()`` leaves the flush to the end of that call (``flush_at``) and ``close()`` waits
    for it to return. The stepping thread's own ``flush()`` or ``close()`` (from inside its
    env) writes at once, as between calls. A ``step()`` or ``reset()`` entered while another
    thread is inside one is refused (:meth:`_one_thread`).
    """

    _file: EvidenceFile
    _closed: bool
    _gated: bool  # closed, or a flush() / close() under way: step() and reset() go by _enter()
    _busy: bool  # a thread is inside step() or reset(), past the gate or about to read it
    _flush_lock: threading.Lock
    _entries: tuple[str, ...] = ("step", "reset")  # the methods that set _busy
    _warns_unclosed = True

    def _opened(self) -> None:
        """Mark the recorder open (the last thing a recorder's ``__init__`` does)."""
        self._flush_lock = threading.Lock()
        self._closed = False
        self._gated = False
        self._busy = False
        _RECORDERS.add(self)

    def __copy__(self) -> Any:
        raise self._not_copied("copied")

    def __deepcopy__(self, memo: Any) -> Any:
        raise self._not_copied("copied")

    def __reduce_ex__(self, protocol: Any) -> Any:
        raise self._not_copied("pickled")

    def _not_copied(self, how: str) -> RecorderError:
        """The error for a copy or a pickle: the open file cannot have two owners."""
        return RecorderError(
            f"{self._file.path}: a recorder cannot be {how}: it owns an open evidence file, "
            "which a copy's close() would finish under it; make a recorder per env, in the "
            "process that steps it"
        )

    def _inherited(self) -> None:
        """Mark the recorder its parent's: called in a forked child, at the fork.

        The file is the parent's (:attr:`EvidenceFile.inherited`): every call here goes by the
        gate, where :meth:`_enter` and :meth:`flush` raise; ``close()`` closes the env and
        writes nothing. The child's copy of the file is closed now, its lock left to the parent.
        The gate's lock is new (a thread of the parent may have held it as it forked), no thread
        of the parent is inside any more, and a dropped recorder does not warn.
        """
        self._flush_lock = threading.Lock()
        self._busy = False
        self._gated = True
        self._warns_unclosed = False
        file = getattr(self, "_file", None)
        if file is not None:
            file.writer.close_inherited()

    def _enter(self) -> None:
        """The way into ``step()`` / ``reset()`` when gated: raise if closed.

        Else wait for the ``flush()`` under way in another thread (``_busy`` clear meanwhile:
        held at the lock, this thread touches nothing).
        """
        self._file.check_open()
        if self._gated:
            self._busy = False
            with self._flush_lock:
                self._busy = True
            self._file.check_open()

    def flush(self) -> None:
        """Write everything recorded so far to the file now; safe from any thread.

        From another thread while a ``step()`` or ``reset()`` is under way, that call flushes as
        it ends. A flush the OS refuses (a full disk) is the recorder's trouble, as in the loop:
        warned once, retried by the next flush, said in the run-end record; it does not raise.
        """
        self._file.check_open()
        with self._flush_lock:
            self._gated = True
            try:
                if _inside(self):
                    self._file.flush_at = 0  # (read at the end of every step and reset)
                else:
                    self._file.auto_flush(background=False)
            finally:
                self._gated = self._closed

    @property
    def trouble(self) -> str | None:
        """The recorder's first failure inside itself (``Type: message``), if any.

        Such a failure (a full disk) was warned once and never raised; the run-end record
        says it too.
        """
        return self._file.first_trouble

    def _busy_here(self) -> bool:
        """Whether ``_busy`` is this thread's, where its stack does not show it.

        SB3's ``step_async()``, before its ``step_wait()`` (a call that has returned), and
        ``RecordEvidence``'s compiled ``step`` (a call with no Python frame): no other thread is
        inside then, and this thread's own ``close()`` must not wait for itself.
        """
        return False

    def _one_thread(self) -> None:
        """Refuse a ``step()`` or ``reset()`` entered while another thread is inside one.

        Called at the entry of those calls when ``_busy`` is set. Two threads stepping one
        env at once interleave their rows in its episodes: the recorder refuses the second
        (``RecorderError``, misuse) before it touches the env or the file.
        """
        if _inside(self, entering=True):
            raise RecorderError(
                f"{self._file.path}: a second thread called this recorder while another is "
                "inside its step() or reset(); an env and its recorder take one call at a "
                "time: give each thread its own env and recorder, or hold a lock around "
                "step() and reset()"
            )

    def _before_close(self) -> None:
        """Called before the file is finished (by :meth:`_close_file`)."""

    def _close_file(self, close_env: Callable[[], None]) -> None:
        """Finish the file; safe to call more than once. ``close_env`` runs even if it fails.

        From another thread, a ``step()`` or ``reset()`` under way ends first (within
        :data:`_CLOSE_WAIT_S`: a thread stuck in its env does not hold the exit).
        """
        if getattr(self, "_closed", True):
            return
        with self._flush_lock:
            if self._closed:
                return
            self._closed = self._gated = True
            deadline = time.monotonic() + _CLOSE_WAIT_S
            while _inside(self) and time.monotonic() < deadline:
                time.sleep(0.001)
            try:
                self._before_close()
                self._file.close()
            finally:
                close_env()

    def __del__(self) -> None:
        """A recorder collected open: its file is finished now, and warned of (one warning).

        As a Python file object closes itself when collected, the evidence file is finished
        (open episodes ``incomplete``, run-end record, summary), so it is complete and its file
        object closed (no ``ResourceWarning`` of its own). The env is left as it is.
        """
        if getattr(self, "_closed", True):
            return
        self._closed = self._gated = True
        if self._warns_unclosed:
            import warnings

            warnings.warn(
                f"episode-audit: {type(self).__name__} for {getattr(self, 'path', '?')} was not "
                "closed; call close() or use it as a context manager (its file was finished as "
                "the recorder was collected)",
                UnclosedRecorderWarning,
                stacklevel=2,
            )
        try:
            self._before_close()
            self._file.close()
        except Exception:
            pass  # (finishing failed: said by the file's own trouble warning, if anything)


def _inside(recorder: FileRecorder, *, entering: bool = False) -> bool:
    """Whether a thread other than this one is inside ``recorder``'s ``step()`` or ``reset()``.

    Called holding the gate's lock (``flush()``, ``close()``), or by
    :meth:`FileRecorder._one_thread` at the entry of a call (``entering``: that call's own
    frames are left out). ``_busy`` says a thread is inside (set before it reads the gate,
    cleared while it waits at the gate's lock). If it is this thread (a ``flush()`` from
    inside its own env's step), none other is. Only this thread's own stack is read: reading
    another thread's frames while it runs is not safe on CPython 3.11 (their ``f_back`` can
    point at a freed frame).
    """
    if not recorder._busy or recorder._busy_here():
        return False
    cls = type(recorder)
    entries = {getattr(cls, name).__code__ for name in recorder._entries}

    def ours(frame: FrameType) -> bool:
        return frame.f_code in entries and frame.f_locals.get("self") is recorder

    f: FrameType | None = sys._getframe(2 if entering else 1)
    while entering and f is not None and ours(f):
        f = f.f_back  # (the call being entered: SB3's step() and its step_async())
    while f is not None:
        if ours(f):
            return False  # (this thread is the one inside)
        f = f.f_back
    return True


class EvidenceFile:
    """One evidence file being recorded: run metadata, episode channels, flushes, close.

    Streams are added with :meth:`add_stream`; :meth:`flush` writes every stream's pending
    blocks and the records of the episodes ended since the previous flush, in one chunk.

    Args:
        path: The evidence file to create (never overwritten unless ``settings.overwrite``): a
            path template (``runs/train-{index}.mcap``, :class:`~.lock.PathTemplate`); the
            resolved path is :attr:`path`.
        run: The run metadata (``layout`` says how many streams there are and of what kind).
        settings: The recorder settings (the same for every stream; ``fsync``, ``overwrite``).
        games: Whether episode records and reset rows carry a ``game`` (PettingZoo files).
        owner: The wrapper to ``close()`` when the interpreter exits with the file still open.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        run: RunInfo,
        settings: RecorderSettings,
        *,
        games: bool = False,
        owner: _Owner | None = None,
    ) -> None:
        self.run = run
        self.settings = settings
        self.games = games
        self.multi = run.layout.get("kind", "single") != "single"
        self.block_steps = settings.block_steps
        self.flush_ns = int(settings.flush_every_s * 1e9)
        # Clock: monotonic for ordering, anchored to the wall clock once.
        self.clock = time.monotonic_ns
        self.wall_offset = time.time_ns() - time.monotonic_ns()
        self.records = EpisodeRecords(games)
        self.pending: list[tuple[Episode, dict[str, Any]]] = []
        self.rng_json = native.rng_json_function()
        self.streams: list[Stream] = []
        # called first by every flush (a batching recorder hands over its rows)
        self.before_flush: list[Callable[[], None]] = []
        metadata = _readable(run.to_metadata())
        self.writer = EvidenceWriter(
            path,
            library=f"episode-audit {__version__}",
            fsync=settings.fsync,
            overwrite=settings.overwrite,
            template=True,
        )
        self.path = self.writer.path
        try:
            self.writer.add_metadata(fmt.METADATA_RUN, metadata)
        except BaseException:
            self.writer.abandon()
            raise
        self.started = False
        self.next_episode = 0
        self.last_flush = self.clock()
        self.flush_at = self.last_flush + self.flush_ns  # when flush_every_s will have passed
        self.closed = False
        self.counts = {"episodes": 0, "steps": 0, "blocks": 0, "success_reported": 0}
        self._warned = False
        self.troubles = 0  # the recorder's own failures, said in the run-end record
        self.first_trouble: str | None = None
        self.pid = os.getpid()  # the process recording: a fork of it writes nothing here
        # held: a recorder is amid the rows of one env step (a Parallel step's agents), whose
        # auto_flush() waits for its end, so a torn file never splits the step; flush_wanted:
        # the auto_flush() it then makes (its `background`; None: none)
        self.held = False
        self.flush_wanted: bool | None = None
        if owner is not None:
            _OPEN_RECORDERS.add(owner)
        self._owner = owner

    @property
    def flush_at(self) -> int:
        """When (:attr:`clock`, ns) the next flush is due.

        ``flush_every_s`` after the last flush, or 0 when a flush from another thread was left
        to the end of a step. Each stream keeps a copy (``Stream.flush_at``, a slot its
        compiled step reads), set here.
        """
        return self._flush_at

    @flush_at.setter
    def flush_at(self, at: int) -> None:
        self._flush_at = at
        for stream in self.streams:
            stream.flush_at = at

    def start(self) -> None:
        """Register the episode channels (after every stream's) and flush the file's head.

        Call once, after the last :meth:`add_stream`; the channels of a single-stream file are
        then numbered as they always were (steps, resets, episode records, episode blocks).
        ``block_steps`` is lowered here when the streams' rows are so large that a chunk would
        outgrow :data:`CHUNK_TARGET_BYTES`.
        """
        if self.started:
            raise RecorderError(f"{self.path}: the evidence file is already started")
        prepare_pyarrow()  # (not amid the loop's steps, nor in the loop's context)
        writer = self.writer
        try:
            self.records.register(writer)
            writer.flush()
        except BaseException:
            writer.abandon()
            raise
        row_bytes = sum(stream.row_bytes for stream in self.streams)
        self.block_steps = max(1, min(self.block_steps, CHUNK_TARGET_BYTES // max(1, row_bytes)))
        for stream in self.streams:
            stream.cap_block_steps(self.block_steps)
        self.started = True

    def add_stream(
        self,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int = 0,
        agent: str | None = None,
        time_limits: Sequence[TimeLimit[Any, Any]] = (),
        max_episode_steps: int | None = None,
        state: bool = False,
    ) -> Stream:
        """Register a stream's step and reset channels and return the stream.

        Truncations count as ``time_limit`` when one of ``time_limits`` (Gymnasium
        ``TimeLimit`` wrappers) says its limit was hit, or, without one, when the episode
        reached ``max_episode_steps``. ``state``: its reset rows have a ``state`` column
        (snapshots).
        """
        if self.started:
            raise RecorderError(f"{self.path}: streams are added before start()")
        stream = Stream(
            self,
            obs_codec,
            act_codec,
            env_index=env_index,
            agent=agent,
            time_limits=time_limits,
            max_episode_steps=max_episode_steps,
            state=state,
        )
        self.streams.append(stream)
        return stream

    @property
    def inherited(self) -> bool:
        """Whether this process is a fork of the one recording (:attr:`pid`)."""
        return os.getpid() != self.pid

    def check_open(self) -> None:
        """Raise :class:`RecorderError` when the file is closed, or its recorder's parent's."""
        if self.inherited:
            raise RecorderError(
                f"{self.path}: this process (pid {os.getpid()}) is a fork of the one recording "
                f"(pid {self.pid}), and the recorder records only there; create the recorder in "
                "this process (e.g. in the function that makes its env)"
            )
        if self.closed:
            raise RecorderError(
                f"{self.path}: the recorder is closed; create a new recorder to record more"
            )

    def take_episode_index(self) -> int:
        """The next file-global episode index."""
        index = self.next_episode
        self.next_episode += 1
        return index

    def due(self) -> bool:
        """Whether ``flush_every_s`` has passed since the last flush."""
        return self.clock() >= self.flush_at

    def trouble(self, exc: Exception) -> None:
        """Something failed inside the recorder itself: warn once, keep the loop running.

        The run-end record counts them and keeps the first (``recorder_trouble``), so the file
        says the evidence may miss what was being recorded then.
        """
        self.troubles += 1
        if self.first_trouble is None:
            self.first_trouble = error_text(exc)[:_TROUBLE_TEXT]
        if not self._warned:
            self._warned = True
            _warn_line(
                f"episode-audit: recording to {self.path} failed ({error_text(exc)}); "
                "the training loop continues and the file's run-end record says so"
            )

    # ------------------------------------------------------------------ episode records

    def _write_episodes(self) -> None:
        """Write the episodes ended since the last flush: JSON messages and one Arrow block."""
        ended = self.pending
        if ended:
            self.pending = []
            self.records.write(self.writer, ended, self.wall_offset)

    # ------------------------------------------------------------------ flushing, closing

    def flush(self, *, background: bool = False) -> None:
        """Write every stream's pending rows and the ended episodes' records, in one chunk.

        ``background``: the chunk is compressed and written while the caller goes on (see
        :meth:`EvidenceWriter.flush`); a failure there is the recorder's trouble, told by the
        next flush. A Ctrl-C meanwhile is raised once the flush is written
        (:func:`.signals.held`).
        """
        with signals.held():  # (a Ctrl-C halfway would drop rows already counted)
            try:
                for hook in self.before_flush:
                    hook()
                for stream in self.streams:
                    stream.write_blocks()
                self._write_episodes()
                self.writer.flush(background=background)
            finally:
                for exc in self.writer.take_failures():  # (an earlier background flush's)
                    self.trouble(exc)
        self.last_flush = self.clock()
        self.flush_at = self.last_flush + self.flush_ns
        if self.writer.newly_deleted():
            _warn_line(_DELETED.format(path=self.path))

    def end_with_error(
        self, streams: Iterable[Stream], exc: BaseException, during: str, action: Any = NO_ACTION
    ) -> None:
        """The env raised ``exc``: end the streams' open episodes as ``error``, written now.

        ``action``: the action of the step that raised, when the streams are one env's (its
        episode block keeps it for replay; see :meth:`~.endings.EpisodeEndings.end_error`).
        A failure here is the recorder's trouble (warned once): the loop then sees the env's
        own error, never one of the recorder's.
        """
        try:
            for stream in streams:
                stream.end_error(exc, during, action)
            self.flush()
        except Exception as trouble:
            self.trouble(trouble)

    def auto_flush(self, *, background: bool = True) -> None:
        """:meth:`flush` because a block filled or ``flush_every_s`` passed (``background``).

        This runs inside the training loop: a failure is the recorder's trouble (warned once),
        never the loop's. While :attr:`held`, it only notes that it is wanted (``flush_wanted``,
        in the background only if every call wanted it so): the recorder holding it calls it
        again once its step's rows are all in.
        """
        if self.held:
            wanted = self.flush_wanted
            self.flush_wanted = background and wanted is not False
            return
        self.flush_wanted = None
        try:
            self.flush(background=background)
        except Exception as exc:
            self.flush_at = self.clock() + self.flush_ns  # not again on every step
            self.trouble(exc)

    def close(self) -> None:
        """End every open episode as ``incomplete``, flush, and finish the file.

        A file whose path ``{index}`` claimed and that never held an episode is removed, so
        its index is free again. Safe to call more than once. Disk trouble does not raise: what
        could not be written is dropped and the run-end record says so; if even that cannot be
        written, the file ends after its last good flush (``episode-audit recover`` finishes it)
        and a warning says so.
        """
        if self.closed:
            return
        self.closed = True
        if self.inherited:  # (the parent's file, closed here at the fork: its lock kept)
            return
        with signals.held():  # (a Ctrl-C meanwhile is raised once the file is finished)
            self._finish()

    def _finish(self) -> None:
        """End the open episodes, flush, and write the footer (for :meth:`close`)."""
        if self._owner is not None:
            _OPEN_RECORDERS.discard(self._owner)
        try:
            for stream in self.streams:
                stream.end_open()
            self.flush()
        except OSError as exc:  # (kept staged: finishing writes it, or drops and counts it)
            self.trouble(exc)
        except BaseException:
            self.writer.abandon()
            raise
        if self.writer.indexed and self.next_episode == 0:
            # an {index} file that never held an episode gives its index back (gymnasium's
            # AsyncVectorEnv builds a sub-env it never steps): removed while still locked
            self.path.unlink(missing_ok=True)
        for _ in range(2):  # the second time with what the first could not write dropped
            try:
                self.writer.finish(run_end_record(self))
                return
            except OSError as exc:
                self.trouble(exc)
            except BaseException:
                self.writer.abandon()
                raise
        self.writer.abandon()
        _warn_line(
            f"episode-audit: {self.path} could not be finished ({self.first_trouble}); it ends "
            f"after its last good flush: `episode-audit recover {self.path}` finishes a copy"
        )


def _readable(metadata: dict[str, str]) -> dict[str, str]:
    """``metadata``, or :class:`ConfigurationError` if a value is larger than readers read.

    Such a file could not be read by any tool (``recover`` included), so it is not created.
    """
    for key, value in metadata.items():
        size = len(value.encode())
        if size > MAX_JSON_TEXT:
            advice = (
                "record an env whose space is smaller to describe (e.g. bounds that are the "
                "same in every dimension)"
                if key.endswith("_space")
                else "make it smaller"
            )
            raise ConfigurationError(
                f"run metadata {key!r}: {size} bytes of JSON, over the {MAX_JSON_TEXT} readers "
                f"accept, so no tool could read the file; {advice}"
            )
    return metadata


_DELETED = (
    "episode-audit: {path} was deleted while being recorded: what it held and what is recorded "
    "from now on are lost with it (the training loop continues)"
)


def _warn_line(message: str) -> None:
    """Warn ``message`` (a :class:`RecorderTroubleWarning`) as one line, without a source line."""
    import warnings

    # A location with no source: the warning prints as
    # "<episode-audit>:0: RecorderTroubleWarning: ...", never with a line of the recorder's code
    # (or the user's) under it.
    warnings.warn_explicit(
        message, RecorderTroubleWarning, "<episode-audit>", 0, module="episode_audit", registry={}
    )


_OPEN_RECORDERS: weakref.WeakSet[Any] = weakref.WeakSet()  # closed as the interpreter exits
_RECORDERS: weakref.WeakSet[FileRecorder] = weakref.WeakSet()  # every recorder opened here


def _after_fork_in_child() -> None:
    """A forked child neither steps, flushes, closes nor finishes its parent's files."""
    _OPEN_RECORDERS.clear()
    for recorder in list(_RECORDERS):
        recorder._inherited()
    _RECORDERS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


@atexit.register
def _close_open_recorders() -> None:
    """Finish files whose recorder was never closed when the interpreter exits normally."""
    for recorder in list(_OPEN_RECORDERS):
        try:
            recorder.close()
        except Exception:
            pass
