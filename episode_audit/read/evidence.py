"""The :class:`Evidence` API: an open evidence file's tables, blocks and episodes.

:class:`Evidence` (made by :func:`~episode_audit.read.opening.open_evidence`) gives the run
metadata, the episodes, steps and resets tables as ``pyarrow`` tables, block-by-block
streaming (:meth:`Evidence.scan`, :meth:`Evidence.iter_step_batches`) and episode-by-episode
reading (:class:`EpisodeEvidence`). One pass over the file serves the steps, the resets and the
episodes; both tables are cached (docs/format.md, "Reading").
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import pyarrow as pa
import pyarrow.compute as pc
from mcap.records import Channel

from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.locking import Holder
from ..format.records import EpisodeRanges, RunInfo
from ..format.run_end import RunEnd
from ..format.spaces import SpaceCodec, codec_for, space_from_description
from .arguments import episode_indices, name_list
from .blocks import _blocks_table, _declared_schema, _empty_table, _reset_block, _topic_schema
from .chunks import _ARROW_SLOTS, _SLOTS, _ChunkRef
from .episode_tables import EpisodeTables
from .passes import (
    SLIM_ABOVE,
    _Chunk,
    _contiguous,
    _Gathered,
    _read_chunks,
    _StepStats,
)
from .storage import Source


@dataclass(frozen=True)
class ChunkContents:
    """What one chunk of an evidence file holds, as :meth:`Evidence.scan` yields it.

    Attributes:
        offset: The chunk's byte offset in the file.
        steps: Its step blocks, in recording order (empty when not asked for).
        resets: Its reset blocks (empty when not asked for).
        episode_records: Its episode records, raw: Arrow IPC episode blocks for files that have
            them (topic ``episode_audit/episodes``), else JSON end records (empty when not
            asked for).
    """

    offset: int
    steps: list[pa.RecordBatch]
    resets: list[pa.RecordBatch]
    episode_records: list[bytes]


@dataclass
class Evidence(EpisodeTables):
    """An open evidence file. Use :func:`open_evidence` to make one.

    Attributes:
        path: The file.
        run: The run metadata.
        finished: Whether the writer finished the file (summary, footer, run-end record).
        run_end: The run-end record (``status`` is ``finished`` or ``recovered``), if any.
        torn: For an unfinished file, what the reader had to drop at the torn end.
        summary_damage: For a finished file whose end is damaged — its summary section
            (MCAP's index of it) does not match the footer's CRC, or the footer or closing
            magic is garbled — what is wrong; the file was then read by scanning its data
            section, which holds all the evidence.
        run_end_damage: For a finished file whose run-end record (which its sound summary
            locates) is garbled, what is wrong. The writer finished the file and every chunk
            is there; the record's status and counts are lost, and :attr:`run_end` is
            ``None``.
        writer: For an unfinished file a live recorder is still writing, that recorder's
            process (the holder of the file's lock, ``docs/format.md``); ``None`` otherwise.
    """

    path: Source
    run: RunInfo
    finished: bool
    run_end: dict[str, str] | None
    torn: str | None
    _chunks: list[_ChunkRef] = field(repr=False)
    _channels: dict[int, Channel] = field(repr=False)
    summary_damage: str | None = None
    run_end_damage: str | None = None
    _schemas: dict[int, pa.Schema] = field(default_factory=dict, repr=False, compare=False)
    _episodes_cache: pa.Table | None = field(default=None, repr=False)
    _resets_cache: pa.Table | None = field(default=None, repr=False)
    _gathered: _Gathered | None = field(default=None, repr=False)
    _stats: _StepStats | None = field(default=None, repr=False)
    writer: Holder | None = None

    @property
    def damaged_episodes(self) -> EpisodeRanges:
        """Episodes that lost part or all of their evidence in damaged chunks.

        Only a file rewritten by ``episode-audit recover`` from a damaged one says so (its
        run-end record lists them); for any other file this is empty.
        """
        return RunEnd.of(self.run_end).damaged_episodes

    @property
    def reports_success(self) -> bool | None:
        """Whether the task said anything about success in an episode's final info.

        ``False`` for a task without a success signal (CartPole, Hopper: its endings are
        failures or cut-offs, never successes); ``None`` when the file does not say (a torn
        file, or one written by a recorder that did not count it yet).
        """
        said = RunEnd.of(self.run_end).success_reported
        return None if said is None else said > 0

    @property
    def damaged_stretches(self) -> int:
        """How many damaged stretches of the original file a recovery skipped (0 if none)."""
        return RunEnd.of(self.run_end).damaged_stretches

    # --------------------------------------------------------------- passes

    @property
    def _slots(self) -> dict[str, int]:
        """Topic -> slot; episode records come from Arrow blocks when the file has them."""
        if any(ch.topic == fmt.TOPIC_EPISODES for ch in self._channels.values()):
            return _ARROW_SLOTS
        return _SLOTS

    def _read(
        self,
        *,
        steps: bool,
        resets: bool,
        records: bool,
        start_time: int | None = None,
        ahead: bool = True,
        indexed_only: bool = False,
    ) -> Iterator[_Chunk]:
        """The wanted messages of every chunk (from ``start_time`` on), in file order.

        ``indexed_only``: skip the chunks a finished file's index says hold none of them.
        """
        refs = [r for r in self._chunks if start_time is None or r.end_time >= start_time]
        expected = _declared_schema(self._channels, self._schemas, fmt.TOPIC_STEPS)
        wanted = (steps, resets, records)
        return _read_chunks(
            self.path, refs, self._channels, self._slots, expected, wanted, ahead, indexed_only
        )

    def _pass(
        self,
        *,
        steps: bool,
        resets: bool = False,
        records: bool = False,
        keep_all: bool = False,
        indexed_only: bool = False,
        slim_above: int | None = None,
    ) -> Iterator[_Chunk]:
        """Read every chunk once; a complete pass also keeps resets and episode records.

        They are kept by the first complete pass only, and (unless ``keep_all``) only up to
        :data:`KEEP_LIMIT` bytes; past ``slim_above`` bytes of resets, the resets without
        their observations (for :meth:`episodes`: :meth:`resets` then reads them again).
        ``indexed_only``: see :meth:`_read`.
        """
        gather = None
        if self._gathered is None:
            gather = _Gathered.for_pass(
                self.path,
                count_steps=steps and not self.finished,
                keep_all=keep_all,
                arrow_records=self._slots is _ARROW_SLOTS,
                slim_above=slim_above,
            )
        keep = gather is not None
        for chunk in self._read(
            steps=steps, resets=resets or keep, records=records or keep, indexed_only=indexed_only
        ):
            if gather is not None:
                gather.add(chunk)
            yield chunk
        if gather is not None and not gather.dropped:
            self._gathered = gather
            if gather.stats is not None:
                self._stats = gather.stats

    def scan(
        self, *, steps: bool = True, resets: bool = True, episode_records: bool = True
    ) -> Iterator[ChunkContents]:
        """Read each chunk once and yield what it holds, in file order.

        Leave out what you do not need: a chunk's step blocks are only decoded with ``steps``.
        Episode records are raw, as written (see :class:`ChunkContents`; :meth:`episodes`
        gives the table).
        A complete scan also fills the caches of :meth:`resets` and :meth:`episodes`.
        """
        path = self.path
        for chunk in self._pass(steps=steps, resets=resets, records=episode_records):
            yield ChunkContents(
                chunk.ref.offset,
                [batch for _, batch in chunk.steps] if steps else [],
                [_reset_block(data, path) for _, data in chunk.resets] if resets else [],
                list(chunk.records) if episode_records else [],
            )

    # --------------------------------------------------------------- steps

    def iter_step_batches(self, columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
        """Yield the steps block by block (one record batch per written block).

        Each chunk is read once; the pass also keeps what :meth:`resets` and :meth:`episodes`
        need, so calling them afterwards reads nothing again.

        Every episode's rows come out contiguous and in step order. In a multi-stream file
        (vector sub-envs, agents) the streams' blocks interleave in the file, so there the
        batches are regrouped: an episode's rows are held until its stream moves on to its next
        episode (or the file ends), then yielded with the other episodes completed in the same
        chunk. Memory is then bounded by the longest open episode of each stream.
        """
        selected = self._columns(columns)
        batches: Iterable[pa.RecordBatch]
        if self.multi_stream:
            batches = _contiguous(self._pass(steps=True))
        else:
            batches = (batch for chunk in self._pass(steps=True) for _, batch in chunk.steps)
        for batch in batches:
            yield batch if selected is None else batch.select(selected)

    @property
    def multi_stream(self) -> bool:
        """Whether the file has more than one step stream (vector sub-envs, agents)."""
        return sum(ch.topic == fmt.TOPIC_STEPS for ch in self._channels.values()) > 1

    def steps(
        self,
        *,
        columns: Sequence[str] | None = None,
        episodes: Iterable[int] | None = None,
    ) -> pa.Table:
        """All steps (or those of ``episodes``) as one table, in recording order.

        ``columns`` is a list of names (a bare ``str`` is refused, as an unknown column is, by
        :class:`~episode_audit.errors.ConfigurationError`), ``episodes`` of episode indices.
        """
        selected = self._columns(columns)
        wanted = None
        if episodes is not None:
            indices = episode_indices("episodes", episodes)
            wanted = pa.array(sorted(set(indices)), pa.int64())
        parts: list[pa.RecordBatch] = []
        for batch in self.iter_step_batches():
            if wanted is not None:
                batch = batch.filter(pc.is_in(batch.column(fmt.COL_EPISODE), wanted))
                if batch.num_rows == 0:
                    continue
            parts.append(batch if selected is None else batch.select(selected))
        return self._table(parts, fmt.TOPIC_STEPS, selected)

    def _columns(self, columns: Sequence[str] | None) -> list[str] | None:
        """``columns`` checked: a list of the steps table's column names (``None``: all)."""
        if columns is None:
            return None
        selected = name_list("columns", columns)
        known = self.steps_schema.names
        unknown = [c for c in selected if known and c not in known]
        if unknown:
            raise ConfigurationError(
                f"columns: no column {unknown[0]!r} in the steps of {self.path}; "
                f"its columns are {', '.join(known)}"
            )
        return selected

    def _table(
        self, parts: list[pa.RecordBatch], topic: str, columns: Sequence[str] | None
    ) -> pa.Table:
        """The blocks as one table; without any, an empty one with the topic's schema."""
        if parts:
            return _blocks_table(parts, topic, self.path)
        return _empty_table(self._topic_schema(topic), columns)

    @property
    def steps_schema(self) -> pa.Schema:
        """The Arrow schema of the steps table (from the file, even when it has no steps)."""
        return self._topic_schema(fmt.TOPIC_STEPS)

    def _topic_schema(self, topic: str) -> pa.Schema:
        """The topic's schema as the file declares it, checked (see :func:`_topic_schema`)."""
        declared = _declared_schema(self._channels, self._schemas, topic)
        return _topic_schema(self.path, declared, topic)

    def _gather(self) -> _Gathered:
        """Reset blocks and episode records, from the last complete pass or a new one."""
        if self._gathered is None:
            # A torn file's episodes need counts from its steps: count them in the same pass.
            # A finished file's index says which chunks hold resets and episode records: only
            # those are read (``report`` of a file in object storage fetches little of it).
            # Past SLIM_ABOVE bytes, its resets are kept without their observations:
            # episodes() needs none of them, and an image observation is ~100 kB a reset
            # (resets() then reads them again, when asked).
            passing = self._pass(
                steps=not self.finished, keep_all=True, indexed_only=True, slim_above=SLIM_ABOVE
            )
            for _ in passing:
                pass
        assert self._gathered is not None
        return self._gathered

    def _step_stats(self) -> _StepStats:
        if self._stats is None:
            stats = _StepStats()
            for chunk in self._read(steps=True, resets=False, records=False):
                for _, batch in chunk.steps:
                    stats.add(batch)
            self._stats = stats
        return self._stats

    @property
    def observation_codec(self) -> SpaceCodec | None:
        """Codec of the observation column, rebuilt from the file (``None`` if unsupported)."""
        return self._codec("observation_space")

    @property
    def action_codec(self) -> SpaceCodec | None:
        """Codec of the action column, rebuilt from the file (``None`` if unsupported)."""
        return self._codec("action_space")

    def _codec(self, name: str) -> SpaceCodec | None:
        cache: dict[str, SpaceCodec | None] = self.__dict__.setdefault("_codec_cache", {})
        if name not in cache:
            cache[name] = _column_codec(self, name)
        return cache[name]

    def __enter__(self) -> Evidence:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def _column_codec(ev: Evidence, name: str) -> SpaceCodec | None:
    """The codec of the space ``name`` describes, if it describes its column in the file."""
    digest = ev.run.recorder.get("digest_min_bytes") if name == "observation_space" else None
    column = fmt.COL_OBSERVATION if name == "observation_space" else fmt.COL_ACTION
    try:
        space = space_from_description(getattr(ev.run, name))
        codec: SpaceCodec | None = codec_for(space, digest_min_bytes=digest)
        stored = ev.steps_schema.field(column).type
        if codec is not None and not (
            pa.types.is_null(stored) or codec.field(column).type.equals(stored)
        ):
            codec = None  # the description does not describe the column: do not decode
    except Exception:
        codec = None
    return codec
