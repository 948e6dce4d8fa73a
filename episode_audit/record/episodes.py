"""One stream's episodes: the state machine a recorder drives, and the writing of its rows.

A *stream* is the episodes of one actor: the single env of ``RecordEvidence``, one sub-env of a
vector env, or one agent of a PettingZoo env (``docs/format.md``, "Multi-stream files").
:class:`EpisodeStream` begins episodes (:meth:`~EpisodeStream.begin` and the reset row), ends
them by their flags, as ``incomplete`` or as ``error``, and counts its block into them at each
flush (:class:`~.channels.StreamChannels` writes it); :class:`~.stream.Stream` adds the steps.
See ``docs/recording.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from gymnasium.wrappers import TimeLimit

from ..format import names as fmt
from ..format.spaces import SpaceCodec
from .block import Block, Episode, row_bytes
from .channels import StreamChannels
from .counting import count_block
from .endings import EpisodeEndings
from .native import counting, untrack
from .notes import add_notes, append_noted, has_note, note
from .settings import RecorderSettings
from .values import RecordedOptions, kept_info, recordable_seed
from .writer import EvidenceWriter

__all__ = ["EpisodeStream", "StreamFile"]


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


class EpisodeStream(EpisodeEndings):
    """A stream's episodes, from their reset rows to their endings, and its block's writing.

    Episodes begin with :meth:`begin` (+ :meth:`record_reset`) and end by their flags
    (classified by the file's ending rules), by :meth:`end_open` (``incomplete``) or by
    :meth:`end_error` (:class:`~.endings.EpisodeEndings`); :meth:`write_blocks` writes the
    rows to the stream's two channels. The constructor sets up the whole stream, what
    :class:`~.stream.Stream`'s steps read included.
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
        "_time_limits",
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

    file: StreamFile  # (the endings need less of it: EndingFile)

    def __init__(
        self,
        file: StreamFile,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int = 0,
        agent: str | None = None,
        time_limits: Sequence[TimeLimit[Any, Any]] = (),
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
        self._time_limits = tuple(time_limits)
        # the one the compiled step reads itself (several: its _limit_hit asks them all)
        self._time_limit = self._time_limits[0] if len(self._time_limits) == 1 else None
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
        options: RecordedOptions | None,
        rng_state: dict[str, Any] | None,
        notes: list[str],
        *,
        game: int | None = None,
        start_ns: int | None = None,
    ) -> Episode:
        """Start the stream's next episode (ending an open one as ``incomplete``).

        ``seed`` is what was passed to ``reset()``; ``options`` the options as recorded before
        it (:func:`~.values.recordable_options`); ``rng_state`` the env's bit-generator state
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
        if options is not None and options.noted is not None:
            notes.append(options.noted)
        episode = Episode(
            file.take_episode_index(),
            recorded_seed,
            None if rng_state is None else file.rng_json(rng_state),
            None if options is None else options.plain,
            file.clock() if start_ns is None else start_ns,
            self.env_index,
            self.agent,
            game,
            None if options is None else options.typed,
            None if options is None else options.text,
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
                episode.options_typed,
            )
            block.resets.append(values)
            untrack(values)
            if notes:
                add_notes(episode, block.reset_notes, row, notes)
        except Exception as exc:  # never break the training loop over recording trouble
            self.file.trouble(exc)

    def cap_block_steps(self, rows: int) -> None:
        """Write a block after at most ``rows`` rows (the file sizes blocks of large rows)."""
        self._block_steps = min(self._block_steps, rows)

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
