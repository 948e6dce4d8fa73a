"""Recover a torn or damaged evidence file: rewrite it as a finished, indexed MCAP file.

A recorder killed before ``close()`` leaves a file without summary, footer or run-end record,
and perhaps a partial record at its end. :func:`recover` copies everything before the torn end —
the run metadata, every complete chunk with its schemas, channels and messages (times and
sequence numbers kept), chunk by chunk — into a new file through
:class:`~episode_audit.record.writer.EvidenceWriter`, which adds the message and chunk indexes, the
summary and the footer, and a run-end record with ``status=recovered`` saying what was dropped.

A chunk damaged after it was written (a CRC mismatch, a frame that does not decompress) is
skipped, as is, in a finished file, a stretch whose record framing is garbled (up to the next
record its summary locates); the result and the run-end record name the damaged stretches and
the episodes that lost evidence in them (:attr:`RecoveryResult.damaged_episodes`).

The input is never changed. The output is written to a temporary file next to ``out`` and
renamed into place only when it is finished, so a crash during recovery loses nothing; an
existing ``out`` is never replaced unless ``overwrite=True``, and never by the input itself.
A file that is already finished is copied unchanged.

>>> import tempfile, pathlib, gymnasium as gym, numpy as np
>>> from episode_audit import RecordEvidence
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> env = RecordEvidence(gym.make("Pendulum-v1"), d / "run.mcap", block_steps=8)
>>> _ = env.reset(seed=0)
>>> for _ in range(20):
...     _ = env.step(np.zeros(1, np.float32))
>>> data = (d / "run.mcap").read_bytes()   # 16 steps flushed; as a killed process leaves it
>>> _ = (d / "torn.mcap").write_bytes(data[:-10])
>>> env.close()
>>> result = recover(d / "torn.mcap", d / "fixed.mcap")
>>> result.lost, result.steps, result.cut_off_episodes
(True, 16, (0,))
>>> open_evidence(d / "fixed.mcap").run_end["status"]
'recovered'
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

import pyarrow.compute as pc
from mcap.records import Channel, Header, Message, Metadata, Schema

from ._version import __version__
from .errors import ConfigurationError, CorruptEvidenceError, EvidenceError
from .format import names as fmt
from .format.records import EpisodeRanges, listing
from .read import (
    _RECOVER_HINT,
    ChunkRecords,
    DamagedRegion,
    FileEnd,
    iter_records,
    open_evidence,
    step_block_rows,
    summary_definitions,
)
from .record.writer import EvidenceWriter

__all__ = ["RecoveryResult", "recover"]

# MCAP record kinds by opcode (https://mcap.dev/spec), to say what was cut off.
_RECORD_NAMES = {
    0x01: "header",
    0x02: "footer",
    0x03: "schema",
    0x04: "channel",
    0x05: "message",
    0x06: "chunk",
    0x07: "message index",
    0x08: "chunk index",
    0x09: "attachment",
    0x0A: "attachment index",
    0x0B: "statistics",
    0x0C: "metadata",
    0x0D: "metadata index",
    0x0E: "summary offset",
    0x0F: "data end",
}
# Cut records that hold no evidence: indexes and summary records (rebuilt by the writer),
# metadata (after the run metadata, which a file must have to be evidence at all, the only
# metadata written is the run-end record, which recovery writes anew), and schema and channel
# records outside chunks (the summary's copies).
_NOT_DATA = frozenset({0x02, 0x03, 0x04, 0x07, 0x08, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F})


@dataclass(frozen=True)
class RecoveryResult:
    """What :func:`recover` wrote and what it had to drop.

    Attributes:
        source: The torn input file (unchanged).
        output: The finished file written.
        already_finished: The input was finished: it was copied unchanged.
        chunks: Complete chunks copied (0 for a finished input, copied as a whole).
        messages: Messages copied (0 for a finished input).
        episodes: Episodes in the output (with or without an end record).
        steps: Step rows in the output.
        cut_off_episodes: Episodes without an end record (the kill cut them off): ``incomplete``.
        dropped_bytes: Bytes of the torn tail not copied (a partial record, or an unfinished
            summary).
        dropped_record: The kind of MCAP record cut off at the torn end (``chunk``,
            ``message index``, ``metadata``, ...), ``None`` if the file ended between records.
        dropped_at: The byte offset where the dropped tail starts (the input's size if none).
        closing: The torn file holds the recorder's run-end record: ``close()`` had flushed
            every step before the kill. Without it the recorder died mid-run, and the steps it
            took after its last flush (at most ``flush_every_s``) are in no file.
        damaged: Damaged chunks (a CRC mismatch, garbled records) and garbled stretches that
            were skipped, in file order.
        damaged_episodes: Episodes that lost part or all of their evidence (reset, steps or
            end record) in those chunks. Those still in the output are ``incomplete`` when
            their end record was lost; ``check`` reports each, and replay skips them.
        damaged_tail: Damage came after the last intact chunk of an unfinished file: episodes
            that began there left nothing behind, and cannot be counted.
        summary_damage: The input's summary section did not match its footer's CRC (what
            :attr:`~episode_audit.read.reader.Evidence.summary_damage` says); the output has a new
            one. The summary only repeats the data section: nothing is lost by it.
        run_end_damage: The input's run-end record was garbled (what
            :attr:`~episode_audit.read.reader.Evidence.run_end_damage` says); the output has a new
            one. ``close()`` had written every step and end record; the old record's status
            and counts are lost.
    """

    source: Path
    output: Path
    already_finished: bool
    chunks: int
    messages: int
    episodes: int
    steps: int
    cut_off_episodes: tuple[int, ...]
    dropped_bytes: int
    dropped_record: str | None
    dropped_at: int
    closing: bool = True
    damaged: tuple[DamagedRegion, ...] = ()
    damaged_episodes: EpisodeRanges = field(default_factory=EpisodeRanges)
    damaged_tail: bool = False
    summary_damage: str | None = None
    run_end_damage: str | None = None

    @property
    def data_dropped(self) -> bool:
        """Whether the dropped tail held evidence (a partial chunk, message or attachment)."""
        return self.dropped_record is not None and self.dropped_record not in _NOT_DATA_NAMES

    @property
    def lost(self) -> bool:
        """Whether anything was or may have been lost.

        A partial chunk, cut-off episodes, or the steps after the last flush of a recorder
        killed before ``close()``.
        """
        return (
            self.data_dropped
            or bool(self.cut_off_episodes)
            or not self.closing
            or bool(self.damaged)
        )

    @property
    def dropped(self) -> str:
        """What the recovery dropped or marked, in words (``nothing`` when nothing)."""
        parts = []
        if self.damaged:
            parts.append(_damage_words(self.damaged, self.damaged_episodes))
            if self.damaged_tail:
                parts.append(
                    "the damage follows the last intact chunk: episodes begun there cannot "
                    "be counted"
                )
        if self.dropped_bytes:
            what = f"a partial {self.dropped_record} record" if self.dropped_record else "bytes"
            parts.append(f"the last {self.dropped_bytes} bytes ({what} at byte {self.dropped_at})")
        if self.cut_off_episodes:
            cut = list(self.cut_off_episodes)
            parts.append(
                f"episode(s) {listing(cut, len(cut))} had no end record: recorded as incomplete"
            )
        if not self.closing:
            parts.append("the recorder was killed before close(): steps after its last flush")
        if self.summary_damage:
            parts.append(f"{self.summary_damage}: a new summary was written")
        if self.run_end_damage:
            parts.append(
                f"{self.run_end_damage}: its status and counts were lost, a new run-end record "
                "was written"
            )
        return "; ".join(parts) if parts else "nothing"

    def summary(self) -> str:
        """One line for people: what was written, and what was dropped."""
        if self.already_finished:
            return (
                f"{self.source} is already finished: copied unchanged to {self.output} "
                f"(nothing to recover)"
            )
        kept = (
            f"recovered {self.source} -> {self.output}: {self.episodes} episodes, "
            f"{self.steps} steps in {self.chunks} chunks"
        )
        if not self.lost:
            if self.run_end_damage:  # (its words say what the record held)
                return f"{kept}; no evidence lost ({self.dropped})"
            if self.summary_damage:
                return f"{kept}; nothing lost ({self.dropped})"
            tail = f"; dropped {self.dropped}" if self.dropped_bytes else ""
            return f"{kept}; nothing lost (the writer had not finished the file{tail})"
        return f"{kept}; dropped: {self.dropped}"


_NOT_DATA_NAMES = frozenset(_RECORD_NAMES[op] for op in _NOT_DATA)


def _damage_words(damaged: tuple[DamagedRegion, ...], episodes: EpisodeRanges) -> str:
    where = "; ".join(d.why for d in damaged[:3])
    more = f"; and {len(damaged) - 3} more" if len(damaged) > 3 else ""
    lost = (
        f": episode(s) {listing(episodes.first(5), episodes.count)} lost evidence in them"
        if episodes
        else " (no episode lost evidence in them)"
    )
    return f"{len(damaged)} damaged stretch(es) skipped ({where}{more}){lost}"


def recover(
    path: str | os.PathLike[str], out: str | os.PathLike[str], *, overwrite: bool = False
) -> RecoveryResult:
    """Rewrite the evidence file ``path`` as a finished, indexed file ``out``.

    Every complete, intact chunk is kept, with the run metadata; damaged chunks and the torn
    tail are dropped; the run-end record has ``status=recovered`` and says what was dropped
    (see ``docs/format.md``).
    Episodes without an end record stay ``incomplete`` (``ended`` false), as a reader of the
    torn file sees them. A finished, intact input is copied unchanged.

    Raises :class:`~episode_audit.errors.ConfigurationError` when ``out`` is the input, exists
    (without ``overwrite``) or cannot be created, and
    :class:`~episode_audit.errors.EvidenceError` (and its subclasses) when the input is not
    readable evidence.
    """
    src, dst = Path(path), Path(out)
    _check_paths(src, dst, overwrite)
    try:
        ev = open_evidence(src)
    except CorruptEvidenceError as exc:
        if not exc.problem.endswith(_RECOVER_HINT):
            raise
        # (an unfinished file: only its first chunk was read, for the channel definitions)
        raise CorruptEvidenceError(
            src,
            f"{exc.problem.removesuffix(_RECOVER_HINT)}: it holds the channel definitions and "
            "the file has no summary that repeats them, so no chunk can be decoded",
        ) from None
    tmp = dst.with_name(f".{dst.name}.{secrets.token_hex(4)}.recovering")
    try:
        if ev.finished and not (ev.summary_damage or ev.run_end_damage) and not _damage_in(src):
            try:
                shutil.copyfile(src, tmp)
            except OSError as exc:
                raise ConfigurationError(f"{tmp}: cannot write: {exc.strerror}") from None
            lengths = ev.episodes()["length"]
            steps = int(pc.sum(lengths).as_py() or 0)
            size = src.stat().st_size
            result = RecoveryResult(src, dst, True, 0, 0, len(lengths), steps, (), 0, None, size)
        else:
            result = _rewrite(src, tmp, dst, ev.summary_damage)
            check = open_evidence(tmp)
            if not check.finished:  # pragma: no cover - the writer finished it just now
                raise CorruptEvidenceError(tmp, f"the recovered file is unfinished: {check.torn}")
        _fsync(tmp)
        _publish(tmp, dst, overwrite)
    finally:
        tmp.unlink(missing_ok=True)
    return result


def _damage_in(path: Path) -> bool:
    """Whether a walk over the finished file ``path`` meets damage (every chunk checked)."""
    return any(isinstance(item, DamagedRegion) for item in iter_records(path, skip_damaged=True))


def _check_paths(src: Path, dst: Path, overwrite: bool) -> None:
    same = src.resolve() == dst.resolve()
    if not same and dst.exists() and src.exists():
        same = os.path.samefile(src, dst)
    if same:
        raise ConfigurationError(
            f"{dst}: the output is the input; recovery never rewrites a file in place — "
            "choose another output path"
        )
    if dst.is_dir():
        raise ConfigurationError(f"{dst}: is a directory; give the output file's path")
    if dst.exists() and not dst.is_file():
        raise ConfigurationError(
            f"{dst}: not a regular file (a device or a pipe); give the output file's path"
        )
    if dst.exists() and not overwrite:
        raise ConfigurationError(
            f"{dst}: file exists; recovery never overwrites it — choose another path or pass "
            "--overwrite"
        )


def _rewrite(src: Path, tmp: Path, dst: Path, summary_damage: str | None) -> RecoveryResult:
    """Copy ``src``'s complete, intact records into the new file ``tmp`` and finish it."""
    records = iter_records(src, skip_damaged=True)
    header = next(records)
    if not isinstance(header, Header):  # open_evidence found one: the walk does too
        raise CorruptEvidenceError(src, "the first record is not an MCAP header")
    writer = EvidenceWriter(tmp, library=header.library)
    try:
        copy = _Copy(src, writer)
        # A finished file repeats its schemas and channels in its summary: with them, chunks
        # after a damaged first chunk (which held the definitions) still decode.
        schemas, channels = summary_definitions(src)
        for record in [*schemas, *channels]:
            copy.record(record)
        end: FileEnd | None = None
        old_run_end: dict[str, str] | None = None
        run_end_damage: str | None = None  # the run-end record is there, but garbled
        damaged: list[DamagedRegion] = []
        for item in records:
            if isinstance(item, FileEnd):
                end = item
            elif isinstance(item, DamagedRegion):
                if item.metadata == fmt.METADATA_RUN_END:
                    run_end_damage = item.why
                else:
                    damaged.append(item)
            elif isinstance(item, Metadata):
                if item.name == fmt.METADATA_RUN_END:
                    old_run_end = dict(item.metadata)
                else:
                    writer.add_metadata(item.name, item.metadata)
            elif isinstance(item, ChunkRecords):
                for record in item.records:
                    copy.record(record)
                writer.flush()
                copy.chunks += 1
                copy.last_chunk = item.offset
            elif not isinstance(item, Header):
                copy.record(item)
        assert end is not None  # iter_records always ends with one
        writer.flush()
        # What the output holds so far (an unfinished file, read as a torn one) says which
        # episodes were cut off, and with damage, which lost evidence.
        damage: _Damage = ""
        if damaged:
            damage = "at the end" if damaged[-1].offset > copy.last_chunk else "inside"
        closed = old_run_end is not None or run_end_damage is not None  # close() ran
        try:
            kept = _Kept.of(tmp, damage, closed=closed, run_end=old_run_end or {})
        except EvidenceError as exc:  # what it copied from src: name src
            raise type(exc)(src, exc.problem) from None
        dropped = end.size - end.offset if not end.footer else 0
        kind = None
        if dropped and end.cut_opcode is not None:
            kind = _RECORD_NAMES.get(end.cut_opcode, f"unknown (opcode {end.cut_opcode:#04x})")
        result = RecoveryResult(
            src,
            dst,
            False,
            copy.chunks,
            copy.messages,
            kept.episodes,
            copy.steps,
            kept.cut_off,
            dropped,
            kind,
            end.size - dropped,
            closed,
            tuple(damaged),
            kept.damaged,
            damage == "at the end" and not closed,
            summary_damage,
            run_end_damage,
        )
        last = (old_run_end or {}).get("end_time")
        writer.finish(
            {
                "status": fmt.RUN_STATUS_RECOVERED,
                "episodes": str(kept.episodes),
                "steps": str(copy.steps),
                "blocks": str(copy.blocks),
                "end_time": last or _iso(copy.last_time),
                "recovered_from": str(src),
                "recovered_by": f"episode-audit {__version__}",
                "recovered_time": datetime.now(timezone.utc).isoformat(),
                "dropped": result.dropped,
                "dropped_bytes": str(dropped),
                "cut_off_episodes": json.dumps(list(kept.cut_off)),
                "damaged": json.dumps(
                    [{"offset": d.offset, "length": d.length, "why": d.why} for d in damaged]
                ),
                "damaged_episodes": kept.damaged.to_json(),
                # (counted over the original's episodes: whether its task reports success)
                **{
                    key: value
                    for key, value in (old_run_end or {}).items()
                    if key == fmt.RUN_END_SUCCESS_REPORTED
                },
            }
        )
    except BaseException:
        writer.abandon()
        raise
    return result


