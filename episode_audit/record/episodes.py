"""One stream's episodes: the state machine a recorder drives, and the writing of its rows.

A *stream* is the episodes of one actor: the single env of ``RecordEvidence``, one sub-env of a
vector env, or one agent of a PettingZoo env (``docs/format.md``, "Multi-stream files").
:class:`EpisodeStream` begins episodes (:meth:`~EpisodeStream.begin` and the reset row), ends
them by their flags, as ``incomplete`` or as ``error``, and counts its block into them at each
flush (:class:`~.channels.StreamChannels` writes it); :class:`~.stream.Stream` adds the steps.
See ``docs/recording.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
from gymnasium.wrappers import TimeLimit

from ..format import names as fmt
from ..format.columns import error_message, text
from ..format.spaces import SpaceCodec
from .block import Block, Episode, row_bytes
from .channels import StreamChannels
from .counting import count_block
from .native import counting, untrack
from .notes import add_notes, append_noted, has_note, note, short
from .rules import Ending, EndingRules, time_limit_hit
from .settings import RecorderSettings
from .values import kept_info, recordable_options, recordable_seed
from .writer import EvidenceWriter

__all__ = ["EpisodeStream", "StreamFile"]

_BOOLS = frozenset({bool, np.bool_})


class StreamFile(Protocol):
    """What a stream uses of its evidence file (:class:`~.file.EvidenceFile`)."""

    settings: RecorderSettings
    writer: EvidenceWriter
    multi: bool
    clock: Callable[[], int]
    wall_offset: int
    flush_at: int
    counts: dict[str, int]
    pending: list[tuple[Episode, dict[str, Any]]]  # ended episodes, their records not written
    rng_json: Callable[[dict[str, Any]], bytes]  # an RNG state's JSON (to_json's bytes)

    def take_episode_index(self) -> int:
        """The next file-global episode index."""

    def auto_flush(self) -> None:
        """Flush because a block filled or ``flush_every_s`` passed; never raises."""

    def trouble(self, exc: Exception) -> None:
        """Something failed inside the recorder itself: warn once, keep the loop running."""


class EpisodeStream:
    """A stream's episodes, from their reset rows to their endings, and its block's writing.

    Episodes begin with :meth:`begin` (+ :meth:`record_reset`) and end by their flags
    (classified by the file's ending rules), by :meth:`end_open` (``incomplete``) or by
    :meth:`end_error`; :meth:`write_blocks` writes the rows to the stream's two channels. The
    constructor sets up the whole stream, what :class:`~.stream.Stream`'s steps read included.
    """

    # slots: the compiled step reads episode, block, _block_steps, flush_at and the terms plan
    __slots__ = (
        "_act_codec",
        "_block_steps",
        "_clock",
        "_compiled",
        "_ending_keys",
        "_extract_terms",
        "_flag_endings",
        "_info_keys",
        "_keep_all_info",
        "_max_steps",
        "_obs_codec",
        "_rules",
        "_terms_get",
        "_terms_keys",
        "_terms_names",
        "_terms_one",
        "_terms_plans",
        "_terms_rule",
        "_time_limit",
        "_track_info",
        "agent",
        "block",
        "channels",
        "env_index",
        "episode",
        "file",
        "flush_at",
        "row_bytes",
    )

    def __init__(
        self,
        file: StreamFile,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int = 0,
        agent: str | None = None,
        time_limit: TimeLimit[Any, Any] | None = None,
        max_episode_steps: int | None = None,
        state: bool = False,
    ) -> None:
        settings = file.settings
        self.file = file
        self._clock = file.clock
        self.env_index = env_index
        self.agent = agent
        self._obs_codec = obs_codec
        self._act_codec = act_codec
        self._rules = settings.rules
        # endings by the flags alone, for final infos without the rules' keys (_stepfast reads them)
        self._flag_endings, self._ending_keys = settings.rules.flag_endings()
        self._terms_rule = settings.terms_rule
        self._extract_terms = settings.terms_rule.extractor
        # How the terms of infos with the last key tuple seen are read (see Stream._plan_terms):
        # the names (None: ask _extract_terms step by step) and one itemgetter of them
        self._terms_keys: tuple[Any, ...] | None = None
        self._terms_names: tuple[str, ...] | None = ()
        self._terms_get: Callable[[Any], Any] = tuple  # set with the names
        self._terms_one = False
        # plans by key tuple: an env that adds a term key on some steps only flips between two
        self._terms_plans: dict[tuple[Any, ...], tuple[Any, ...]] = {}
        self._info_keys = settings.info_keys
        self._keep_all_info = settings.keep_all_info
        self._track_info = settings.track_info
        self._block_steps = settings.block_steps
        self.row_bytes = row_bytes(obs_codec, act_codec)
        """Estimated bytes of one step row (for sizing blocks)."""
        self._time_limit = time_limit
        self._max_steps = max_episode_steps
        self.channels = StreamChannels(
            file.writer,
            obs_codec,
            act_codec,
            env_index=env_index,
            agent=agent,
            multi=file.multi,
            state=state,
        )
        """The stream's ``steps`` and ``resets`` channels."""
        self.episode: Episode | None = None
        self.block = Block(obs_codec, act_codec, None)
        self._compiled = counting()  # (the compiled counting of its blocks, or None)
        self.flush_at = file.flush_at
        """The file's ``flush_at``, kept here by the file (read on every step)."""

    # ------------------------------------------------------------------ episodes

    def begin(
        self,
        seed: Any,
        options: Any,
        rng_state: dict[str, Any] | None,
        notes: list[str],
        *,
        game: int | None = None,
        start_ns: int | None = None,
    ) -> Episode:
        """Start the stream's next episode (ending an open one as ``incomplete``).

        ``seed`` is what was passed to ``reset()``; ``rng_state`` the env's bit-generator state
        before an unseeded reset (``None`` if unknown: the episode is then noted as not
        replayable). Notes about the seed or options are appended to ``notes``.
        """
        episode = self.episode
        if episode is not None and not episode.ended:
            self.end_episode(episode, fmt.OUTCOME_INCOMPLETE)
        file = self.file
        recorded_seed = recordable_seed(seed, notes)
        if seed is None and rng_state is None and not has_note(notes, "rng_state_unavailable"):
            notes.append(
                note("rng_state_unavailable", "reset without a seed and the env has no np_random")
            )
        recorded_options = recordable_options(options, notes)
        episode = Episode(
            file.take_episode_index(),
            recorded_seed,
            None if rng_state is None else file.rng_json(rng_state),
            recorded_options,
            file.clock() if start_ns is None else start_ns,
            self.env_index,
            self.agent,
            game,
        )
        self.episode = episode
        untrack(episode)
        untrack(self.block.add_segment(self.block.rows(), episode, 0, True))
        return episode

    def record_reset(
        self, episode: Episode, obs: Any, info: Any, notes: list[str], state: str | None = None
    ) -> None:
        """Record the reset row of ``episode`` (just begun); never raises.

        ``state``: the snapshot taken before the reset (JSON text, :mod:`.state`).
        """
        try:
            block = self.block
            row = len(block.resets)
            rng_json = None if episode.rng_json is None else episode.rng_json.decode()
            append_noted(block.reset_obs, obs, "observation", notes, "reset observation: ")
            if self._track_info or type(info) is not dict:
                kept = kept_info(info, self._keep_all_info, self._info_keys, notes)
                if kept:
                    block.reset_info[row] = kept
            values = (
                episode.index,
                episode.start_ns,
                episode.seed,
                rng_json,
                episode.options_json,
                episode.game,
                state,
            )
            block.resets.append(values)
            untrack(values)
            if notes:
                add_notes(episode, block.reset_notes, row, notes)
        except Exception as exc:  # never break the training loop over recording trouble
            self.file.trouble(exc)

    def end_open(self, outcome: str = fmt.OUTCOME_INCOMPLETE) -> None:
        """End the open episode, if any, with ``outcome`` (``incomplete`` by default)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self.end_episode(episode, outcome)

    def end_error(self, exc: BaseException, during: str) -> None:
        """End the open episode as ``error`` (the env raised ``exc`` during reset or step)."""
        episode = self.episode
        if episode is None or episode.ended:
            return
        self.end_episode(episode, fmt.OUTCOME_ERROR, error=(exc, during))

    def end_episode(
        self,
        episode: Episode,
        outcome: str,
        *,
        failure_label: str | None = None,
        truncation_reason: str | None = None,
        terminated: bool = False,
        truncated: bool = False,
        error: tuple[BaseException, str] | None = None,
    ) -> None:
        """Mark the episode ended; its record is written at the next flush."""
        episode.ended = True
        ending: dict[str, Any] = {
            "outcome": outcome,
            "failure_label": failure_label,
            "truncation_reason": truncation_reason,
            "terminated": terminated,
            "truncated": truncated,
            "error": None,
        }
        if error is not None:
            ending["error"] = _error_record(*error)
            ending["error_ns"] = self.file.clock()
        file = self.file
        pair = (episode, ending)
        file.pending.append(pair)
        untrack(pair)
        file.counts["episodes"] += 1

    def cap_block_steps(self, rows: int) -> None:
        """Write a block after at most ``rows`` rows (the file sizes blocks of large rows)."""
        self._block_steps = min(self._block_steps, rows)

    def end_step(
        self, row: int, terminated: bool, truncated: bool, info: Mapping[str, Any]
    ) -> None:
        """End the open episode by the flags of its step at ``row`` (a batched row)."""
        episode = self.episode
        if episode is not None and not episode.ended:
            self._end_by_flags(episode, self.block, row, terminated, truncated, info)

    def end_batched(
        self, pending: int, terminated: bool, truncated: bool, info: dict[str, Any]
    ) -> None:
        """A batched vector step ended the episode (:meth:`end_step`).

        ``pending`` rows are batched for the stream (its block counts them); the last is that
        step's.
        """
        block = self.block
        block.pending = pending
        self.end_step(block.rows() - 1, terminated, truncated, info)

    def _implicit_episode(self, notes: list[str]) -> Episode:
        """The episode of a step before any reset (not replayable, noted)."""
        file = self.file
        episode = Episode(
            file.take_episode_index(), None, None, None, file.clock(), self.env_index, self.agent
        )
        self.episode = episode
        self.block.add_segment(len(self.block.times), episode, 0, True)
        notes.append(
            note("stepped_before_reset", "the env was stepped before reset(); not replayable")
        )
        return episode

    # ------------------------------------------------------------------ endings

    def _limit_hit(self, block: Block) -> bool:
        if self._time_limit is not None:
            return time_limit_hit(self._time_limit)
        limit = self._max_steps
        # The step's row is committed: the next step index is the episode's length so far.
        return limit is not None and block.segments != [] and block.next_step_index() >= limit

    def _end_by_flags(
        self,
        episode: Episode,
        block: Block,
        row: int,
        terminated: bool,
        truncated: bool,
        info: Mapping[str, Any],
    ) -> None:
        hit = self._limit_hit(block)
        if (
            type(info) is dict
            and type(terminated) is bool
            and type(truncated) is bool
            and info.keys().isdisjoint(self._ending_keys)
        ):  # the common case: nothing to note, no success reported
            plain = self._flag_endings.get((terminated, truncated, hit))
            if plain is not None:
                self._end_as(episode, block, row, plain, terminated, truncated)
                return
        ending, read = _read_ending(self._rules, terminated, truncated, info, hit)
        if self._rules.reports_success(info):
            self.file.counts["success_reported"] += 1
        if read:
            add_notes(episode, block.notes, row, read)
        self._end_as(episode, block, row, ending, bool(terminated), bool(truncated))

    def _end_as(
        self,
        episode: Episode,
        block: Block,
        row: int,
        ending: Ending,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """End ``episode`` at its step ``row`` as ``ending`` says."""
        label = ending.failure_label if terminated else ending.truncation_reason
        untrack(ends := (ending.outcome, label))
        untrack(flags := (terminated, truncated))
        block.ends[row] = ends
        block.flags[row] = flags
        self.end_episode(
            episode,
            ending.outcome,
            failure_label=ending.failure_label,
            truncation_reason=ending.truncation_reason,
            terminated=terminated,
            truncated=truncated,
        )

    # ------------------------------------------------------------------ blocks

    def write_blocks(self) -> None:
        """Write the stream's pending step and reset rows (called by ``EvidenceFile.flush``)."""
        block = self.block
        # Count the rows into their episodes before the next block starts from them.
        counted = count_block(block, len(block.times), self._compiled) if block.times else None
        self.block = Block(self._obs_codec, self._act_codec, self.episode)
        file = self.file
        self.channels.write(file.writer, block, counted, file.wall_offset, self._compiled)
        self.block.take_buffers(block)
        if counted is not None:
            file.counts["steps"] += len(block.times)
            file.counts["blocks"] += 1


def _read_ending(
    rules: EndingRules, terminated: Any, truncated: Any, info: Mapping[str, Any], hit: bool
) -> tuple[Ending, list[str]]:
    """The ending of a step whose flags or info are not the plain case, and what to note.

    Flags that are not bools are taken by their truth value (the text ``"False"`` is true:
    the episode ends, and the step says why); an ending the rules cannot read is the flags'.
    """
    read: list[str] = []
    if type(terminated) not in _BOOLS or type(truncated) not in _BOOLS:
        odd = f"terminated={short(terminated)}, truncated={short(truncated)}"
        read.append(note("flags_not_bool", f"{odd} (taken by their truth value)"))
    ending, why = rules.classify_or_note(
        bool(terminated), bool(truncated), info, time_limit_hit=hit, notes=read
    )
    if why is not None:  # the ending by the flags alone; say why
        read.append(note("ending_unreadable", why))
    return ending, read


def _error_record(exc: BaseException, during: str) -> dict[str, str]:
    """The ``error`` of an episode the env's exception ``exc`` ended, ``during`` reset or step."""
    return {
        "type": text(type(exc).__qualname__),
        "message": error_message(exc)[:2000],
        "during": during,
    }
