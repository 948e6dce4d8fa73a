"""An evidence file's episode-level API: its resets and episodes tables, and one episode.

:class:`EpisodeTables` is the part of :class:`~.evidence.Evidence` built on its passes over the
file (``_gather``: the reset blocks and episode records one complete pass keeps; ``_read``: the
chunks of a time range): :meth:`~EpisodeTables.resets`, :meth:`~EpisodeTables.episodes`,
:meth:`~EpisodeTables.error_actions`, and :class:`EpisodeEvidence`, one episode with its rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.compute as pc

from ..errors import EvidenceError
from ..format import names as fmt
from .arguments import episode_index
from .blocks import _reset_block
from .chunks import _ARROW_SLOTS
from .episodes import _build_episodes, _error_actions
from .passes import _Chunk, _decode_kept, _episode_rows, _Gathered, _StepStats
from .storage import Source

__all__ = ["EpisodeEvidence", "EpisodeTables"]


@dataclass
class EpisodeEvidence:
    """One episode: its record (a row of :meth:`Evidence.episodes`), its steps and reset row."""

    record: dict[str, Any]
    steps: pa.Table
    reset: dict[str, Any] | None

    @property
    def index(self) -> int:
        """The episode index in its file."""
        return int(self.record["episode"])


class EpisodeTables:
    """The resets and episodes tables and single episodes of an open file (a mixin).

    :class:`~.evidence.Evidence` provides what these read: its passes (``_gather``,
    ``_read``), its tables' assembly (``_table``) and caches, and its step counts.
    """

    if TYPE_CHECKING:  # (Evidence's)
        path: Source
        finished: bool
        _episodes_cache: pa.Table | None
        _resets_cache: pa.Table | None

        @property
        def _slots(self) -> dict[str, int]: ...

        @property
        def steps_schema(self) -> pa.Schema:
            """The steps table's schema."""

        def _gather(self) -> _Gathered: ...

        def _read(self, *args: Any, **kwargs: Any) -> Iterator[_Chunk]: ...

        def _table(
            self, parts: list[pa.RecordBatch], topic: str, columns: Sequence[str] | None
        ) -> pa.Table: ...

        def _step_stats(self) -> _StepStats: ...

    @property
    def holds_nothing(self) -> bool:
        """Whether the file holds no episode and no reset (no complete chunk of a run)."""
        return not self.episodes().num_rows and not self.resets().num_rows

    def resets(self) -> pa.Table:
        """One row per reset: episode, seed, rng_state (JSON), options (JSON), observation.

        ``options_typed``: the options exactly (``format.options.decode_typed``) where JSON
        would change them, else null (files without the column: none).

        The table is read once and cached.
        """
        if self._resets_cache is None:
            gathered = self._gather()
            if gathered.slim:  # (kept for episodes(): read them again, observations and all)
                kept: list[pa.RecordBatch | bytes] = [
                    data
                    for chunk in self._read(
                        steps=False, resets=True, records=False, indexed_only=True
                    )
                    for _, data in chunk.resets
                ]
            else:
                kept, gathered.resets = gathered.resets, []
            parts = _decode_kept(kept, _reset_block, self.path)
            self._resets_cache = self._table(parts, fmt.TOPIC_RESETS, None)
        return self._resets_cache

    def _reset_rows(self) -> pa.Table:
        """The reset rows :meth:`episodes` reads: :meth:`resets`, or its slim pass's own.

        (A slim pass's rows have no observations and state snapshots.)
        """
        gathered = self._gather()
        if self._resets_cache is not None or not gathered.slim:
            return self.resets()
        parts = _decode_kept(gathered.resets, _reset_block, self.path)
        return self._table(parts, fmt.TOPIC_RESETS, None)

    def episodes(self) -> pa.Table:
        """One row per episode (see :data:`EPISODE_COLUMNS`), including cut-off ones.

        The table is read once and cached. An episode with an end record takes every value
        from it; one without (cut off by a torn file) is counted from its reset row and steps.
        """
        if self._episodes_cache is None:
            self._episodes_cache = self._build_episodes()
        return self._episodes_cache

    def _build_episodes(self) -> pa.Table:
        gathered = self._gather()
        table = _build_episodes(
            self.path,
            gathered.records,
            arrow=self._slots is _ARROW_SLOTS,
            finished=self.finished,
            resets=self._reset_rows,
            step_stats=self._step_stats,
        )
        gathered.records = []
        return table

    def error_actions(self) -> pa.Table:
        """The actions of the steps that raised, by episode: ``episode`` and ``action``.

        Single-env files keep the action of an ``error`` episode's step that raised
        (``docs/format.md``, "Episode blocks"); ``action`` has the steps' action type, null
        when the action did not fit it. An error episode missing here has none recorded (a
        file of an older recorder; a vector or PettingZoo file). Reads the file's episode
        blocks again, once (cached): for replay, which asks only when a file has such an episode.
        """
        cache: dict[str, pa.Table] = self.__dict__.setdefault("_error_actions_cache", {})
        if "table" not in cache:
            blocks = (
                [
                    bytes(data)
                    for chunk in self._read(
                        steps=False, resets=False, records=True, indexed_only=True
                    )
                    for data in chunk.records
                ]
                if self._slots is _ARROW_SLOTS
                else []
            )
            action = self.steps_schema.field(fmt.COL_ACTION).type
            cache["table"] = _error_actions(blocks, self.path, action)
        return cache["table"]

    def episode(self, index: int) -> EpisodeEvidence:
        """One episode, read from the chunks its time range covers only.

        ``index`` is an ``int`` (else :class:`~episode_audit.errors.ConfigurationError`); an
        index the file has no episode of raises :class:`~episode_audit.errors.EvidenceError`.
        """
        index = episode_index("index", index)
        table = self.episodes()
        match = table.filter(pc.equal(table.column("episode"), index))
        if match.num_rows == 0:
            raise EvidenceError(
                self.path, f"no episode {index} (the file has {table.num_rows} episodes)"
            )
        record = match.to_pylist()[0]
        return self._load_episode(record)

    def _load_episode(self, record: dict[str, Any]) -> EpisodeEvidence:
        start = record.get("start_time_ns")
        end = record.get("end_time_ns") if record.get("ended") else None
        parts, reset = _episode_rows(
            self._read(steps=True, resets=True, records=False, start_time=start, ahead=False),
            int(record["episode"]),
            start,
            end,
            self.path,
        )
        return EpisodeEvidence(record, self._table(parts, fmt.TOPIC_STEPS, None), reset)

    def iter_episodes(self) -> Iterator[EpisodeEvidence]:
        """Yield every episode with its steps, one at a time."""
        for record in self.episodes().to_pylist():
            yield self._load_episode(record)