_Damage = Literal["", "inside", "at the end"]
"""Where a recovery met damage: nowhere, before an intact chunk, or after the last one."""


def _cut_off_of(run_end: dict[str, str]) -> set[int]:
    """The episodes a recovery's run-end record lists as cut off (none if it does not parse)."""
    try:
        listed = json.loads(run_end.get("cut_off_episodes") or "[]")
    except ValueError:
        return set()
    if not isinstance(listed, list):
        return set()
    return {e for e in listed if isinstance(e, int) and not isinstance(e, bool)}


@dataclass(frozen=True)
class _Kept:
    """The episodes of a recovery's output: how many, which were cut off, which damaged."""

    episodes: int
    cut_off: tuple[int, ...]
    damaged: EpisodeRanges

    @classmethod
    def of(cls, path: Path, damage: _Damage, *, closed: bool, run_end: dict[str, str]) -> _Kept:
        """Read the (still unfinished) output ``path``.

        ``closed``: the input has a run-end record (intact or garbled), so ``close()`` ran;
        ``run_end``: that record's values, when it could be read (else empty). A recovered
        input's record lists the episodes its torn original had cut off: they stay cut off.

        Without damage, the episodes without an end record were cut off by the torn end. With
        damage, an episode lost evidence when its end record is missing but a later episode
        of its stream began (only a stream's last episode can be cut off), its reset row is
        missing, it has fewer step rows than its record says, its step indices have a gap, or
        it is missing altogether (indices are 0, 1, ... in a file; a finished input's run-end
        record says how many). An episode without an end record counts as damaged, not cut
        off, when the input was ``closed`` (``close()`` wrote every end record) or the
        ``damage`` comes after the last intact chunk.
        """
        ev = open_evidence(path)
        table = ev.episodes()
        index = table.column(fmt.COL_EPISODE).to_pylist()
        ended = table.column("ended").to_pylist()
        if not damage:
            cut = tuple(e for e, done in zip(index, ended, strict=True) if not done)
            return cls(len(index), cut, EpisodeRanges())
        streams = zip(
            table.column("env_index").to_pylist(), table.column("agent").to_pylist(), strict=True
        )
        last: dict[tuple[Any, Any], int] = {}
        for e, stream in zip(index, streams, strict=True):
            last[stream] = max(last.get(stream, e), e)
        # After close() (its run-end record is there, even garbled) no episode is cut off —
        # but those a recovery's record lists: a recovered input's cut-off episodes were cut
        # off by the torn original, and stay so. Nor, when damage follows the last intact
        # chunk, can a missing end record be told from a lost one.
        finals = set() if closed or damage == "at the end" else set(last.values())
        if run_end.get("status") == fmt.RUN_STATUS_RECOVERED:
            finals |= _cut_off_of(run_end)
        cut = tuple(e for e, done in zip(index, ended, strict=True) if not done and e in finals)
        lost = {e for e, done in zip(index, ended, strict=True) if not done and e not in finals}
        resets = set(ev.resets().column(fmt.COL_EPISODE).to_pylist())
        lost.update(e for e in index if e not in resets)
        rows = (
            ev.steps(columns=[fmt.COL_EPISODE, fmt.COL_STEP])
            .group_by(fmt.COL_EPISODE)
            .aggregate([(fmt.COL_STEP, "count"), (fmt.COL_STEP, "min"), (fmt.COL_STEP, "max")])
        )
        counts: dict[int, int] = {}
        for e, n, low, high in zip(
            rows.column(fmt.COL_EPISODE).to_pylist(),
            rows.column(f"{fmt.COL_STEP}_count").to_pylist(),
            rows.column(f"{fmt.COL_STEP}_min").to_pylist(),
            rows.column(f"{fmt.COL_STEP}_max").to_pylist(),
            strict=True,
        ):
            counts[e] = n
            if low != 0 or high != n - 1:
                lost.add(e)
        for e, done, length in zip(index, ended, table.column("length").to_pylist(), strict=True):
            if done and counts.get(e, 0) < (length or 0):
                lost.add(e)
        known = sorted(set(index) | set(counts) | resets)
        try:
            total = int(run_end.get("episodes", "0"))
        except ValueError:
            total = 0
        # the indices no evidence is left of: the gaps, and after the last one kept
        gaps, previous = [], -1
        for e in [*known, max(total, known[-1] + 1 if known else 0)]:
            if e > previous + 1:
                gaps.append((previous + 1, e - 1))
            previous = max(previous, e)
        return cls(len(index), cut, EpisodeRanges.of(lost, gaps))


