"""One autoreset strategy per mode: where a sub-env's reset row and RNG state come from.

- :class:`Autoreset` — what every mode shares: beginning a sub-env's episode (its reset row,
  with its seed or RNG state), recording a step sub-env by sub-env; ``DISABLED`` is just this
  (episodes begin only by ``reset()``, the RNG state read before it).
- :class:`NextStep` — the step after an ending only resets: its row is the reset row; the RNG
  state is read right after the ending step.
- :class:`SameStep` — the reset runs inside the ending step: the step's row comes from
  ``final_obs`` / ``final_info``, the RNG state from the reset info (:class:`ResetRngInfo`).

The modes themselves: ``docs/format.md``, "Vector files"; the recorder: ``docs/recording.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from gymnasium.vector import AutoresetMode, VectorEnv

from ..fast import BeginAutoreset, EndBatched
from ..notes import note
from ..stream import Stream
from ..values import RecordedOptions
from .infos import EMPTY, env_infos
from .rng import LocalSubEnvs, RngState, SubEnvRng

__all__ = ["Autoreset", "NextStep", "SameStep", "autoreset_mode", "autoreset_strategy"]

_SAME_STEP_NO_RNG = (
    "SAME_STEP autoreset ran inside step(): the sub-env's RNG state before it cannot be read "
    "from outside; wrap the sub-envs in episode_audit.ResetRngInfo "
    "(gym.make_vec(..., wrappers=[ResetRngInfo])) to make such episodes replayable"
)

Result = tuple[Any, Any, Any, Any, Any]


def autoreset_mode(env: VectorEnv[Any, Any, Any]) -> AutoresetMode:
    """The vector env's autoreset mode (``NEXT_STEP`` when it says none, or one unknown)."""
    mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
    if isinstance(mode, AutoresetMode):
        return mode
    try:
        return AutoresetMode(mode)
    except ValueError:
        return AutoresetMode.NEXT_STEP


class Autoreset:
    """How sub-env episodes begin and steps are recorded sub-env by sub-env (``DISABLED``).

    ``resetting`` lists the sub-envs whose current step only resets them, ``pending_rng`` their
    RNG states read after the step before (``NEXT_STEP`` only); ``batches_endings`` says
    whether a step that ends an episode may be batched.
    """

    mode = AutoresetMode.DISABLED
    batches_endings = True

    def __init__(
        self,
        streams: Sequence[Stream],
        rng: SubEnvRng,
        clock: Callable[[], int],
        no_rng_note: str | None,
    ) -> None:
        self.streams = streams
        self.rng = rng
        self._clock = clock
        self._no_rng_note = no_rng_note
        self.resetting: list[int] = []
        self.pending_rng: dict[int, RngState | None] = {}  # of the sub-envs in resetting
        # the compiled autoreset (NEXT_STEP, SAME_STEP), set by VectorSteps when the streams
        # keep no info
        self.compiled_begin: BeginAutoreset | None = None

    def begin(
        self,
        i: int,
        seed: int | None,
        options: RecordedOptions | None,
        rng_state: RngState | None,
        obs: Any,
        info: Any,
        start_ns: int,
        why_no_rng: str | None = None,
        noted: str | None = None,
    ) -> None:
        """Begin sub-env ``i``'s next episode and record its reset row (noted ``noted``)."""
        stream = self.streams[i]
        notes: list[str] = [] if noted is None else [noted]
        if seed is None and rng_state is None:
            notes.append(
                note(
                    "rng_state_unavailable",
                    why_no_rng or self.rng.unread.get(i) or self._no_rng_note or "no np_random",
                )
            )
        state, state_note = self.rng.state_from_info(info)
        if state_note is not None:
            notes.append(state_note)
        episode = stream.begin(seed, options, rng_state, notes, start_ns=start_ns)
        stream.record_reset(episode, obs, info, notes, state)

    def begin_compiled(
        self, i: int, rng: RngState | None, obs: Any, info: Any, now: int, noted: str | None
    ) -> bool:
        """Begin sub-env ``i``'s autoreset episode in C (``compiled_begin``), if it can be.

        It can be when the RNG state is known, nothing is to be noted, and the reset info is a
        dict with no state snapshot nor a note on one (the streams keep no info:
        ``compiled_begin`` is set only then), so that :meth:`begin` would record the same.
        ``False``: nothing has changed.
        """
        begin = self.compiled_begin
        if begin is None or rng is None or noted is not None or type(info) is not dict:
            return False
        if info and self.rng.state_from_info(info) != (None, None):
            return False
        stream = self.streams[i]
        return bool(begin(stream, stream.file.rng_json(rng), obs, now))

    def begin_failed(
        self,
        i: int,
        seed: Any,
        options: RecordedOptions | None,
        rng_state: RngState | None,
        exc: Exception,
    ) -> None:
        """Record sub-env ``i``'s reset that raised ``exc``: an episode ended ``error``.

        The caller has handed the sub-env's batched rows over (or counted them as pending).
        """
        stream = self.streams[i]
        stream.end_open()
        stream.begin(seed, options, rng_state, [])
        stream.end_error(exc, "reset")

    def record_rows(
        self,
        obs_rows: list[Any],
        act_rows: list[Any],
        rewards: list[Any],
        terminated: list[Any],
        truncated: list[Any],
        ended: list[bool],
        infos: Any,
    ) -> None:
        """Record a vector step sub-env by sub-env (a step the batched path could not take).

        The flags are as given where one is to be noted (see ``steps.read_flags``), for the
        stream to note as it would a single env's; ``ended`` is their reading.
        """
        streams = self.streams
        resetting = set(self.resetting)
        now = self._clock()
        sub_infos, unmasked = env_infos(infos, len(streams))
        for i, stream in enumerate(streams):
            info = sub_infos[i]
            if i in resetting:
                self.autoreset(i, obs_rows[i], info, now, unmasked)
                continue
            if unmasked is not None:
                stream.note_next_row([unmasked])
            result = (obs_rows[i], rewards[i], terminated[i], truncated[i], info)
            if ended[i]:
                self.record_ending(i, act_rows[i], result, now, unmasked)
            else:
                stream.step(act_rows[i], result)

    def record_ending(
        self, i: int, action: Any, result: Result, now: int, noted: str | None
    ) -> None:
        """Record sub-env ``i``'s step that ended its episode (``result``: its share)."""
        self.streams[i].step(action, result)

    def autoreset(self, i: int, obs: Any, info: Any, now: int, noted: str | None) -> None:
        """Sub-env ``i``'s step only reset it (``NEXT_STEP``): its next episode's reset row."""
        raise NotImplementedError(f"{self.mode.value} autoresets no sub-env in a step of its own")

    def stepped(self, ends: list[int]) -> None:
        """A vector step was recorded; ``ends`` are the sub-envs whose episodes it ended."""

    def were_reset(self, indices: Sequence[int]) -> None:
        """``reset()`` began new episodes for the sub-envs ``indices``."""

    def failed_autoresets(self, exc: Exception) -> None:
        """The vector step raised ``exc``: record the autoresets of it that failed, if any."""


