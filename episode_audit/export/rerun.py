"""Export an evidence file as a Rerun recording (``.rrd``), written with ``rerun-sdk``.

Timelines ``step`` (within the episode; -1 for its reset), ``episode`` and ``time`` (the step's
or reset's log time), and no other: rerun-sdk's own ``log_time`` (the export's wall clock) and
``log_tick`` are turned off. Each episode's reset comes first: its observation from
``reset()``. Per stream (``/env_N`` or ``/AGENT`` prefix in multi-stream files, none in
single-env ones): scalars ``steps/reward``, ``steps/terminated``, ``steps/truncated``,
``steps/terms/NAME``, ``steps/action[/ITEM]`` and ``steps/observation[/ITEM]`` (the plottable
fields) and images ``camera/FIELD`` (PNG). For the file: ``/log``, a text log line per ending
(failures and errors at level ERROR, truncations and cut-off episodes WARN, successes INFO).
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import ConfigurationError
from ..format.records import unstarted
from ..read import Evidence, open_evidence
from ..read.storage import as_source
from ._copied import CopiedPipe
from ._output import ViewerExport, local_file, missing, need_pillow, sdk_failure, staged
from ._values import (
    RESET_STEP,
    Leaf,
    Split,
    blocks,
    ending_text,
    frame_names,
    split_batch,
    streams,
)

__all__ = ["export_rerun"]

_LEVELS = {"success": "INFO", "failure": "ERROR", "error": "ERROR"}


def export_rerun(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
) -> ViewerExport:
    """Write ``source``'s steps, endings and camera frames to the Rerun recording ``out``.

    Raises :class:`~episode_audit.errors.ConfigurationError` when ``rerun-sdk`` is not
    installed (or Pillow, for a file with camera frames) or ``out`` cannot be written,
    :class:`~episode_audit.errors.EvidenceError` when ``source`` cannot be read; either way no
    ``out`` is left behind. ``source`` may be a URL (``s3://…``), read through ``filesystem``
    or one made with ``storage_options`` (``docs/storage.md``); ``out`` is a local path.
    """
    try:
        import rerun as rr
    except ImportError:
        raise missing("rerun-sdk", "rerun", needs=(3, 11)) from None
    source = as_source(source, filesystem=filesystem, storage_options=storage_options)
    out = local_file(out, "rerun")
    ev = open_evidence(source)
    need_pillow(ev, "rerun")
    unfinished = None if ev.finished else ev.torn or "no run-end record"
    result = ViewerExport(out, source, "rerun", unfinished=unfinished)
    try:
        with staged(
            source, out, overwrite=overwrite, overwrite_option=overwrite_option
        ) as temporary:
            try:
                writer = _write(rr, temporary, ev, result, progress)
            except (OSError, RuntimeError) as exc:  # (a failed write: a full disk …; the SDK's)
                raise sdk_failure(out, "rerun-sdk", exc) from None
            if temporary.stat().st_size == 0:  # a disabled SDK (RERUN=off in the environment)
                raise ConfigurationError(
                    f"{out}: rerun-sdk wrote nothing; is logging turned off (RERUN=off)?"
                )
    finally:
        _free_dropped_recordings()
    result.paths = sorted(writer.paths)
    result.left_out = sorted(writer.left_out)
    return result


def _write(
    rr: Any,
    path: Path,
    ev: Evidence,
    result: ViewerExport,
    progress: Callable[[int], None] | None,
) -> _Writer:
    """Write ``ev`` to a new recording saved at ``path``; the writer, which keeps no stream.

    The SDK's file writer writes into a pipe a thread of ours copies to ``path``
    (:class:`~._copied.CopiedPipe`): a failed write of its own (a full disk) can leave its
    flush waiting forever; ours is an ``OSError`` raised here.
    """
    rec = rr.RecordingStream("episode-audit", send_properties=False)
    rec.set_log_time_enabled(False)  # (the export's wall clock: no timeline of the episodes)
    rec.set_log_tick_enabled(False)
    copy = None
    try:
        copy = CopiedPipe(path)
        rec.save(copy.path)
    except (OSError, RuntimeError) as exc:  # (the folder was checked: rare)
        if copy is not None:
            with contextlib.suppress(OSError):
                copy.close()
        # (the path is the temporary file's or the pipe's)
        why = getattr(exc, "strerror", None) or str(exc).split(", path:")[0]
        raise sdk_failure(result.path, "rerun-sdk", exc, "create", why) from None
    copy.opened()
    rec.send_recording_name(result.source.name)
    writer = _Writer(rr, rec, ev, result)
    try:
        for reset, batch in blocks(ev):
            writer.batch(batch, reset=reset)
            copy.check()
            if progress is not None and not reset:
                progress(batch.num_rows)
        result.episodes = writer.endings()
        result.unstarted = int(unstarted(ev.episodes()).sum())
    except BaseException:
        with contextlib.suppress(RuntimeError):  # (the same failure, again, in closing)
            _close(rec)
        with contextlib.suppress(OSError):
            copy.close()
        raise
    finally:
        writer.rec = None  # (the stream is dropped with the last reference: _free_dropped_...)
    try:
        _close(rec)
    finally:
        copy.close()  # (a failed write: OSError)
    return writer


def _close(rec: Any) -> None:
    """Write what ``rec`` holds to its file, then end its file writer."""
    try:
        rec.flush()
    finally:
        rec.disconnect()


def _free_dropped_recordings() -> None:
    """End the threads of recording streams no one holds any more.

    rerun-sdk gives each ``RecordingStream`` two threads (its batcher and its sink) and ends
    them only in this sweep, which ``rr.init`` runs; one process exporting many files would
    otherwise keep two threads per file (tests/test_export_rerun.py counts them).
    """
    try:
        from rerun_bindings import flush_and_cleanup_orphaned_recordings
    except ImportError:  # (another layout of rerun-sdk: its threads stay until the process ends)
        return
    with contextlib.suppress(RuntimeError):  # (a failed stream's flush: its export said so)
        flush_and_cleanup_orphaned_recordings()


class _Writer:
    """Sends each block's columns to the recording, stream by stream."""

    def __init__(self, rr: Any, rec: Any, ev: Evidence, result: ViewerExport) -> None:
        self.rr, self.rec, self.ev, self.result = rr, rec, ev, result
        self.named = streams(ev)
        self.frame_names = frame_names(ev.steps_schema)
        self.part = rr.escape_entity_path_part  # (a "/" or a space in a name is the name's)
        self.prefix_of = self.named.prefix_of
        self.paths: set[str] = set()
        self.left_out: set[str] = set()

    def batch(self, batch: pa.RecordBatch, *, reset: bool) -> None:
        """Send a step block, or (``reset``) a reset block's observations at step -1."""
        episodes = batch.column("episode").to_numpy(zero_copy_only=False)
        prefixes = np.array([self.prefix_of.get(int(e), "") for e in episodes], dtype=object)
        names = ("observation",) if reset else ("action", "observation")
        splits = [split_batch(batch, name) for name in names]
        for split in splits:
            self.left_out.update(split.left_out)
        for prefix in sorted(set(prefixes.tolist())):
            rows = np.flatnonzero(prefixes == prefix)
            self._stream(prefix, batch, rows, splits, reset=reset)
        if reset:
            self.result.resets += batch.num_rows
        else:
            self.result.steps += batch.num_rows

    def _times(self, batch: pa.RecordBatch, rows: npt.NDArray[Any]) -> list[Any]:
        rr = self.rr
        column = batch.column

        def take(name: str) -> npt.NDArray[Any]:
            values = np.asarray(column(name).to_numpy(zero_copy_only=False))
            taken: npt.NDArray[Any] = values[rows]
            return taken

        if batch.schema.get_field_index("step") < 0:  # a reset block: before step 0
            step = np.full(len(rows), RESET_STEP, np.int64)
        else:
            step = take("step")
        return [
            rr.TimeColumn("step", sequence=step),
            rr.TimeColumn("episode", sequence=take("episode")),
            rr.TimeColumn("time", timestamp=take("time_ns").astype("datetime64[ns]")),
        ]

    def _send(self, path: str, batch: pa.RecordBatch, rows: npt.NDArray[Any], values: Any) -> None:
        if len(rows) == 0:
            return
        self.rec.send_columns(
            path, indexes=self._times(batch, rows), columns=self.rr.Scalars.columns(scalars=values)
        )
        self.paths.add(path)

    def _stream(
        self,
        prefix: str,
        batch: pa.RecordBatch,
        rows: npt.NDArray[Any],
        splits: list[Split],
        *,
        reset: bool,
    ) -> None:
        def numbers(name: str) -> npt.NDArray[Any]:
            array = pc.cast(batch.column(name), pa.float64())
            values = np.asarray(array.to_numpy(zero_copy_only=False), dtype=np.float64)
            taken: npt.NDArray[Any] = values[rows]
            return taken

        if not reset:
            for name in ("reward", "terminated", "truncated"):
                self._send(f"{prefix}/steps/{name}", batch, rows, numbers(name))
            self._terms(prefix, batch, rows)
        for split in splits:
            for leaf in split.leaves:
                self._leaf(prefix, batch, rows, leaf)
            for frames in split.images:
                self._frames(prefix, batch, rows, frames.path, frames.pixels, frames.present)

    def _terms(self, prefix: str, batch: pa.RecordBatch, rows: npt.NDArray[Any]) -> None:
        terms = batch.column("terms").take(pa.array(rows)).to_pylist()
        names = sorted({name for row in terms for name, _ in row or []})
        for name in names:
            present, values = [], []
            for i, row in enumerate(terms):
                value = dict(row or []).get(name)
                if value is not None:
                    present.append(rows[i])
                    values.append(value)
            path = f"{prefix}/steps/terms/{self.part(name)}"
            self._send(path, batch, np.array(present), np.array(values))

    def _leaf(self, prefix: str, batch: pa.RecordBatch, rows: npt.NDArray[Any], leaf: Leaf) -> None:
        keep = rows[leaf.present[rows]]
        path = "/".join(self.part(part) for part in leaf.path)
        values = leaf.numbers[keep].astype(np.float64)
        self._send(f"{prefix}/steps/{path}", batch, keep, values[:, 0] if leaf.scalar else values)

    def _frames(
        self,
        prefix: str,
        batch: pa.RecordBatch,
        rows: npt.NDArray[Any],
        path: tuple[str, ...],
        pixels: npt.NDArray[np.uint8],
        present: npt.NDArray[np.bool_],
    ) -> None:
        from PIL import Image

        keep = rows[present[rows]]
        if len(keep) == 0:
            return
        blobs = []
        for i in keep.tolist():
            png = io.BytesIO()
            Image.fromarray(pixels[i].squeeze()).save(png, format="png")
            blobs.append(png.getvalue())
        name = self.frame_names.get(path) or ".".join(path)
        entity = f"{prefix}/camera/{self.part(name)}"
        self.rec.send_columns(
            entity,
            indexes=self._times(batch, keep),
            columns=self.rr.EncodedImage.columns(blob=blobs, media_type=["image/png"] * len(blobs)),
        )
        self.paths.add(entity)
        self.result.frames += len(blobs)

    def endings(self) -> int:
        """A ``/log`` line per episode, at its end time; the number of episodes."""
        rr, rec = self.rr, self.rec
        records = self.ev.episodes().to_pylist()
        for record in records:
            end = record.get("end_time_ns") or record.get("start_time_ns")
            if end is None:
                continue
            who = self.named.name(self.prefix_of[record["episode"]])
            rec.set_time("time", timestamp=np.datetime64(end, "ns"))
            rec.set_time("episode", sequence=record["episode"])
            rec.set_time("step", sequence=max(record["length"] - 1, 0))
            level = getattr(rr.TextLogLevel, _LEVELS.get(record["outcome"], "WARN"))
            text = (f"{who} " if who else "") + ending_text(record)
            rec.log("/log", rr.TextLog(text, level=level))
            self.paths.add("/log")
        return len(records)