class _Copy:
    """Schemas, channels and messages copied so far, with the old-to-new id maps."""

    def __init__(self, src: Path, writer: EvidenceWriter) -> None:
        self.src = src
        self.writer = writer
        self.schemas: dict[int, int] = {0: 0}
        self.channels: dict[int, int] = {}
        self.steps_channels: set[int] = set()
        self.chunks = self.messages = self.steps = self.blocks = 0
        self.last_time = 0
        self.last_chunk = -1  # the offset of the last chunk copied

    def record(self, record: object) -> None:
        writer = self.writer
        if isinstance(record, Message):
            channel = self.channels.get(record.channel_id)
            if channel is None:
                raise CorruptEvidenceError(
                    self.src, f"a message on unknown channel {record.channel_id}"
                )
            writer.write_message(
                channel, record.data, record.log_time, record.publish_time, record.sequence
            )
            self.messages += 1
            self.last_time = max(self.last_time, record.log_time)
            if channel in self.steps_channels:
                self.steps += step_block_rows(record.data, self.src)
                self.blocks += 1
        elif isinstance(record, Schema) and record.id not in self.schemas:
            self.schemas[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = self.schemas.get(record.schema_id)
            if schema is None:
                raise CorruptEvidenceError(
                    self.src, f"channel {record.topic!r} names unknown schema {record.schema_id}"
                )
            new = writer.register_channel(
                record.topic, record.message_encoding, schema, record.metadata
            )
            self.channels[record.id] = new
            if record.topic == fmt.TOPIC_STEPS:
                self.steps_channels.add(new)


def _iso(time_ns: int) -> str:
    return datetime.fromtimestamp(time_ns / 1e9, timezone.utc).isoformat()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _publish(tmp: Path, dst: Path, overwrite: bool) -> None:
    """Move the finished ``tmp`` to ``dst`` atomically; never over a file unless asked."""
    link: Callable[[Path, Path], None] = os.replace if overwrite else os.link
    try:
        link(tmp, dst)
    except FileExistsError:
        raise ConfigurationError(
            f"{dst}: file exists; recovery never overwrites it — choose another path or pass "
            "--overwrite"
        ) from None
    except OSError as exc:
        if overwrite or dst.exists():
            raise ConfigurationError(f"{dst}: cannot write: {exc.strerror}") from None
        os.replace(tmp, dst)  # a file system without hard links
    try:
        fd = os.open(dst.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