class NextStep(Autoreset):
    """``NEXT_STEP``: the step after an ending only resets the sub-env (its next reset row).

    Nothing touches the sub-env between the step that ended its episode and that reset, so its
    RNG state read right after the ending step is the one the reset draws from.
    """

    mode = AutoresetMode.NEXT_STEP

    def autoreset(self, i: int, obs: Any, info: Any, now: int, noted: str | None) -> None:
        """Begin sub-env ``i``'s next episode with this step's observation as its reset row."""
        rng = self.rng.from_info(info, i) if info else None
        if rng is None:
            rng = self.pending_rng.pop(i, None)
        if self.begin_compiled(i, rng, obs, info, now, noted):
            return
        self.streams[i].end_open()
        self.begin(i, None, None, rng, obs, info, now, None, noted)

    def stepped(self, ends: list[int]) -> None:
        """The sub-envs whose episodes ``ends`` ended reset on the next step: read their RNGs."""
        self.resetting = ends
        if ends and not self.rng.in_info:
            self.pending_rng = self.rng.capture(ends)

    def were_reset(self, indices: Sequence[int]) -> None:
        """Sub-envs that ``reset()`` reset are no longer due for an autoreset."""
        if self.resetting:
            done = set(indices)
            self.resetting = [i for i in self.resetting if i not in done]
        for i in indices:
            self.pending_rng.pop(i, None)

    def failed_autoresets(self, exc: Exception) -> None:
        """The step was to reset the sub-envs whose episodes ended on the step before.

        Which one raised is known for a ``SyncVectorEnv`` (by :class:`ResetRngInfo`, else the
        sub-env whose ``reset`` is in the exception's traceback); otherwise every one of them
        gets the error. The sub-envs not recorded so stay due for their autoreset (a
        ``SyncVectorEnv`` retries it on its next step), from their RNG states read again.
        """
        failed = self.rng.failed_resets(exc)
        resetting = self.resetting
        if not resetting:
            return
        if not failed:
            raiser = _sync_raiser(self.rng.sync, exc)
            if raiser is None:  # not known: every autoreset of the step may have raised
                failed = dict.fromkeys(resetting, (None, None))
            elif raiser[1] == "reset":
                failed = {raiser[0]: (None, None)}
        for i in resetting:
            if i in failed:
                state = failed[i][0]
                if state is None:
                    state = self.pending_rng.get(i)
                self.begin_failed(i, None, None, state, exc)
        if self.rng.sync is not None and not self.rng.in_info:
            self.pending_rng = self.rng.capture(resetting)  # a failed step may have drawn


