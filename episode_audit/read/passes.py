"""Passes over a file's chunks: what each chunk yields, what a whole pass keeps.

:func:`_read_chunks` is the chunk loop: it routes each chunk's messages by topic into a
:class:`_Chunk`, decoding the step blocks (one schema for all). A complete pass keeps the reset
blocks and episode records (:class:`_Gathered`, up to :data:`KEEP_LIMIT` bytes) and, for a torn
file, per-episode step counts (:class:`_StepStats`). :func:`_episode_rows` reads one episode;
:func:`_contiguous` regroups a multi-stream file's blocks so each episode's rows are contiguous.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from mcap.records import Channel

from ..errors import CorruptEvidenceError, EvidenceError
from ..format import names as fmt
from .blocks import _arrow_batch, _episode_part, _reset_block
from .chunks import _OTHER, _RESETS, _STEPS, _ChunkRef, _decoded, _split
from .storage import Source

KEEP_LIMIT = 256 << 20
"""Most bytes of reset blocks and episode records a pass over the steps keeps for later."""


@dataclass
class _Chunk:
    """The wanted messages of one chunk: step blocks parsed, the rest as raw bytes."""

    ref: _ChunkRef
    steps: list[tuple[int, pa.RecordBatch]]
    resets: list[tuple[int, bytes]]
    records: list[bytes]
    step_channels: list[int] = field(default_factory=list)  # channel id of each step block


def _read_chunks(
    path: Source,
    refs: list[_ChunkRef],
    channels: dict[int, Channel],
    slots: dict[str, int],
    expected: pa.Schema | None,
    wanted: tuple[bool, bool, bool],
    ahead: bool,
    indexed_only: bool = False,
) -> Iterator[_Chunk]:
    """Yield the wanted (steps, resets, records) messages of each chunk of ``refs``, in order.

    ``channels`` learns the Channel records the chunks hold. Every step block must have the
    schema ``expected`` (the file's declared one), or if None the first block's: a reader
    streaming blocks can rely on one schema. With ``ahead`` (for whole-file passes) a worker
    thread reads and decompresses the next chunks while the caller works on this one. With
    ``indexed_only``, chunks whose index (a finished file's summary) lists no message on a
    wanted channel are not read at all (nor yielded): ``Evidence.episodes`` of a finished
    file reads only the chunks with reset blocks and episode records.
    """
    route = {cid: slots.get(ch.topic, _OTHER) for cid, ch in channels.items()}
    want = frozenset(c for c, slot in route.items() if slot != _OTHER and wanted[slot])
    if indexed_only:
        refs = [
            r for r in refs if not r.index_offsets or any(c in want for c, _ in r.index_offsets)
        ]
    for ref, (data, positions) in _decoded(path, refs, ahead=ahead, want=want):
        found: list[Channel] = []
        messages = _split(data, path, ref.offset, route, wanted, found, None, slots, positions)
        for channel in found:
            channels.setdefault(channel.id, channel)
        chunk = _Chunk(ref, [], [], [])
        for slot, log_time, view, channel_id in messages:
            if slot == _STEPS:
                batch = _arrow_batch(view, path, fmt.TOPIC_STEPS)
                if expected is None:
                    expected = batch.schema
                elif not batch.schema.equals(expected):
                    raise CorruptEvidenceError(
                        path,
                        f"a step block in the chunk at byte {ref.offset} does not have the "
                        "schema of the others (or the one the file declares)",
                    )
                chunk.steps.append((log_time, batch))
                chunk.step_channels.append(channel_id)
            elif slot == _RESETS:
                chunk.resets.append((log_time, view.tobytes()))
            else:
                chunk.records.append(view.tobytes())
        yield chunk


def _episode_rows(
    chunks: Iterable[_Chunk], index: int, start: int | None, end: int | None, path: Source
) -> tuple[list[pa.RecordBatch], dict[str, Any] | None]:
    """Episode ``index``'s step rows and reset row, from the chunks from its start time on.

    ``end`` is its end time when it ended (else its rows are looked for to the file's end). A
    flush writes every stream's blocks into one chunk: the episode's last row is in the first
    chunk with a block that ends at or after the episode (in any stream), and its reset row in
    the first chunk with a reset block that ends after its start (in any stream: the rest of
    that chunk is read, where its own stream's block is).
    """
    parts: list[pa.RecordBatch] = []
    key = pa.scalar(index, pa.int64())
    reset = None
    steps_done = resets_done = False
    for chunk in chunks:
        for log_time, batch in [] if steps_done else chunk.steps:
            rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
            if rows.num_rows:
                parts.append(rows)
            if end is not None and log_time >= end:
                steps_done = True
        for log_time, data in [] if resets_done else chunk.resets:
            batch = _reset_block(data, path)
            rows = batch.filter(pc.equal(batch.column(fmt.COL_EPISODE), key))
            if rows.num_rows:
                reset = rows.to_pylist()[0]
                break
            if start is not None and log_time > start:
                resets_done = True  # (after this chunk: another stream's block may come first)
        resets_done = resets_done or reset is not None
        if steps_done and resets_done:
            break
    return parts, reset


@dataclass
class _StepStats:
    """Per episode: step rows, summed reward and the last block's latest time."""

    lengths: dict[int, int] = field(default_factory=dict)
    returns: dict[int, float] = field(default_factory=dict)
    last_time: dict[int, int] = field(default_factory=dict)

    def add(self, batch: pa.RecordBatch) -> None:
        grouped = (
            pa.table(
                {
                    "e": batch.column(fmt.COL_EPISODE),
                    "r": batch.column(fmt.COL_REWARD),
                    "t": batch.column(fmt.COL_TIME),
                }
            )
            .group_by("e")
            .aggregate([("r", "count"), ("r", "sum"), ("t", "max")])
        )
        lengths, returns, last_time = self.lengths, self.returns, self.last_time
        for e, n, s, t in zip(  # noqa: B905 - equal-length columns of one table
            grouped.column("e").to_pylist(),
            grouped.column("r_count").to_pylist(),
            grouped.column("r_sum").to_pylist(),
            grouped.column("t_max").to_pylist(),
        ):
            lengths[e] = lengths.get(e, 0) + n
            returns[e] = returns.get(e, 0.0) + (s or 0.0)
            last_time[e] = t


@dataclass
class _Gathered:
    """What a complete pass keeps for :meth:`Evidence.resets` and :meth:`Evidence.episodes`.

    With a ``limit``, a pass that was not asked for them stops keeping anything once they
    exceed it (a later call then reads the file again); their own pass keeps everything.

    With a ``path``, reset blocks and episode Arrow blocks are decoded as they come (while
    the read-ahead thread decompresses the next chunks) rather than all at the end. A block
    that fails to decode is kept as bytes, and so is every block after it: decoding them
    later raises the error where it did before, when :meth:`Evidence.resets` or
    :meth:`Evidence.episodes` is called.
    """

    stats: _StepStats | None = None
    limit: int | None = None
    path: Source | None = None
    arrow_records: bool = False
    slim_above: int | None = None
    """Past this many bytes of reset blocks, keep them :attr:`slim` (``None``: never)."""
    slim: bool = False
    """Whether the reset blocks are kept without their observations and state snapshots
    (:data:`SLIM_OUT`), copied out of the chunk: what :meth:`Evidence.episodes` needs of them,
    in little memory (image observations: ~100 kB a reset)."""
    reset_bytes: int = 0
    resets: list[pa.RecordBatch | bytes] = field(default_factory=list)
    records: list[pa.RecordBatch | bytes] = field(default_factory=list)
    size: int = 0
    dropped: bool = False

    @classmethod
    def for_pass(
        cls,
        path: Source,
        *,
        count_steps: bool,
        keep_all: bool,
        arrow_records: bool,
        slim_above: int | None = None,
    ) -> _Gathered:
        """What a new pass keeps: everything with ``keep_all``, else :data:`KEEP_LIMIT` bytes.

        Past ``slim_above`` bytes of reset blocks, the resets are kept :attr:`slim`.
        """
        limit = None if keep_all else KEEP_LIMIT
        stats = _StepStats() if count_steps else None
        return cls(stats, limit, path, arrow_records=arrow_records, slim_above=slim_above)

    def add(self, chunk: _Chunk) -> None:
        if self.dropped:
            return
        for _, data in chunk.resets:
            self.reset_bytes += len(data)
            if not self.slim and self.slim_above is not None and self.reset_bytes > self.slim_above:
                self.slim = True
                self.resets = [
                    _own(r, SLIM_OUT) if isinstance(r, pa.RecordBatch) else r for r in self.resets
                ]
            drop = SLIM_OUT if self.slim else frozenset()
            self.resets.append(self._early(data, self.resets, _reset_block, drop))
            self.size += len(data)
        for data in chunk.records:
            decode = _episode_part if self.arrow_records else None
            self.records.append(self._early(data, self.records, decode))
            self.size += len(data)
        if self.limit is not None and self.size > self.limit:
            self.dropped = True
            self.resets, self.records, self.stats = [], [], None
            return
        if self.stats is not None:
            try:
                for _, batch in chunk.steps:
                    self.stats.add(batch)
            except Exception:
                self.stats = None  # counted again, with its error, if episodes() needs it

    def _early(
        self,
        data: bytes,
        kept: list[pa.RecordBatch | bytes],
        decode: Callable[[bytes, Source], pa.RecordBatch] | None,
        drop: frozenset[str] = frozenset(),
    ) -> pa.RecordBatch | bytes:
        """``data`` decoded, or as it is; ``drop``: the decoded columns left out, copied.

        (A message is a view of its decompressed chunk: a selection of its columns would
        keep the whole chunk, every step's observation of it included, alive.)
        """
        if decode is None or self.path is None or (kept and isinstance(kept[-1], bytes)):
            return data
        try:
            batch = decode(data, self.path)
        except EvidenceError:
            return data
        return _own(batch, drop) if drop else batch


SLIM_OUT = frozenset({fmt.COL_OBSERVATION, fmt.COL_STATE})
"""The reset columns a slim pass leaves out (see :attr:`_Gathered.slim`)."""
SLIM_ABOVE = 64 << 20
"""Reset blocks :meth:`Evidence.episodes`'s own pass keeps whole, in bytes: past it, slim."""


def _own(batch: pa.RecordBatch, drop: frozenset[str] = frozenset()) -> pa.RecordBatch:
    """``batch`` without its ``drop`` columns, copied: in memory of its own.

    (A block decoded from a chunk shares the chunk's buffer; so would a selection of its
    columns.)
    """
    if drop:
        batch = batch.select([name for name in batch.schema.names if name not in drop])
    return batch.take(pa.array(np.arange(batch.num_rows)))


def _decode_kept(
    kept: list[pa.RecordBatch | bytes],
    decode: Callable[[bytes, Source], pa.RecordBatch],
    path: Source,
) -> list[pa.RecordBatch]:
    """The blocks a pass kept, decoding those it kept as bytes (see :class:`_Gathered`)."""
    return [data if isinstance(data, pa.RecordBatch) else decode(data, path) for data in kept]


def _contiguous(chunks: Iterable[_Chunk]) -> Iterator[pa.RecordBatch]:
    """The step blocks of a multi-stream file, regrouped so every episode's rows are contiguous.

    A stream's own rows are in order and its episodes follow one another, so an episode is
    complete once its stream shows a row of another episode (or the file ends). Complete
    episodes are yielded at the end of each chunk, those of one schema as one batch.
    """
    open_: dict[int, tuple[int, list[pa.RecordBatch]]] = {}  # channel -> (episode, parts)
    for chunk in chunks:
        done: list[pa.RecordBatch] = []
        for (_, batch), channel in zip(chunk.steps, chunk.step_channels, strict=True):
            if batch.num_rows == 0:
                continue
            episode = batch.column(fmt.COL_EPISODE).to_numpy(zero_copy_only=False)
            starts = [0, *(np.flatnonzero(episode[1:] != episode[:-1]) + 1).tolist()]
            stops = [*starts[1:], batch.num_rows]
            for start, stop in zip(starts, stops, strict=True):
                index = int(episode[start])
                part = batch.slice(start, stop - start)
                current = open_.get(channel)
                if current is not None and current[0] == index:
                    current[1].append(part)
                    continue
                if current is not None:
                    done.extend(current[1])
                open_[channel] = (index, [part])
        yield from _joined(done)
    rest = sorted(open_.values(), key=lambda item: item[0])
    yield from _joined([part for _, parts in rest for part in parts])


def _joined(parts: list[pa.RecordBatch]) -> Iterator[pa.RecordBatch]:
    """``parts`` as few batches as possible: consecutive parts of one schema are joined."""
    group: list[pa.RecordBatch] = []
    for part in parts:
        if group and not part.schema.equals(group[0].schema):
            yield pa.concat_batches(group) if len(group) > 1 else group[0]
            group = []
        group.append(part)
    if group:
        yield pa.concat_batches(group) if len(group) > 1 else group[0]
