"""Export an evidence file as a Foxglove-ready MCAP file, written with ``foxglove-sdk``.

Per stream (``/env_N`` or ``/AGENT`` prefix in multi-stream files, none in single-env ones):
``steps`` (JSON with a JSON Schema: episode, step, reward, terms, terminated, truncated and the
plottable action and observation fields, one message per step at its log time, each episode's
reset before them: ``step`` -1 and its observation only, at the reset's time) and
``camera/FIELD`` (``foxglove.CompressedImage`` PNG frames of image observations). For the file:
``/episodes`` (``foxglove.Event`` per episode, its time range and outcome) and ``/log``
(``foxglove.Log`` per ending: failures and errors as errors, truncations and cut-off episodes as
warnings, successes as info). Topics, the layout file and why this library: docs/viewers.md.
"""

from __future__ import annotations

import bisect
import contextlib
import heapq
import io
import json
import logging
import os
from collections.abc import Callable, Iterator
from operator import itemgetter
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.records import unstarted
from ..read import Evidence, open_evidence
from ..read.storage import Source, as_source
from ._output import ViewerExport, local_file, missing, need_pillow, sdk_failure, staged
from ._values import (
    NONFINITE_NULL,
    RESET_STEP,
    Frames,
    Split,
    Streams,
    chunk_blocks,
    ending_text,
    finite,
    frame_names,
    json_rows,
    json_schema,
    split_batch,
    streams,
)

__all__ = ["STEP_SCHEMA_NAME", "export_foxglove"]

STEP_SCHEMA_NAME: Final = "episode_audit.Step"
"""The JSON Schema name of the ``steps`` topics."""
_STEP: Final = (
    f"the step's index in its episode, from 0; {RESET_STEP}: the episode's reset, the "
    "observation it starts from (no action, reward, terms or flags)"
)
"""The description of ``step`` in the ``steps`` topics' JSON Schema."""
_LEVELS: Final = {"success": "Info", "failure": "Error", "error": "Error"}
"""Log level by outcome; any other (``truncated``, ``incomplete``) is a warning."""


