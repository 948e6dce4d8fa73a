"""How a vector step is recorded: batched when it can be, sub-env by sub-env otherwise.

:class:`VectorSteps` is the vector recorder's hot path. A step without info, or whose info holds
only what the batched path takes (``SAME_STEP`` endings' final observations and infos; reward
terms, :mod:`.terms`), and without values that need a cast or flags that are not a bool array,
is written into preallocated batch buffers with its time; every
:data:`BATCH_STEPS` vector steps (fewer for big rows: :data:`BATCH_BYTES`), and at each flush,
each sub-env's rows are handed to its stream in bulk. Only episode boundaries are handled per
sub-env, at the rows they will have.
Any other step goes to the autoreset strategy, sub-env by sub-env (``docs/recording.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.spaces import Space
from gymnasium.vector.utils import iterate

from ...format.spaces import SpaceCodec
from ..fast import (
    VectorStep,
    begin_autoreset_function,
    end_batched_function,
    vector_step_function,
)
from ..file import EvidenceFile
from ..stream import Stream
from .batch import Batch
from .boundaries import Boundaries
from .infos import EMPTY, env_infos
from .modes import Autoreset, SameStep
from .terms import StepTerms, TermColumns, TermNames, list_terms

__all__ = ["VectorSteps", "per_env", "read_flags"]

_BOOLS = frozenset({bool, np.bool_})
_BOOL = np.dtype(np.bool_)

_Bools = np.ndarray[Any, np.dtype[np.bool_]]
_SameStepEndings = dict[int, tuple[Any, dict[str, Any], dict[str, Any]]]
_FINAL = ("final_obs", "final_info")


def _fits(values: Any, shape: tuple[int, ...], dtype: Any) -> bool:
    """Whether a batch can be stored as it is (exact shape; dtype, or any signed int for int)."""
    return (
        type(values) is np.ndarray
        and values.shape == shape
        and (values.dtype == dtype or (dtype.kind == "i" and values.dtype.kind == "i"))
    )


def per_env(values: Any, n: int) -> list[Any]:
    """One value per sub-env from a batch (an array, or a list from a vector env of its own).

    Numbers come out as Python numbers; anything else is handed on as it is, for the stream to
    record and note as the single-env recorder would (e.g. a reward that is text).
    """
    if isinstance(values, np.ndarray) and values.shape == (n,) and values.dtype.kind in "biuf":
        return values.tolist()  # type: ignore[no-any-return]
    try:
        items = list(values)
    except TypeError:
        return [values] * n
    return items if len(items) == n else [values] * n


def read_flags(values: Any, n: int) -> tuple[_Bools, list[Any] | None]:
    """A batch of flags (``terminated`` or ``truncated``) read, and as given if one is noted.

    A bool array of ``n`` (what Gymnasium's vector envs return) is taken as it is: one check.
    Anything else is read flag by flag as the single-env recorder reads a flag: a flag with no
    truth value is false, and it or a true flag that is not a ``bool`` (the text ``"False"``,
    the int ``1``) is noted ``flags_not_bool`` by the stream that records it as given.
    """
    if type(values) is np.ndarray and values.dtype is _BOOL and values.shape == (n,):
        return values, None
    given = per_env(values, n)
    truths: list[bool] = []
    odd = False
    for value in given:
        try:
            truth = bool(value)
        except Exception:  # no truth value (an array of several)
            truth, odd = False, True
        else:
            odd = odd or (truth and type(value) not in _BOOLS)
        truths.append(truth)
    return np.array(truths, dtype=np.bool_), given if odd else None


def _same_step_endings(
    infos: Any,
    ends: list[int],
    n: int,
    shape: tuple[int, ...],
    dtype: Any,
    names_for: TermNames,
) -> tuple[_SameStepEndings, StepTerms] | None:
    """A SAME_STEP step's endings and reward terms, if the batched path can take the step.

    It can when each ending sub-env's info holds a final observation of one row's ``shape``
    and ``dtype`` and a ``final_info`` dict (the ending rules read it as they would on the
    slow path), and :func:`~.terms.list_terms` takes the step's terms: the endings' from their
    ``final_info``, the other sub-envs' from their infos.
    """
    subs, unmasked = env_infos(infos, n)
    if unmasked is not None:
        return None
    out: _SameStepEndings = {}
    for i in ends:
        info = subs[i]
        if type(info) is not dict or "final_obs" not in info:
            return None
        final_obs, final_info = info["final_obs"], info.get("final_info")
        if type(final_info) is not dict or not _fits(final_obs, shape, dtype):
            return None
        reset_info = {k: v for k, v in info.items() if k not in _FINAL}
        out[i] = (final_obs, final_info, reset_info)
    terms = list_terms(subs, (), names_for, {i: e[1] for i, e in out.items()})
    return None if terms is None else (out, terms)


class VectorSteps(Boundaries):
    """Record vector steps: whole batches while they need nothing per sub-env (the hot path).

    ``idle`` is the set of sub-envs without a running episode (never reset, or ended), ``None``
    when not known (then worked out on the next step). Resets and failures: :class:`Boundaries`.
    """

    def __init__(
        self,
        file: EvidenceFile,
        streams: list[Stream],
        autoreset: Autoreset,
        obs_space: Space[Any],
        act_space: Space[Any],
        codecs: tuple[SpaceCodec, SpaceCodec],
        single_spaces: tuple[Space[Any], Space[Any]],
        track_info: bool,
    ) -> None:
        n = len(streams)
        self._n = n
        self._file = file
        self._streams = streams
        self._autoreset = autoreset
        self._batches_endings = autoreset.batches_endings  # read per step: kept here
        self._obs_space = obs_space
        self._act_space = act_space
        single_obs, single_act = single_spaces
        obs_codec, act_codec = codecs
        self._obs_shape = (n, *(single_obs.shape or ()))
        self._act_shape = (n, *(single_act.shape or ()))
        self._obs_dtype = single_obs.dtype
        self._act_dtype = single_act.dtype
        self._batchable = (
            not track_info
            and self._obs_dtype is not None
            and self._act_dtype is not None
            and obs_codec.new_buffer().extend(np.zeros((0, *self._obs_shape[1:]), self._obs_dtype))
            and act_codec.new_buffer().extend(np.zeros((0, *self._act_shape[1:]), self._act_dtype))
        )
        # the common batched step in C, or None (the Python path: _batch_step)
        self._compiled = vector_step_function() if self._batchable else None
        self._end_batched = end_batched_function()
        if self._batchable:  # (the streams keep no info)
            autoreset.compiled_begin = begin_autoreset_function()
        # the batched steps' rows, and their reward terms read by the streams' rule (the file's
        # one rule: any stream says); no terms: steps with infos are not batched
        terms = TermColumns(n, streams[0].term_names) if self._batchable else None
        self._batch = Batch(streams, terms)
        self._terms = terms
        self._since_flush = 0
        self._block_steps = file.block_steps  # capped by start() for big rows
        self.idle: set[int] | None = None
        self._no_infos = [EMPTY] * n  # a DictInfoToList info without values
        self._flags_shape = (n,)
        file.before_flush.append(self._on_flush)

    def record(self, actions: Any, result: tuple[Any, ...]) -> None:
        """Record one vector step (``result``: what the vector env's ``step`` returned)."""
        if self._compiled is not None and self._compiled_step(self._compiled, actions, result):
            return
        obs, rewards, terminated, truncated, infos = result
        n = self._n
        if (
            type(terminated) is np.ndarray
            and type(truncated) is np.ndarray
            and terminated.dtype is _BOOL
            and truncated.dtype is _BOOL
            and terminated.shape == truncated.shape == self._flags_shape
        ):  # the common case (Gymnasium's vector envs), checked once per vector step
            term, trunc, term_given, trunc_given = terminated, truncated, None, None
        else:
            term, term_given = read_flags(terminated, n)
            trunc, trunc_given = read_flags(truncated, n)
        ended = (term | trunc).tolist()
        ends = [i for i, e in enumerate(ended) if e] if True in ended else []
        autoreset = self._autoreset
        resetting = autoreset.resetting  # NEXT_STEP: the sub-envs this step only resets
        idle = self.idle
        if idle is None:
            idle = self.idle = {
                i for i, s in enumerate(self._streams) if s.episode is None or s.episode.ended
            }
        taken = self._infos_taken(infos, ends, resetting) if self._batchable else None
        if (
            taken is not None
            and (not idle or idle.issubset(resetting))  # else: notes (before reset, after end)
            and term_given is None  # else: flags to note (not bool)
            and trunc_given is None
            and type(rewards) is np.ndarray
            and rewards.shape == (n,)
            and rewards.dtype.kind in "biuf"
            and _fits(obs, self._obs_shape, self._obs_dtype)
            and _fits(actions, self._act_shape, self._act_dtype)
        ):
            self._batch_step(obs, actions, rewards, term, trunc, ends, resetting, *taken)
        else:
            self.drain()
            self.idle = None
            autoreset.record_rows(
                list(iterate(self._obs_space, obs)),
                list(iterate(self._act_space, actions)),
                per_env(rewards, n),
                term.tolist() if term_given is None else term_given,
                trunc.tolist() if trunc_given is None else trunc_given,
                ended,
                infos,
            )
        if ends or resetting:
            autoreset.stepped(ends)

    def _infos_taken(
        self, infos: Any, ends: list[int], resetting: list[int]
    ) -> tuple[_SameStepEndings | None, StepTerms | None] | None:
        """What the batched path keeps of a step's ``infos``, or ``None`` when it cannot.

        Its ``SAME_STEP`` endings (final observations and infos, :func:`_same_step_endings`)
        and its reward terms (:class:`~.terms.TermColumns`); a step without info has neither.
        """
        if (type(infos) is dict and not infos) or (type(infos) is list and infos == self._no_infos):
            return (None, None) if self._batches_endings or not ends else None
        columns = self._terms
        if columns is None:
            return None
        if ends and not self._batches_endings:
            shape, dtype = self._obs_shape[1:], self._obs_dtype
            return _same_step_endings(infos, ends, self._n, shape, dtype, columns.names_for)
        terms = columns.read(infos, resetting)
        return None if terms is None else (None, terms)

    def _compiled_step(self, step: VectorStep, actions: Any, result: tuple[Any, ...]) -> bool:
        """Take the common batched step in C (:func:`~..fast.vector_step_function`).

        Whether it did: it does when the step has no info and needs no note, and its values go
        into the batch buffers as they are; else nothing has changed.
        """
        obs, rewards, terminated, truncated, infos = result
        batch, idle, autoreset = self._batch, self.idle, self._autoreset
        held = batch.obs
        resetting = autoreset.resetting
        if held is None or idle is None or (idle and not idle.issubset(resetting)):
            return False
        terms, columns = None, self._terms
        if not (
            (type(infos) is dict and not infos) or (type(infos) is list and infos == self._no_infos)
        ):
            if columns is None:
                return False
            terms = columns.read(infos, resetting)
            if terms is None or not columns.fits(terms):
                return False
        t = batch.length
        taken = step(
            held,
            batch.act,
            batch.rew,
            batch.time,
            t,
            obs,
            actions,
            rewards,
            terminated,
            truncated,
            self._file.clock,
            self._batches_endings,
        )
        if taken is None:
            return False
        now, ends = taken
        if terms is not None and columns is not None:
            columns.keep(t, batch.rows, terms)
        batch.length = t + 1
        self._batched(t, obs, terminated, truncated, ends, resetting, None, now, terms)
        if ends or resetting:
            autoreset.stepped(ends)
        return True

    def _batch_step(
        self,
        obs: np.ndarray[Any, Any],
        actions: np.ndarray[Any, Any],
        rewards: Any,
        term: _Bools,
        trunc: _Bools,
        ends: list[int],
        resetting: list[int],
        same: _SameStepEndings | None = None,
        terms: StepTerms | None = None,
    ) -> None:
        """A step the batched path takes: keep it; hand rows to the streams in bulk later.

        Only episode boundaries are handled per sub-env: the NEXT_STEP autoresets (reset rows)
        and the endings (at the rows they will have: each block's ``pending`` counts the rows
        batched for it); ``same``: the SAME_STEP endings' final observations (their rows) and
        infos, and the reset rows that follow them; ``terms``: the step's info, whose reward
        terms are kept with the batch.
        """
        file = self._file
        now = file.clock()
        batch, columns = self._batch, self._terms
        held = batch.obs
        if (
            held is None
            or held.dtype != obs.dtype
            or batch.act.dtype != actions.dtype
            or (terms is not None and columns is not None and not columns.fits(terms))
        ):
            batch.hold(obs, actions)  # a batch as numpy would stack it: one dtype per column
            held = batch.obs
            assert held is not None
        t = batch.length
        batch.rew[t] = rewards  # (a number of any kind: never fails) before the rest
        held[t] = obs
        batch.act[t] = actions
        batch.time[t] = now
        if same is not None:
            for i, (final_obs, _, _) in same.items():
                held[t, i] = final_obs
        if terms is not None and columns is not None:
            columns.keep(t, batch.rows, terms)
        batch.length = t + 1
        self._batched(t, obs, term, trunc, ends, resetting, same, now, terms)

    def _batched(
        self,
        t: int,
        obs: np.ndarray[Any, Any],
        term: _Bools,
        trunc: _Bools,
        ends: list[int],
        resetting: list[int],
        same: _SameStepEndings | None,
        now: int,
        terms: StepTerms | None = None,
    ) -> None:
        """Batched step ``t`` is written: its episode boundaries, then a flush or drain if due.

        ``terms``: the step's info (its endings are read with each sub-env's).
        """
        file = self._file
        if resetting or ends:
            streams, batch = self._streams, self._batch
            for i in resetting:
                # NEXT_STEP autoreset: the reset row of the sub-env's next episode, not a step.
                streams[i].block.pending = batch.only_reset(t, i)
                self._autoreset.autoreset(i, obs[i], EMPTY, now, None)
            idle = self.idle
            if idle:
                idle.difference_update(resetting)
            for i in ends:
                if resetting and i in resetting:
                    continue  # a reset step has no flags (Gymnasium clears them)
                flags = bool(term[i]), bool(trunc[i])
                if same is not None:  # the ending, then the reset inside the same step
                    streams[i].block.pending = batch.pending_rows(i)
                    _, final_info, reset_info = same[i]
                    assert isinstance(self._autoreset, SameStep)  # (only it does not batch them)
                    self._autoreset.end_batched(
                        i, flags, final_info, obs[i], reset_info, now, self._end_batched
                    )
                    continue
                info = EMPTY if terms is None else terms.env_info(i)
                self._end_batched(streams[i], batch.pending_rows(i), *flags, info)
                if idle is not None:
                    idle.add(i)
        self._since_flush += 1
        if self._since_flush >= self._block_steps or now >= file.flush_at:
            file.auto_flush()
        batch = self._batch
        if batch.length >= batch.rows:  # (a flush has drained them, unless it could not)
            batch.drain()

    def drain(self) -> None:
        """Hand the batched rows over to each sub-env's stream (before any other row)."""
        self._batch.drain()

    def _on_flush(self) -> None:
        self._batch.drain()
        self._since_flush = 0
