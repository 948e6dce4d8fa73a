"""Step a file's episodes in one env: reset each as recorded, then the recorded actions.

:class:`EpisodeRunner` resets every replayable episode from its recorded seed (or RNG state),
steps it with its recorded actions, keeps what the env returns (:mod:`.returned`) and hands the
stepped episodes to a :class:`~.compare.Comparison`. How the time limit is counted and what
makes an episode not replayable: docs/replay.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa

from ..format import names as fmt
from ..format.records import EpisodeRanges, from_json
from ..format.spaces import SpaceCodec, codec_in
from ..format.wrappers import unread_limits
from ..read import Evidence
from ..record.seeding import restore_rng_state
from ..record.state import StateTargets, restore_snapshot
from ..record.time_limits import plain_time_limit, time_limit_hit, time_limits
from .compare import Comparison
from .recorded import (
    ordinal,
    replay_actions,
    reset_options,
    rules_of,
    unread_rng_states,
    unrecorded_options,
)
from .results import (
    RESET_RAISED,
    Divergence,
    EpisodeReplay,
    env_error,
    options_not_held,
    restored_state,
)
from .returned import Ran, Rows, Steps

__all__ = ["EpisodeRunner"]

_SKIPPED = object()
"""What :meth:`EpisodeRunner._reset` returns for an episode it did not reset."""


def _codecs_and_comparison(
    ev: Evidence, env: Any, atol: float
) -> tuple[SpaceCodec | None, SpaceCodec | None, Comparison | None]:
    """The file's observation and action codecs for ``env``'s spaces, and its comparison.

    A space of a class episode-audit does not know: the env's own converts its JSON. ``None``
    for a codec whose space the file does not describe (then no comparison either).
    """
    obs_codec, act_codec = ev.observation_codec, ev.action_codec
    digest = ev.run.recorder.get("digest_min_bytes")
    obs = (
        None
        if obs_codec is None
        else codec_in(obs_codec, env.observation_space, digest_min_bytes=digest)
    )
    act = None if act_codec is None else codec_in(act_codec, env.action_space)
    if obs is None:
        return obs, act, None
    rules, terms_rule = rules_of(ev.run)
    comparison = Comparison(
        str(ev.path),
        obs,
        atol=atol,
        rules=rules,
        terms_rule=terms_rule,
        unread_limits=unread_limits(ev.run.layout),
    )
    return obs, act, comparison


class EpisodeRunner:
    """Replays the episodes of one file in one environment."""

    def __init__(
        self,
        ev: Evidence,
        env: gym.Env[Any, Any],
        *,
        atol: float,
        progress: Callable[[int], None] | None,
    ) -> None:
        self.ev = ev
        self.file = str(ev.path)
        self.env = env
        self.progress = progress
        self.obs_codec, self.act_codec, self.comparison = _codecs_and_comparison(ev, env, atol)
        self.vector = ev.run.layout.get("kind") == "vector"
        self.earlier: dict[int, int] = {}
        """Per episode reset: how many episodes this env was reset for before it."""
        # An outermost Gymnasium TimeLimit is counted by the stepping loop, not called: the
        # same flags, without a wrapper call per step (see plain_time_limit).
        self.counted = plain_time_limit(env)
        self.time_limits = time_limits(env if self.counted is None else self.counted[0])
        """The TimeLimits the stepped env holds (the counted one aside): each one counts."""
        # state snapshots (record/state.py): the reset rows' column, the env's adapted objects
        self.states: pa.ChunkedArray | None = None
        self.typed_options: pa.ChunkedArray | None = None  # the reset rows' options_typed
        self.adapted = bool(StateTargets(env))
        self.restored: dict[int, list[str]] = {}  # what was restored before each reset
        self.raised_again: set[int] = set()
        """Error episodes whose recorded step that raised raised the same again in replay."""
        self._raising: dict[int, Any] = {}  # by error episode: its recorded action that raised
        self._not_raised: dict[int, str] = {}  # by error episode: how its raising step differed
        self._unset_options: dict[int, str] = {}  # by episode: options the file does not hold
        self._unread_rng: dict[int, str] = {}  # by episode: why its RNG state was not recorded

    def _not_replayable(self, index: int, steps: int, reason: str) -> EpisodeReplay:
        return EpisodeReplay(self.file, index, "not_replayable", steps, reason=reason)

    def run_all(
        self,
        records: list[dict[str, Any]],
        steps: pa.Table,
        rows: dict[int, tuple[int, int]],
        reset_rows: dict[int, int],
        resets: pa.Table,
    ) -> list[EpisodeReplay]:
        """Replay ``records`` (in file order): step every episode, then compare in one pass.

        Stepping only keeps what the env returns; the values become columns afterwards, and
        the comparison runs over whole columns at once. Only an episode with a difference is
        looked at on its own, from the mismatch positions.
        """
        done: dict[int, EpisodeReplay] = {}
        if not records:
            return []
        if self.comparison is None or self.act_codec is None:
            for r in records:
                index = int(r["episode"])
                done[index] = self._not_replayable(index, 0, "the file's spaces cannot be rebuilt")
            return [done[int(r["episode"])] for r in records]
        actions, null_rows = replay_actions(steps.column(fmt.COL_ACTION), self.act_codec)
        names = resets.column_names
        self.states = resets.column(fmt.COL_STATE) if fmt.COL_STATE in names else None
        typed = fmt.COL_OPTIONS_TYPED
        self.typed_options = resets.column(typed) if typed in names else None
        self._unset_options = unrecorded_options(resets)
        self._unread_rng = unread_rng_states(resets)
        self._raising = self._raising_actions(records)
        ran, returned, got_obs, got_reset = self._step_all(
            records, actions, null_rows, rows, reset_rows, done
        )
        if ran.records:
            self.comparison.episodes(ran, returned, got_obs, got_reset, steps, resets, done)
        for index, why in self._not_raised.items():
            result = done.get(index)
            if result is not None and result.status == "identical":
                done[index] = self._not_replayable(index, result.steps, why)
        self._not_raised = {}
        return [self._with_restored(done[int(r["episode"])], r) for r in records]

    def _raising_actions(self, records: list[dict[str, Any]]) -> dict[int, Any]:
        """The recorded actions that raised, of ``records``' error episodes (when recorded).

        Read from the file (:meth:`~episode_audit.read.Evidence.error_actions`) only when
        ``records`` has an episode whose step raised.
        """
        raised = {int(r["episode"]) for r in records if _raised_in_step(r)}
        if not raised:
            return {}
        assert self.act_codec is not None
        table = self.ev.error_actions()
        values, _ = replay_actions(table.column(fmt.COL_ACTION), self.act_codec)
        episodes = table.column(fmt.COL_EPISODE).to_pylist()
        return {
            e: value
            for e, value in zip(episodes, values, strict=True)
            if e in raised and value is not None
        }

    def _raise_again(self, step: Callable[[Any], Any], record: dict[str, Any]) -> None:
        """Step an error episode's recorded action that raised, expecting the same error.

        The same exception type: the episode's raise is repeated (:attr:`raised_again`).
        Another, or none: the episode is ``not_replayable`` (an error may come from outside
        the env: memory, files, a network), with what happened.
        """
        index = int(record["episode"])
        recorded = str(record.get("error_type") or "an error")
        nth = ordinal(int(record.get("length") or 0) + 1)
        try:
            step(self._raising[index])
        except Exception as exc:
            if type(exc).__qualname__ == recorded:
                self.raised_again.add(index)
                return
            got = f"raised {env_error(exc)}"
        else:
            got = "did not raise"
        self._not_raised[index] = (
            f"its {nth} step raised {recorded} when recorded, and {got} in replay with the "
            "recorded action (an error may come from outside the env: memory, files, network)"
        )

    def restored_snapshots(self, record: dict[str, Any]) -> list[str]:
        """The state snapshots set before ``record``'s reset, one name each.

        E.g. ``"snapshot of NormalizeObservation"`` (record/state.py, :func:`restore_snapshot`).
        """
        return [f"snapshot of {name}" for name in self.restored.get(int(record["episode"]), ())]

    def _with_restored(self, result: EpisodeReplay, record: dict[str, Any]) -> EpisodeReplay:
        """A diverged ``result``, with what replay restored before its reset."""
        if result.status != "diverged":
            return result
        env = "this env"
        if self.vector:
            env = f"sub-env {int(record.get(fmt.COL_ENV_INDEX) or 0)}'s env"
        restored = restored_state(
            record,
            self.earlier.get(result.episode, 0),
            env=env,
            snapshots=self.restored_snapshots(record),
        )
        return replace(result, restored=restored)

    def _step_all(
        self,
        records: list[dict[str, Any]],
        actions: Any,
        null_rows: np.ndarray[Any, Any] | None,
        rows: dict[int, tuple[int, int]],
        reset_rows: dict[int, int],
        done: dict[int, EpisodeReplay],
    ) -> tuple[Ran, Steps, pa.Array, pa.Array]:
        """Reset and step every replayable episode.

        Returns the stepped episodes, what their steps returned (in order), and the columns
        of their observations and reset observations (copied as they come: an env may
        change an array it returned).

        The steps themselves are :class:`_StepLoop`'s; what is done once per episode and is not
        the usual case (:meth:`_reset`'s refusals, a null action) is in its own method.
        """
        assert self.obs_codec is not None
        env = self.env if self.counted is None else self.counted[0]
        limit = None if self.counted is None else self.counted[1]
        got_obs, got_reset = Rows(self.obs_codec), Rows(self.obs_codec)
        keep_reset = got_reset.keep
        steps = Steps()
        run_steps = _StepLoop(env.step, got_obs, steps).run
        rewards, ends = steps.rewards, steps.ends
        ran = Ran()
        stepped = ran.stepped
        keep_stepped = stepped.append
        limits, progress, reset = self.time_limits, self.progress, self._reset
        has_nulls = null_rows is not None and null_rows.size > 0
        damaged = self.ev.damaged_episodes or None  # (an empty set is not asked)
        no_rows = (0, 0)
        for record in records:
            index = record["episode"]
            start, count = rows.get(index, no_rows)
            reset_at = reset_rows.get(index)
            obs = reset(env, record, index, count, reset_at, damaged, done)
            if obs is _SKIPPED:
                continue
            keep_reset(obs)
            stop = start + count
            crash: Divergence | None = None
            if has_nulls:
                assert null_rows is not None
                stop, crash = _first_null_action(null_rows, start, stop)
            # the TimeLimit truncates its limit-th step, so stepping ends there at the latest
            end = stop if limit is None or stop - start <= limit else start + limit
            before = len(rewards)
            term, trunc, info, failed = run_steps(actions[start:end])
            if failed is not None:
                crash = Divergence(len(rewards) - before, "step", "a step", failed)
            ran_now = len(rewards) - before
            if ran_now == limit:
                trunc = True  # what the TimeLimit sets on its limit-th step
            if ran_now < stop - start and (crash is None or crash.field == "action"):
                crash = None  # it ended early: the length check says so
            # Every step before the last had both flags falsy (stepping stops at the first
            # that has one set): only the last step's are kept.
            if ran_now:
                ends.append((len(rewards) - 1, term, trunc))
            if crash is not None:
                ran.crashes[len(stepped)] = crash
            elif (
                index in self._raising
                and ran_now == count
                and not (term or trunc)
                and (limit is None or ran_now < limit)
            ):
                self._raise_again(env.step, record)
            # the TimeLimit state belongs to this episode: read it now, not after the others
            hit = ran_now == limit or time_limit_hit(limits)
            keep_stepped((record, start, count, ran_now, info if ran_now else {}, hit, reset_at))
            if progress is not None:
                progress(count)
        return ran.finish(), steps, got_obs.finish(), got_reset.finish()

    def _reset(
        self,
        env: gym.Env[Any, Any],
        record: dict[str, Any],
        index: int,
        count: int,
        reset_at: int | None,
        damaged: EpisodeRanges | None,
        done: dict[int, EpisodeReplay],
    ) -> Any:
        """Reset ``env`` for one episode and return its observation.

        An episode that cannot be reset as recorded, or whose reset raises, gets its result
        in ``done`` instead, and this returns ``_SKIPPED``.
        """
        seed = record.get("seed")
        rng_state = record.get("rng_state")
        if seed is None and rng_state is None:
            why = self._unread_rng.get(index)
            done[index] = self._not_replayable(
                index,
                0,
                "no seed or RNG state recorded for its reset" + ("" if why is None else f": {why}"),
            )
            return _SKIPPED
        if damaged is not None and index in damaged:
            done[index] = self._not_replayable(
                index, count, "part of its evidence was in a damaged chunk (skipped by recover)"
            )
            return _SKIPPED
        if reset_at is None:
            why = (
                RESET_RAISED
                if record.get("error_during") == "reset"
                else "its reset row is missing (torn file)"
            )
            done[index] = self._not_replayable(index, count, why)
            return _SKIPPED
        if index in self._unset_options:
            why = options_not_held(self._unset_options[index])
            done[index] = self._not_replayable(index, count, why)
            return _SKIPPED
        try:
            typed = None if self.typed_options is None else self.typed_options[reset_at].as_py()
            options = reset_options(record.get("options"), typed)
            state: Any = None if seed is not None else from_json(str(rng_state), "rng_state")
        except ValueError as exc:
            done[index] = self._not_replayable(index, count, f"its reset record: {exc}")
            return _SKIPPED
        if self.adapted or self.states is not None:
            try:
                snapshot = None if self.states is None else self.states[reset_at].as_py()
                restored = restore_snapshot(env, snapshot, seeded=seed is not None)
            except ValueError as exc:
                done[index] = self._not_replayable(index, count, str(exc))
                return _SKIPPED
            if restored:
                self.restored[index] = restored
        self.earlier[index] = len(self.earlier)
        try:
            if seed is not None:
                obs, _ = env.reset(seed=seed, options=options)
            else:
                restore_rng_state(env, state)
                obs, _ = env.reset(options=options)
        except Exception as exc:
            divergence = Divergence(None, "reset", "a reset", env_error(exc))
            done[index] = EpisodeReplay(self.file, index, "diverged", 0, divergence)
            return _SKIPPED
        return obs


class _StepLoop:
    """Replay's per-step loop: an episode's actions stepped, what each step returned kept.

    Everything a step does is inline (no call, attribute lookup or object per step beyond the
    env's own step); what it needs is read into locals once per episode.
    """

    def __init__(self, env_step: Callable[[Any], Any], got_obs: Rows, steps: Steps) -> None:
        self._env_step = env_step
        self._got_obs = got_obs
        self._steps = steps

    def run(self, actions: Any) -> tuple[Any, Any, Any, Any]:
        """Step ``actions`` until one ends the episode: its flags and info, and the env's error.

        The error (``None`` unless a step raised) is :func:`env_error`'s account of it; the
        flags and info are the last step's (unset when no step ran).
        """
        env_step, got_obs, steps = self._env_step, self._got_obs, self._steps
        keep_raw: Callable[[Any], int] = got_obs.raw.write  # (takes any C-contiguous array)
        keep_other = got_obs.add
        raw_dtype, raw_shape, ndarray = got_obs.dtype, got_obs.shape, np.ndarray
        rewards = steps.rewards
        keep_reward, keep_info = rewards.append, steps.infos.append
        keep_info_row = steps.info_rows.append
        term = trunc = info = None
        try:
            for action in actions:
                obs, reward, term, trunc, info = env_step(action)
                # got_obs.keep(obs), inlined
                if type(obs) is ndarray and obs.dtype is raw_dtype and obs.shape == raw_shape:
                    try:
                        keep_raw(obs)
                    except ValueError:  # not C-contiguous
                        keep_other(obs)
                else:
                    keep_other(obs)
                keep_reward(reward)
                try:
                    if info:
                        keep_info_row(len(rewards) - 1)
                        keep_info(info)
                except Exception:  # an info with no truth value (an array): kept
                    keep_info_row(len(rewards) - 1)
                    keep_info(info)
                try:
                    if term or trunc:
                        break
                except Exception:  # flags with no truth value: False, as the recorder took them
                    term = trunc = False
        except Exception as exc:
            return term, trunc, info, env_error(exc)
        return term, trunc, info, None


def _raised_in_step(record: dict[str, Any]) -> bool:
    """Whether ``record``'s episode ended ``error`` because a step raised."""
    return record.get("outcome") == fmt.OUTCOME_ERROR and record.get("error_during") == "step"


def _first_null_action(
    null_rows: np.ndarray[Any, Any], start: int, stop: int
) -> tuple[int, Divergence | None]:
    """Where an episode's rows ``start .. stop`` stop being steppable, and why if before ``stop``.

    A row with no recorded action (not recordable) ends the stepping there, as a divergence.
    """
    k = int(np.searchsorted(null_rows, start))
    if k < null_rows.size and null_rows[k] < stop:
        null = int(null_rows[k])
        return null, Divergence(
            null - start, "action", "a recorded action", "null (not recordable)"
        )
    return stop, None