def export_foxglove(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ViewerExport:
    """Write ``source``'s steps, endings and camera frames to ``out`` for Foxglove.

    Raises :class:`~episode_audit.errors.ConfigurationError` when ``foxglove-sdk`` is not
    installed (or Pillow, for a file with camera frames) or ``out`` cannot be written,
    :class:`~episode_audit.errors.EvidenceError` when ``source`` cannot be read; either way no
    ``out`` is left behind. ``source`` may be a URL (``s3://…``), read through ``filesystem``
    or one made with ``storage_options`` (``docs/storage.md``); ``out`` is a local path.
    """
    try:
        import foxglove
    except ImportError:
        raise missing("foxglove", "foxglove") from None
    source = as_source(source, filesystem=filesystem, storage_options=storage_options)
    out = local_file(out, "foxglove")
    ev = open_evidence(source)
    need_pillow(ev, "foxglove")
    result = ViewerExport(out, source, "foxglove", unfinished=_unfinished(ev))
    staging = staged(source, out, overwrite=overwrite, overwrite_option=overwrite_option)
    with staging as temporary, _failed_writes() as failed:
        context = foxglove.Context()
        options = foxglove.mcap.MCAPWriteOptions(compression_threads=0)
        writer = _open(foxglove, temporary, out, context, options)
        try:
            try:
                writer.write_metadata(fmt.METADATA_EXPORT, _metadata(ev, source))
                named = streams(ev)
                order = _InOrder(_endings(foxglove, context, ev, named, result), failed)
                _Steps(foxglove, context, ev, named, result, order).write(progress)
                result.paths += ["/episodes", "/log"]
            except BaseException:
                # closed (else the SDK panics as it drops it at exit); its error in closing,
                # the same failure again, is not raised
                with contextlib.suppress(RuntimeError):
                    writer.close()
                raise
            writer.close()
        except RuntimeError as exc:
            failure = _sdk_failure(out, exc)
            if failure is None:
                raise
            raise failure from None
    result.paths.sort()
    return result


def _sdk_failure(out: Path, exc: RuntimeError) -> ConfigurationError | None:
    """The one-line error for foxglove-sdk's own error ``exc`` writing ``out``.

    The SDK's error is a ``FoxgloveError``, or a write it failed (:class:`_WriteFailed`). A
    disk with no space left says so (:func:`~episode_audit.record.published.no_space`); any
    other failure of the SDK's is said as the SDK says it. ``None``: not the SDK's error.
    """
    if not isinstance(exc, _WriteFailed) and not str(exc).startswith("FoxgloveError"):
        return None
    return sdk_failure(out, "foxglove-sdk", exc)


class _WriteFailed(RuntimeError):
    """A message foxglove-sdk failed to write (its log line is the error's text)."""


class _FailedWrites(logging.Filter):
    """foxglove-sdk's log records of messages it failed to write: kept, not printed.

    The SDK does not raise a failed write: it logs it, for every message after it too —
    hundreds of lines on a full disk — on its ``foxglove.log_sink_set`` logger, a warning:
    ``error logging message: {error:?}`` (``rust/foxglove/src/log_sink_set.rs``), the error
    of an MCAP writer's sink being ``McapError(…)`` (``McapError(Io(Os { code: 28, kind:
    StorageFull, … }))``) or ``SinkClosed`` (:data:`FAILED`). :meth:`check` raises the first,
    as :class:`_WriteFailed`. Any other record on that logger is passed on as it is.
    """

    LOGGER: Final = "foxglove.log_sink_set"
    FAILED: Final = ("error logging message: McapError(", "error logging message: SinkClosed")

    def __init__(self) -> None:
        super().__init__()
        self.first: str | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        try:
            message = record.getMessage()
        except Exception:  # (a record whose arguments do not format: not the SDK's)
            return True
        if not message.startswith(self.FAILED):
            return True
        if self.first is None:
            self.first = message
        return False

    def check(self) -> None:
        """Raise :class:`_WriteFailed` if a write failed."""
        if self.first is not None:
            raise _WriteFailed(self.first)


@contextlib.contextmanager
def _failed_writes() -> Iterator[_FailedWrites]:
    """Keep foxglove-sdk's failed-write lines while in the block (:class:`_FailedWrites`)."""
    logger = logging.getLogger(_FailedWrites.LOGGER)
    failed = _FailedWrites()
    logger.addFilter(failed)
    try:
        yield failed
    finally:
        logger.removeFilter(failed)


def _open(foxglove: Any, temporary: Path, out: Path, context: Any, options: Any) -> Any:
    """The SDK's MCAP writer on ``temporary`` (made by :func:`staged`: it exists, empty)."""
    try:
        return foxglove.open_mcap(
            temporary, allow_overwrite=True, context=context, writer_options=options
        )
    except (OSError, RuntimeError) as exc:  # (the folder was checked: rare)
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise ConfigurationError(f"{out}: foxglove-sdk cannot create it: {why}") from None


def _unfinished(ev: Evidence) -> str | None:
    return None if ev.finished else ev.torn or "no run-end record"


def _metadata(ev: Evidence, source: Source) -> dict[str, str]:
    run = ev.run
    return {
        "source": str(source),
        "env_id": run.env_id or "",
        "tags": json.dumps(run.tags, sort_keys=True),
        "layout": json.dumps(run.layout, sort_keys=True),
        "start_time": run.start_time,
    }


class _Steps:
    """The ``steps`` and ``camera/*`` topics of every stream, written block by block."""

    def __init__(
        self,
        foxglove: Any,
        context: Any,
        ev: Evidence,
        named: Streams,
        result: ViewerExport,
        order: _InOrder,
    ) -> None:
        self.fg, self.context, self.ev, self.result = foxglove, context, ev, result
        self.hold = order.hold
        self.order = order
        self.named, self.prefix_of = named, named.prefix_of
        self.terms = sorted(
            {
                name
                for totals in ev.episodes().column("term_totals").to_pylist()
                for name, _ in totals or []
            }
        )
        # The message schema comes from the file's step schema (every stream's blocks have
        # it), not from the first block: a stream's reset may come before its first step.
        none = pa.RecordBatch.from_pylist([], schema=ev.steps_schema)
        action, observation = split_batch(none, "action"), split_batch(none, "observation")
        self.schema = json.dumps(_step_schema(self.terms, action, observation)).encode()
        self.frame_names = frame_names(ev.steps_schema)
        self.channels: dict[str, Any] = {}
        self.images: dict[str, Any] = {}

    def write(self, progress: Callable[[int], None] | None) -> None:
        """Write every chunk's resets, steps and frames, each chunk's in log-time order."""
        left_out: set[str] = set()
        for chunk in chunk_blocks(self.ev):
            for reset, batch in chunk:
                observation = split_batch(batch, "observation")
                left_out.update(observation.left_out)
                if reset:
                    self.result.resets += self._write_resets(batch, observation)
                    images = observation.images
                else:
                    action = split_batch(batch, "action")
                    left_out.update(action.left_out)
                    self.result.steps += self._write_batch(batch, action, observation)
                    if progress is not None:
                        progress(batch.num_rows)
                    images = action.images + observation.images
                for frames in images:
                    self._write_frames(batch, frames)
            self.order.write()
        self.order.write(last=True)
        self.result.left_out = sorted(left_out)

    def _log(self, episode: int) -> Callable[[bytes, int], None]:
        """The function logging a message on the ``steps`` topic of ``episode``'s stream."""
        prefix = self.prefix_of.get(episode, "")
        channel = self.channels.get(prefix)
        if channel is None:
            channel = self.fg.Channel(
                f"{prefix}/steps",
                schema=self.fg.Schema(
                    name=STEP_SCHEMA_NAME, encoding="jsonschema", data=self.schema
                ),
                message_encoding="json",
                context=self.context,
                metadata=self._agent(prefix),
            )
            self.channels[prefix] = channel
            self.result.paths.append(f"{prefix}/steps")
        log: Callable[[bytes, int], None] = channel.base.log
        return log

    def _agent(self, prefix: str) -> dict[str, str] | None:
        """A PettingZoo agent's channel metadata: its name (its prefix may be changed)."""
        agent = self.named.agent_at.get(prefix)
        return None if agent is None else {"agent": agent}

    def _write_resets(self, batch: pa.RecordBatch, observation: Split) -> int:
        """Write the block's resets as messages of step :data:`RESET_STEP`; returns how many."""
        episodes = batch.column("episode").to_pylist()
        times = batch.column("time_ns").to_pylist()
        observations = json_rows(observation.leaves, batch.num_rows)
        dumps = json.JSONEncoder(allow_nan=False, separators=(",", ":")).encode
        written = 0
        for episode, time, values in zip(episodes, times, observations, strict=True):
            if not _in_range(time):  # (not from our recorder)
                self.result.out_of_range += 1
                continue
            message: dict[str, Any] = {"episode": episode, "step": RESET_STEP}
            if values is not None:
                message["observation"] = values
            self.hold(time, self._log(episode), dumps(message).encode())
            written += 1
        return written

    def _write_batch(self, batch: pa.RecordBatch, action: Split, observation: Split) -> int:
        """Write the batch's steps; returns how many (a time out of range leaves one out)."""
        n = batch.num_rows
        episodes = batch.column("episode").to_pylist()
        steps = batch.column("step").to_pylist()
        times = batch.column("time_ns").to_pylist()
        rewards = batch.column("reward").to_pylist()
        terms = batch.column("terms").to_pylist()
        terminated = pc.cast(batch.column("terminated"), pa.int8()).to_pylist()
        truncated = pc.cast(batch.column("truncated"), pa.int8()).to_pylist()
        actions = json_rows(action.leaves, n)
        observations = json_rows(observation.leaves, n)
        logs: dict[int, Callable[[bytes, int], None]] = {}
        hold = self.hold
        dumps = json.JSONEncoder(allow_nan=False, separators=(",", ":")).encode
        left_out = 0
        every_time_fits = _all_in_range(batch.column("time_ns"))  # (else look at each row)
        for i in range(n):
            if not every_time_fits and not _in_range(times[i]):  # (not from our recorder)
                self.result.out_of_range += 1
                left_out += 1
                continue
            episode = episodes[i]
            log = logs.get(episode)
            if log is None:
                log = logs[episode] = self._log(episode)
            message: dict[str, Any] = {
                "episode": episode,
                "step": steps[i],
                "reward": rewards[i],
                "terminated": terminated[i],
                "truncated": truncated[i],
            }
            if terms[i]:
                message["terms"] = dict(terms[i])
            if actions[i] is not None:
                message["action"] = actions[i]
            if observations[i] is not None:
                message["observation"] = observations[i]
            try:
                data = dumps(message)
            except ValueError:  # a NaN or infinite reward or term: JSON has no such number
                message["reward"] = finite([rewards[i]])[0]
                if "terms" in message:
                    message["terms"] = dict(
                        zip(message["terms"], finite(list(message["terms"].values())), strict=True)
                    )
                data = dumps(message)
            hold(times[i], log, data.encode())
        return int(n) - left_out

    def _write_frames(self, batch: pa.RecordBatch, frames: Frames) -> None:
        from PIL import Image

        messages = self.fg.messages
        episodes = batch.column("episode").to_pylist()
        times = batch.column("time_ns").to_pylist()
        name = self.frame_names.get(frames.path) or ".".join(frames.path)
        every_time_fits = _all_in_range(batch.column("time_ns"))
        for i in np.flatnonzero(frames.present).tolist():
            if not every_time_fits and not _in_range(times[i]):  # (counted with its step)
                continue
            prefix = self.prefix_of.get(episodes[i], "")
            topic = f"{prefix}/camera/{name}"
            log = self.images.get(topic)
            if log is None:
                channel = self.fg.channels.CompressedImageChannel(
                    topic, context=self.context, metadata=self._agent(prefix)
                )
                log = self.images[topic] = _log_of(channel)
                self.result.paths.append(topic)
            png = io.BytesIO()
            Image.fromarray(frames.pixels[i].squeeze()).save(png, format="png")
            message = messages.CompressedImage(
                timestamp=_timestamp(messages, times[i]),
                frame_id=name,
                data=png.getvalue(),
                format="png",
            )
            self.hold(times[i], log, message)
            self.result.frames += 1


def _step_schema(terms: list[str], action: Split, observation: Split) -> dict[str, Any]:
    """The JSON Schema of a ``steps`` message (Foxglove reads field types from it)."""
    properties: dict[str, Any] = {
        "episode": {"type": "integer"},
        "step": {"type": "integer", "description": _STEP},
        "reward": {"type": "number", "description": NONFINITE_NULL},
        "terminated": {"type": "integer", "description": "1 if terminated"},
        "truncated": {"type": "integer", "description": "1 if truncated"},
    }
    if terms:
        properties["terms"] = {
            "type": "object",
            "properties": {
                name: {"type": "number", "description": NONFINITE_NULL} for name in terms
            },
        }
    for name, split in (("action", action), ("observation", observation)):
        schema = json_schema(split.leaves)
        if schema is not None:
            properties[name] = schema
    return {"title": STEP_SCHEMA_NAME, "type": "object", "properties": properties}


_LAST_NS = (1 << 32) * 1_000_000_000 - 1
"""The latest time a ``foxglove.Timestamp`` holds (its seconds are 32 bits: early 2106)."""


def _in_range(ns: Any) -> bool:
    """Whether ``ns`` is a time a Foxglove message can have (1970 to 2106, in ns)."""
    return type(ns) is int and 0 <= ns <= _LAST_NS


def _all_in_range(times: pa.Array) -> bool:
    """Whether every time of a block is one a Foxglove message can have (one pass in C)."""
    low, high = pc.min_max(times).values()
    return low.as_py() is not None and low.as_py() >= 0 and high.as_py() <= _LAST_NS


def _timestamp(messages: Any, ns: int) -> Any:
    return messages.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _endings(
    foxglove: Any, context: Any, ev: Evidence, named: Streams, result: ViewerExport
) -> list[tuple[int, Callable[[Any, int], None], Any]]:
    """Per episode, its ``foxglove.Event`` (``/episodes``) and ``foxglove.Log`` (``/log``).

    As ``(time, log, message)`` to write: the event at the episode's start, the log at its end.

    Counted in ``result.episodes`` (and ``result.unstarted``); an episode without a time, or
    whose times no Foxglove timestamp holds (a file not from our recorder), is left out and
    counted in ``result.out_of_range``.
    """
    messages, channels = foxglove.messages, foxglove.channels
    events = _log_of(channels.EventChannel("/episodes", context=context))
    logs = _log_of(channels.LogChannel("/log", context=context))
    out: list[tuple[int, Callable[[Any, int], None], Any]] = []
    table = ev.episodes()
    for record, idle in zip(table.to_pylist(), unstarted(table).tolist(), strict=True):
        start, end = record.get("start_time_ns"), record.get("end_time_ns")
        end = end if end is not None else start
        start = start if start is not None else end
        if not (_in_range(start) and _in_range(end)):  # (no time at all is not one either)
            result.out_of_range += 1
            continue
        prefix = named.prefix_of[record["episode"]]
        who = named.name(prefix)
        pairs = {
            "episode": record["episode"],
            "outcome": record["outcome"],
            "label": record.get("failure_label") or record.get("truncation_reason") or "",
            "seed": "" if record.get("seed") is None else record["seed"],
            "length": record["length"],
            "return": record.get("return"),
            "stream": prefix.lstrip("/"),
        }
        if record.get("agent"):
            pairs["agent"] = record["agent"]
        event = messages.Event(
            start_time=_timestamp(messages, start),
            end_time=_timestamp(messages, end),
            metadata=[messages.KeyValuePair(key=k, value=str(v)) for k, v in pairs.items()],
        )
        level = getattr(messages.LogLevel, _LEVELS.get(record["outcome"], "Warning"))
        ending = messages.Log(
            timestamp=_timestamp(messages, end),
            level=level,
            message=(f"{who} " if who else "") + ending_text(record),
            name=who or "episode_audit",
        )
        out += [(start, events, event), (end, logs, ending)]
        result.episodes += 1
        result.unstarted += idle
    return out


def _log_of(channel: Any) -> Callable[[Any, int], None]:
    """The function logging a message on ``channel`` (a typed one) at a log time."""

    def log(message: Any, time: int) -> None:
        channel.log(message, log_time=time)

    return log


_BY_TIME = itemgetter(0, 1)


class _InOrder:
    """The messages of one evidence chunk, held, then written in log-time order.

    A chunk's reset blocks come before its step blocks in the evidence file, and the episodes'
    events and ending logs are known from the start; the recorder's chunks do not overlap in
    time (a flush writes the rows since the last one). So each chunk's messages are sorted by
    log time (ties in the order held) and merged with the ``endings`` due by the chunk's last
    one: the file's messages are in log-time order, and Foxglove reads its chunks one after the
    other. One chunk's messages are held at a time.
    """

    def __init__(
        self,
        endings: list[tuple[int, Callable[[Any, int], None], Any]],
        failed: _FailedWrites,
    ) -> None:
        self.failed = failed
        self.endings = sorted(
            ((time, k, log, message) for k, (time, log, message) in enumerate(endings)),
            key=_BY_TIME,
        )
        self.times = [ending[0] for ending in self.endings]
        self.next = 0
        self.held: list[tuple[int, int, Callable[[Any, int], None], Any]] = []

    def hold(self, time: int, log: Callable[[Any, int], None], message: Any) -> None:
        """Hold ``message``, to be written by ``log`` at ``time``."""
        self.held.append((time, len(self.held), log, message))

    def write(self, *, last: bool = False) -> None:
        """Write the held messages and the endings due by then (``last``: every ending left)."""
        self.held.sort(key=_BY_TIME)
        if last:
            until = len(self.endings)
        elif self.held:
            until = bisect.bisect_right(self.times, self.held[-1][0], lo=self.next)
        else:
            return
        due = self.endings[self.next : until]
        self.next = until
        for time, _, log, message in heapq.merge(due, self.held, key=itemgetter(0)):
            log(message, time)
        self.held.clear()
        self.failed.check()  # (the SDK logs a failed write: the export stops at the first)