class SameStep(Autoreset):
    """``SAME_STEP``: the reset runs inside the step that ended the episode.

    The ending step's row takes ``final_obs`` / ``final_info``; the returned observation and the
    rest of the info are the next episode's reset row, its RNG state the one
    :class:`ResetRngInfo` reported (none otherwise: noted why).
    """

    mode = AutoresetMode.SAME_STEP
    batches_endings = False
    no_rng_why = _SAME_STEP_NO_RNG
    """Why an autoreset episode has no RNG state when the reset info holds none."""

    def record_ending(
        self, i: int, action: Any, result: Result, now: int, noted: str | None
    ) -> None:
        """Record the ending step from the final observation and info, then the reset row."""
        obs, reward, terminated, truncated, info = result
        if isinstance(info, Mapping):
            final = info.get("final_info")
            step_info = final if isinstance(final, Mapping) else EMPTY
            final_obs = info["final_obs"] if "final_obs" in info else obs  # noqa: SIM401
            reset_info: Any = {
                k: v for k, v in info.items() if k not in ("final_info", "final_obs")
            }
        else:  # neither the vector dict form nor a list of dicts (noted)
            step_info = reset_info = info
            final_obs = obs
        terminated, truncated = self._flags_at(i, terminated, truncated, counted=False)
        self.streams[i].step(action, (final_obs, reward, terminated, truncated, step_info))
        self._begin_next(i, obs, reset_info, now, noted)

    def end_batched(
        self,
        i: int,
        flags: tuple[bool, bool],
        final_info: dict[str, Any],
        obs: Any,
        reset_info: dict[str, Any],
        now: int,
        end: EndBatched,
    ) -> None:
        """:meth:`record_ending` for a step the batched path took (its row already counted).

        ``final_info`` is the step's info (``final_info``), ``obs`` and ``reset_info`` the next
        episode's reset row; ``end`` ends the episode (:func:`~..fast.end_batched_function`).
        """
        terminated, truncated = self._flags_at(i, *flags, counted=True)
        stream = self.streams[i]
        end(stream, stream.block.pending, terminated, truncated, final_info)
        self._begin_next(i, obs, reset_info, now, None)

    def _flags_at(
        self, i: int, terminated: Any, truncated: Any, *, counted: bool
    ) -> tuple[Any, Any]:
        """:meth:`ending_flags` of sub-env ``i``'s ending step (``counted``: its row is too)."""
        block = self.streams[i].block
        if not block.segments:
            return terminated, truncated
        step = block.next_step_index() - counted
        return self.ending_flags(i, terminated, truncated, step)

    def ending_flags(self, i: int, terminated: Any, truncated: Any, step: int) -> tuple[Any, Any]:
        """The flags to record sub-env ``i``'s ending step with (``step``: its index): as given."""
        return terminated, truncated

    def _begin_next(self, i: int, obs: Any, reset_info: Any, now: int, noted: str | None) -> None:
        """Begin sub-env ``i``'s next episode from the reset inside the ending step."""
        rng = self.rng.from_info(reset_info, i)
        if self.begin_compiled(i, rng, obs, reset_info, now, noted):
            return
        why = None if rng is not None else self.no_rng_why
        self.begin(i, None, None, rng, obs, reset_info, now, why, noted)

    def failed_autoresets(self, exc: Exception) -> None:
        """A reset that raised after the step that ended the episode, kept by ResetRngInfo.

        That step's result never left the vector env; :class:`ResetRngInfo` kept it: the step
        is recorded (the episode's true ending), then the failed reset. Without it the episode
        ends ``error`` like the others.
        """
        for i, (state, last) in self.rng.failed_resets(exc).items():
            if last is not None:
                self.streams[i].step(*last)
                self.begin_failed(i, None, None, state, exc)


def autoreset_strategy(
    mode: AutoresetMode,
    streams: Sequence[Stream],
    rng: SubEnvRng,
    clock: Callable[[], int],
    no_rng_note: str | None,
) -> Autoreset:
    """The strategy of ``mode``."""
    kind = {AutoresetMode.NEXT_STEP: NextStep, AutoresetMode.SAME_STEP: SameStep}.get(
        mode, Autoreset
    )
    return kind(streams, rng, clock, no_rng_note)


def _sync_raiser(sync: LocalSubEnvs | None, exc: Exception) -> tuple[int, str] | None:
    """The ``SyncVectorEnv`` sub-env whose ``reset`` or ``step`` raised ``exc``, if known.

    The sub-env's own method is in the exception's traceback (the vector env calls it).
    """
    if sync is None:
        return None
    envs = {id(env): i for i, env in enumerate(sync.envs)}
    tb = exc.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        name = frame.f_code.co_name
        if name in ("reset", "step"):
            i = envs.get(id(frame.f_locals.get("self")))
            if i is not None:
                return i, name
        tb = tb.tb_next
    return None
