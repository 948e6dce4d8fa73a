"""What a recovery wrote and what it had to drop (:class:`RecoveryResult`), in words."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..format.records import EpisodeRanges, listing
from ..read import DamagedRegion
from ..read.storage import Source

__all__ = ["RecoveryResult", "record_name"]

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
CLOSING_MAGIC = "closing magic"
"""What a dropped tail was when it is the file's closing magic bytes (after a damaged footer)."""
_NOT_DATA_NAMES = frozenset({*(_RECORD_NAMES[op] for op in _NOT_DATA), CLOSING_MAGIC})


def record_name(opcode: int) -> str:
    """The kind of MCAP record an opcode starts.

    >>> record_name(0x06), record_name(0x7F)
    ('chunk', 'unknown (opcode 0x7f)')
    """
    return _RECORD_NAMES.get(opcode, f"unknown (opcode {opcode:#04x})")


@dataclass(frozen=True)
class RecoveryResult:
    """What :func:`~episode_audit.recover.recover` wrote and what it had to drop.

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
            :attr:`~episode_audit.read.Evidence.summary_damage` says); the output has a new
            one. The summary only repeats the data section: nothing is lost by it.
        run_end_damage: The input's run-end record was garbled (what
            :attr:`~episode_audit.read.Evidence.run_end_damage` says); the output has a new
            one. ``close()`` had written every step and end record; the old record's status
            and counts are lost.
    """

    source: Source
    output: Source
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

        A partial chunk, cut-off episodes, or the steps after the last flush of a file its
        recorder never finished (killed before ``close()``, or a ``close()`` refused by the OS).
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
        parts = _damage_parts(self) + _tail_parts(self)
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
            f"recovered {self.source} -> {self.output}: {self.episodes} "
            f"episode{'s' if self.episodes != 1 else ''}, {self.steps} "
            f"step{'s' if self.steps != 1 else ''} in {self.chunks} "
            f"chunk{'s' if self.chunks != 1 else ''}"
        )
        if not self.lost:
            if self.run_end_damage:  # (its words say what the record held)
                return f"{kept}; no evidence lost ({self.dropped})"
            if self.summary_damage:
                return f"{kept}; nothing lost ({self.dropped})"
            tail = f"; dropped {self.dropped}" if self.dropped_bytes else ""
            # (not lost: close() ran, its run-end record is there; what follows was cut)
            why = "close() had written the run-end record; the summary after it was cut"
            return f"{kept}; nothing lost ({why}{tail})"
        return f"{kept}; dropped: {self.dropped}"


def _damage_parts(result: RecoveryResult) -> list[str]:
    """The damaged stretches skipped, and the episodes that lost evidence in them."""
    if not result.damaged:
        return []
    damaged, episodes = result.damaged, result.damaged_episodes
    where = "; ".join(d.why for d in damaged[:3])
    more = f"; and {len(damaged) - 3} more" if len(damaged) > 3 else ""
    lost = (
        f": episode(s) {listing(episodes.first(5), episodes.count)} lost evidence in them"
        if episodes
        else " (no episode lost evidence in them)"
    )
    parts = [f"{len(damaged)} damaged stretch(es) skipped ({where}{more}){lost}"]
    if result.damaged_tail:
        parts.append(
            "the damage follows the last intact chunk: episodes begun there cannot be counted"
        )
    return parts


def _tail_parts(result: RecoveryResult) -> list[str]:
    """The torn tail dropped, the episodes it cut off, and a file its recorder never finished."""
    parts: list[str] = []
    if result.dropped_bytes:
        what = (
            "the closing magic"
            if result.dropped_record == CLOSING_MAGIC
            else f"a partial {result.dropped_record} record"
            if result.dropped_record
            else "bytes"
        )
        parts.append(f"the last {result.dropped_bytes} bytes ({what} at byte {result.dropped_at})")
    if result.cut_off_episodes:
        cut = list(result.cut_off_episodes)
        parts.append(
            f"episode(s) {listing(cut, len(cut))} had no end record: recorded as incomplete"
        )
    if not result.closing:
        parts.append(
            "the recorder never finished the file (killed, or its close() could not write): "
            "the steps after its last flush are lost"
        )
    return parts
