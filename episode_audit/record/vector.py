"""Record a ``gymnasium.vector.VectorEnv``: one episode stream per sub-env, in one evidence file.

- :class:`RecordVectorEvidence` — a ``gymnasium.vector.VectorWrapper`` over any vector env
  (``SyncVectorEnv``, ``AsyncVectorEnv``, ``gym.make_vec``) in any autoreset mode.
- :class:`ResetRngInfo` — a small sub-env wrapper that puts the env's RNG state from just before
  an unseeded reset into the reset's info, for the one case the recorder cannot read it from
  outside (``SAME_STEP`` autoreset on an ``AsyncVectorEnv``).

Autoreset modes (https://farama.org/Vector-Autoreset-Mode):

- ``NEXT_STEP`` (default): the step after a sub-env's episode ended is a reset (reward 0, flags
  False, action ignored). It is recorded as the **reset row** of the sub-env's next episode, never
  as a step. Nothing touches the sub-env between the step that ended its episode and that reset,
  so its RNG state read right after the ending step (``envs[i]`` of a ``SyncVectorEnv``;
  ``get_attr("np_random")`` of an ``AsyncVectorEnv``, once for the step, whatever the number of
  ended sub-envs) is exactly the state the reset draws from.
- ``SAME_STEP``: the reset runs inside ``step()``; the ending step's observation and info are
  read from ``info["final_obs"]`` / ``info["final_info"]``. The RNG state before that reset
  cannot be read from outside afterwards: the recorder wraps each sub-env of a ``SyncVectorEnv``
  in :class:`ResetRngInfo` (in place, at construction); for an ``AsyncVectorEnv`` pass
  ``gym.make_vec(..., wrappers=[ResetRngInfo])``. Without it those episodes are recorded as not
  replayable, with a note saying why (``check`` reports it).
- ``DISABLED``: the user resets ended sub-envs with ``reset(options={"reset_mask": mask})``;
  the recorder captures the RNG state of the masked unseeded sub-envs before the reset.

``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (a list seeds each in turn), and each
episode records its own seed. A vector env built from a ``vector_entry_point`` (CartPole's own
``CartPoleVectorEnv``, which ``gym.make_vec`` picks by default) has no sub-envs: it is recorded
the same way, but its episodes are marked not replayable on their own.

The hot path is batched: a vector step without info (and, in ``SAME_STEP`` mode, without an
ending) keeps copies of the batch arrays (observations, actions, rewards) and one time; every
256 vector steps, and at each flush, each sub-env's rows are handed to its stream in bulk. Only
episode boundaries (autoresets, endings) are handled per sub-env when they happen, at the rows
they will have. Steps with info (e.g. MuJoCo ``reward_*`` terms), or with values that need a cast,
are recorded sub-env by sub-env as :class:`~episode_audit.RecordEvidence` records a step, with
per-sub-env info dicts taken from the vector info (``info[k][i]`` where ``info["_k"][i]``; a key
without a mask is taken as every sub-env's, noted ``info_unmasked``), or from a list of
per-sub-env infos (Gymnasium's ``DictInfoToList``). So are steps of a sub-env without a running
episode (stepped before its reset, or after its episode ended), and steps whose flags are not a
bool array, which are noted as the single-env recorder notes them.

Wrap the vector env itself (innermost): replay rebuilds one sub-env from its spec.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv, VectorEnv
from gymnasium.vector.utils import iterate
from typing_extensions import Unpack

from ..format import names as fmt
from ..format.records import to_json
from ..format.spaces import codec_for, describe_space
from .file import EvidenceFile
from .notes import note
from .rules import find_time_limit
from .seeding import capture_rng_state
from .settings import RecorderOptions, RecorderSettings, run_info
from .stream import Stream

__all__ = ["RecordVectorEvidence", "ResetRngInfo"]

_EMPTY: dict[str, Any] = {}
_BATCH_STEPS = 256  # vector steps batched before their rows are handed to the streams
_BOOLS = frozenset({bool, np.bool_})
_BOOL = np.dtype(np.bool_)


def _fits(values: Any, shape: tuple[int, ...], dtype: Any) -> bool:
    """Whether a batch can be stored as it is (exact shape; dtype, or any signed int for int)."""
    return (
        type(values) is np.ndarray
        and values.shape == shape
        and (values.dtype == dtype or (dtype.kind == "i" and values.dtype.kind == "i"))
    )


class ResetRngInfo(gym.Wrapper[Any, Any, Any, Any]):
    """Put the env's RNG state from just before an unseeded ``reset()`` into its info.

    The state (``env.unwrapped.np_random.bit_generator.state``) goes to
    ``info["episode_audit.rng_state"]`` as JSON text. :class:`RecordVectorEvidence` reads it to make
    episodes that a vector env resets by itself replayable on their own. The wrapper changes
    nothing else, and it is invisible in the env's spec (replay does not need it).

    It also remembers its last step since a reset, and a reset that raised (with that step and
    the RNG state it started from), so that the recorder of a ``SyncVectorEnv`` can record an
    autoreset that raised inside ``step()`` where it belongs: after the step that ended the
    episode, as an episode of its own that ended ``error`` during ``reset``.

    >>> import gymnasium as gym
    >>> env = ResetRngInfo(gym.make("CartPole-v1"))
    >>> _, info = env.reset(seed=1)
    >>> "episode_audit.rng_state" in info
    False
    >>> _, info = env.reset()
    >>> sorted(json.loads(info["episode_audit.rng_state"]))
    ['bit_generator', 'has_uint32', 'state', 'uinteger']
    """

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self._last_step: tuple[Any, Any] | None = None  # (action, result) since the last reset
        # a reset that raised: (the exception, the RNG state before it, the step before it)
        self._failed_reset: tuple[BaseException, Any, tuple[Any, Any] | None] | None = None

    def step(self, action: Any) -> Any:
        """Step the env (remembering the step until the next reset)."""
        result = self.env.step(action)
        self._last_step = (action, result)
        return result

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the env; an unseeded reset's info gains the RNG state it started from."""
        state = capture_rng_state(self.env) if seed is None else None
        last, self._last_step = self._last_step, None
        try:
            result = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            self._failed_reset = (exc, state, last)
            raise
        self._failed_reset = None
        obs, info = result
        if state is not None:
            info = {**info, fmt.INFO_RNG_STATE: to_json(state).decode()}
        return obs, info

    @property
    def spec(self) -> Any:  # type: ignore[override]
        """The wrapped env's spec: this wrapper only observes."""
        return self.env.spec


def _entries(value: Any, n: int) -> Any:
    """``value`` itself if it holds one entry per sub-env (an array, a list or a tuple of n)."""
    if isinstance(value, np.ndarray):
        return value if value.ndim and len(value) == n else None
    if isinstance(value, (list, tuple)) and len(value) == n:
        return value
    return None


def _split_info(
    infos: Mapping[Any, Any], n: int, prefix: str = ""
) -> tuple[list[dict[Any, Any]], list[str]]:
    """Each sub-env's info from a vector info dict, and the keys read without a mask.

    A key ``k`` with a mask ``_k`` (Gymnasium's vector envs give every key one): ``infos[k][i]``
    where ``infos["_k"][i]`` is set. A key without one (a vector env of one's own may leave them
    out) is taken as present for every sub-env: a value of ``n`` entries (an array, a list or a
    tuple) as each sub-env's own entry, any other value as the same for every sub-env. Such keys
    are returned (dotted within nested dicts, which are read the same way) so that the rows they
    reached can say so: that reading is a guess.
    """
    outs: list[dict[Any, Any]] = [{} for _ in range(n)]
    guessed: list[str] = []
    for key, value in infos.items():
        mask = infos.get(f"_{key}")
        present = None if mask is None else _entries(mask, n)
        if present is None and type(key) is str and key[:1] == "_" and key[1:] in infos:
            continue  # the mask of another key
        if isinstance(value, Mapping):
            values, inner = _split_info(value, n, f"{prefix}{key}.")
            guessed += inner
        else:
            values = _entries(value, n)
            if values is None:  # not one entry per sub-env (masked or not)
                values = [value] * n
                guessed.append(f"{prefix}{key} (the same for every sub-env)")
            elif present is None:
                guessed.append(f"{prefix}{key}")
        if present is None:
            if mask is not None:  # a mask that is not one truth value per sub-env
                guessed.append(f"{prefix}_{key} (not a mask of {n})")
            if isinstance(value, Mapping):
                for out, sub in zip(outs, values, strict=True):
                    if sub:
                        out[key] = sub
            else:
                for i, out in enumerate(outs):
                    out[key] = values[i]
            continue
        if isinstance(present, np.ndarray):
            present = present.tolist()
        for i, here in enumerate(present):
            if here:
                outs[i][key] = values[i]
    return outs, guessed


def _env_infos(infos: Any, n: int) -> tuple[list[Any], str | None]:
    """Each sub-env's info from a vector step's or reset's info, as the sub-env would give it.

    The vector dict form (:func:`_split_info`), or a list of per-sub-env infos (what Gymnasium's
    ``DictInfoToList`` makes of it); anything else is handed on as it is (the stream notes an
    info that is not a dict). Also the ``info_unmasked`` note for every sub-env's row when the
    dict had keys without a ``_key`` mask (``None`` when it had none).
    """
    if isinstance(infos, Mapping):
        if not infos:
            return [_EMPTY] * n, None
        outs, guessed = _split_info(infos, n)
        if not guessed:
            return outs, None
        return outs, note(
            "info_unmasked",
            f"vector info without a '_<key>' mask of {n} truth values for {', '.join(guessed)}: "
            f"taken as present for every sub-env, a value of {n} entries as one entry each",
        )
    if isinstance(infos, (list, tuple)) and len(infos) == n:
        return list(infos), None
    return [infos] * n, None


def _per_env(values: Any, n: int) -> list[Any]:
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


def _flags(values: Any, n: int) -> tuple[np.ndarray[Any, np.dtype[np.bool_]], list[Any] | None]:
    """A batch of flags (``terminated`` or ``truncated``) read, and as given if one is noted.

    A bool array of ``n`` (what Gymnasium's vector envs return) is taken as it is: one check.
    Anything else is read flag by flag as the single-env recorder reads a flag: a flag with no
    truth value is false, and it or a true flag that is not a ``bool`` (the text ``"False"``,
    the int ``1``) is noted ``flags_not_bool`` by the stream that records it as given.
    """
    if type(values) is np.ndarray and values.dtype is _BOOL and values.shape == (n,):
        return values, None
    given = _per_env(values, n)
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


def _rejected(seed: Any, options: Any, n: int) -> bool:
    """Whether Gymnasium's vector envs refuse these reset arguments before resetting any sub-env.

    (A seed that is neither ``None``, an int nor ``n`` seeds; a ``reset_mask`` that is not a bool
    array of shape ``(n,)`` with a true value.) Such a refused reset changes no episode.
    """
    if seed is not None and not isinstance(seed, int):
        try:
            if len(seed) != n:
                return True
        except TypeError:
            return True
    if isinstance(options, Mapping) and "reset_mask" in options:
        mask = options["reset_mask"]
        return not (
            isinstance(mask, np.ndarray)
            and mask.shape == (n,)
            and mask.dtype == np.bool_
            and bool(mask.any())
        )
    return False


def _autoreset_mode(env: VectorEnv[Any, Any, Any]) -> AutoresetMode:
    mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
    if isinstance(mode, AutoresetMode):
        return mode
    try:
        return AutoresetMode(mode)
    except ValueError:
        return AutoresetMode.NEXT_STEP


class RecordVectorEvidence(gym.vector.VectorWrapper):
    """Record every sub-env episode of a vector env to one MCAP evidence file.

    Each sub-env is a stream of its own (its index is the episodes' ``env_index``); an episode
    stores its reset seed or the sub-env's RNG state before the reset, so every sub-env episode,
    those an autoreset started included, can be replayed on its own by rebuilding one sub-env
    (see the module docstring for how each autoreset mode is handled and why).

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from episode_audit import RecordVectorEvidence, open_evidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "vec.mcap"
        >>> envs = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync", max_episode_steps=3)
        >>> with RecordVectorEvidence(envs, path) as envs:
        ...     _ = envs.reset(seed=5)
        ...     for _ in range(4):  # 3 steps, then the autoreset step
        ...         _ = envs.step(envs.action_space.sample())
        >>> ep = open_evidence(path).episodes().to_pylist()
        >>> [(e["env_index"], e["seed"], e["outcome"], e["length"]) for e in ep[:2]]
        [(0, 5, 'truncated', 3), (1, 6, 'truncated', 3)]

    Args:
        env: The vector env to record (wrap it directly: replay rebuilds one sub-env).
        path: The evidence file to create (never overwritten unless ``overwrite=True``).
        install_rng_info: For a ``SyncVectorEnv`` in ``SAME_STEP`` mode, wrap its sub-envs in
            :class:`ResetRngInfo` in place (default), so autoreset episodes are replayable.
        tags, reward_terms, constant_terms, ending_rules, info_keys, digest_min_bytes,
        block_steps, flush_every_s, fsync, overwrite, command_line: as for
            :class:`~episode_audit.RecordEvidence` (``block_steps`` counts rows per sub-env).
    """

    def __init__(
        self,
        env: VectorEnv[Any, Any, Any],
        path: str | os.PathLike[str],
        *,
        install_rng_info: bool = True,
        **options: Unpack[RecorderOptions],
    ) -> None:
        super().__init__(env)
        settings = RecorderSettings.of(options, "RecordVectorEvidence.__init__()")
        base = env.unwrapped
        self._mode = _autoreset_mode(env)
        self._sync = base if isinstance(base, SyncVectorEnv) else None
        self._async = base if isinstance(base, AsyncVectorEnv) else None
        self._sub_envs = self._sync is not None or self._async is not None
        n = int(env.num_envs)
        self._n = n
        sub_spec = self._sub_spec(env)
        notes: list[str] = []
        self._no_rng_note: str | None = None
        if not self._sub_envs:
            self._no_rng_note = (
                f"{type(base).__name__} has no sub-envs (a vector_entry_point env): its episodes "
                "cannot be replayed on their own"
            )
            notes.append(self._no_rng_note)
        self._rng_in_info = False
        # the sub-envs' unwrapped envs, whose np_random resets draw from (Sync only)
        self._sync_unwrapped = [] if self._sync is None else [e.unwrapped for e in self._sync.envs]
        if self._mode is AutoresetMode.SAME_STEP and self._sync is not None and install_rng_info:
            for i, sub in enumerate(self._sync.envs):
                if _rng_wrapper(sub) is None:
                    self._sync.envs[i] = ResetRngInfo(sub)
            self._rng_in_info = True
        obs_space, act_space = env.single_observation_space, env.single_action_space
        layout: dict[str, Any] = {
            "kind": "vector",
            "num_envs": n,
            "agents": [],
            "autoreset_mode": self._mode.value,
            "vector_class": type(base).__name__,
            "sub_envs": self._sub_envs,
        }
        if self._no_rng_note:
            layout["replay_note"] = self._no_rng_note
        self.run_info = run_info(
            settings=settings,
            spec=sub_spec,
            observation_space=describe_space(obs_space),
            action_space=describe_space(act_space),
            layout=layout,
            notes=notes,
        )
        self._file = EvidenceFile(path, self.run_info, settings, owner=self)
        self.path = self._file.path
        obs_codec = codec_for(obs_space, digest_min_bytes=settings.digest_min_bytes)
        act_codec = codec_for(act_space)
        self._streams: list[Stream] = [
            self._file.add_stream(obs_codec, act_codec, env_index=i, max_episode_steps=limit)
            for i, limit in enumerate(self._max_steps(sub_spec))
        ]
        self._file.start()
        self._file.before_flush.append(self._on_flush)
        # Batched rows (steps without info): whole vector steps, handed over by _drain.
        single_obs, single_act = obs_space, act_space
        self._obs_shape = (n, *(single_obs.shape or ()))
        self._act_shape = (n, *(single_act.shape or ()))
        self._obs_dtype = single_obs.dtype
        self._act_dtype = single_act.dtype
        self._batchable = (
            not settings.track_info
            and self._obs_dtype is not None
            and self._act_dtype is not None
            and obs_codec.new_buffer().extend(np.zeros((0, *self._obs_shape[1:]), self._obs_dtype))
            and act_codec.new_buffer().extend(np.zeros((0, *self._act_shape[1:]), self._act_dtype))
        )
        self._p_len = 0  # vector steps batched
        self._p_skip = [0] * n  # of those, the ones each sub-env spent resetting (no row)
        self._p_obs: list[np.ndarray[Any, Any]] = []
        self._p_act: list[np.ndarray[Any, Any]] = []
        self._p_rew: list[np.ndarray[Any, Any]] = []
        self._p_time: list[int] = []
        self._p_mask: list[list[int]] = []  # per batched step: the sub-envs that only reset
        self._since_flush = 0
        self._block_steps = self._file.block_steps  # capped by start() for big rows
        self._obs_space = env.observation_space
        self._act_space = env.action_space
        # NEXT_STEP: the sub-envs whose next step is their autoreset, and their RNG states.
        self._resetting: list[int] = []
        # the sub-envs without a running episode (never reset, or ended); None: not known now
        self._idle: set[int] | None = None
        self._no_infos = [_EMPTY] * n  # a DictInfoToList info without values
        self._flags_shape = (n,)
        self._pending_rng: dict[int, dict[str, Any] | None] = {}
        self._closed = False

    # ------------------------------------------------------------------ setup helpers

    def _sub_spec(self, env: VectorEnv[Any, Any, Any]) -> Any:
        """The spec of one sub-env (what replay rebuilds), or ``None``."""
        try:
            if self._sync is not None:
                return self._sync.envs[0].spec
            if self._async is not None:
                return self._async.get_attr("spec")[0]
        except Exception:
            return None
        spec = env.spec
        if spec is None:
            return None
        kwargs = {
            k: v
            for k, v in spec.kwargs.items()
            if k not in ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")
        }
        return dataclasses.replace(spec, kwargs=kwargs)

    def _max_steps(self, sub_spec: Any) -> list[int | None]:
        """Each sub-env's step limit: its ``TimeLimit``'s, else its spec's.

        The limit is counted by the stream (a ``SAME_STEP`` autoreset has zeroed the wrapper's
        own count by the time the ending is recorded). A ``SyncVectorEnv``'s sub-envs are
        searched for a ``TimeLimit`` directly. An ``AsyncVectorEnv``'s are asked for
        ``_max_episode_steps`` (``TimeLimit``'s), but only when every one says it has it
        (``has_wrapper_attr``, which every ``gymnasium.Env`` has): a worker asked for an
        attribute its env lacks raises, and that ends the worker.
        """
        limits: list[int | None] = [getattr(sub_spec, "max_episode_steps", None)] * self._n
        found: Sequence[Any] = ()
        if self._sync is not None:
            found = [
                getattr(find_time_limit(sub), "_max_episode_steps", None) for sub in self._sync.envs
            ]
        elif self._async is not None:
            try:
                if all(self._async.call("has_wrapper_attr", "_max_episode_steps")):
                    found = self._async.get_attr("_max_episode_steps")
            except Exception:  # the spec's limit, then
                found = ()
        for i, limit in enumerate(found):
            if isinstance(limit, int) and not isinstance(limit, bool):
                limits[i] = limit
        return limits

    # ------------------------------------------------------------------ RNG states

    def _capture(self, indices: Sequence[int]) -> dict[int, dict[str, Any] | None]:
        """The RNG states of sub-envs ``indices`` now (``None`` where unknown)."""
        if not indices:
            return {}
        if self._sync is not None:
            envs = self._sync_unwrapped
            return {i: capture_rng_state(envs[i]) for i in indices}
        if self._async is not None:
            try:
                generators = self._async.get_attr("np_random")
            except Exception:
                return dict.fromkeys(indices)
            out: dict[int, dict[str, Any] | None] = {}
            for i in indices:
                try:
                    state = generators[i].bit_generator.state
                    out[i] = state if isinstance(state, dict) else None
                except Exception:
                    out[i] = None
            return out
        return dict.fromkeys(indices)

    def _rng_from_info(self, info: Any) -> dict[str, Any] | None:
        """The state :class:`ResetRngInfo` put in a reset info (then it is always used)."""
        if not isinstance(info, Mapping):
            return None
        text = info.get(fmt.INFO_RNG_STATE)
        if not isinstance(text, str):
            return None
        try:
            state = json.loads(text)
        except ValueError:
            return None
        if not isinstance(state, dict):
            return None
        self._rng_in_info = True  # the sub-envs report it: no need to read it from outside
        return state

    def _begin(
        self,
        i: int,
        seed: int | None,
        options: Any,
        rng_state: dict[str, Any] | None,
        obs: Any,
        info: Any,
        start_ns: int,
        why_no_rng: str | None = None,
        noted: str | None = None,
    ) -> None:
        """Begin sub-env ``i``'s next episode and record its reset row (noted ``noted``)."""
        stream = self._streams[i]
        notes: list[str] = [] if noted is None else [noted]
        if seed is None and rng_state is None:
            notes.append(
                note("rng_state_unavailable", why_no_rng or self._no_rng_note or "no np_random")
            )
        episode = stream.begin(seed, options, rng_state, notes, start_ns=start_ns)
        stream.record_reset(episode, obs, info, notes)

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the vector env (or the sub-envs of ``options["reset_mask"]``) and record it."""
        file = self._file
        file.check_open()
        n = self._n
        indices, recorded_options = _reset_targets(options, n)
        seeds = self._seeds(seed)
        rejected = _rejected(seed, options, n)
        unseeded = [i for i in indices if seeds[i] is None]
        states = {} if self._rng_in_info else self._capture(unseeded)
        start = file.clock()
        self._idle = None
        try:
            obs, infos = self.env.reset(seed=seed, options=options)  # type: ignore[arg-type]
        except Exception as exc:
            if rejected:  # refused before any sub-env was reset: no episode changed
                raise
            try:
                for i in indices:
                    self._begin_failed(i, seeds[i], recorded_options, states.get(i), exc)
                file.flush()
            except Exception as trouble:  # the loop sees the env's error, not the recorder's
                file.trouble(trouble)
            raise
        try:
            rows = list(iterate(self._obs_space, obs))
            sub_infos, unmasked = _env_infos(infos, n)
            for i in indices:
                info = sub_infos[i]
                rng = states.get(i)
                if seeds[i] is None:
                    rng = self._rng_from_info(info) or rng
                self._streams[i].block.pending = self._pending_rows(i)
                self._streams[i].end_open()
                self._begin(
                    i, seeds[i], recorded_options, rng, rows[i], info, start, None, unmasked
                )
            if self._resetting:
                done = set(indices)
                self._resetting = [i for i in self._resetting if i not in done]
            for i in indices:
                self._pending_rng.pop(i, None)
            if file.due():
                file.flush()
        except Exception as exc:  # never break the training loop over recording trouble
            file.trouble(exc)
        return obs, infos

    def _seeds(self, seed: Any) -> list[Any]:
        """The seed each sub-env's reset gets from ``reset(seed=seed)`` (as Gymnasium's do)."""
        n = self._n
        if seed is None or not self._sub_envs:
            return [None] * n
        if isinstance(seed, (int, np.integer)):
            return [int(seed) + i for i in range(n)]
        try:
            seeds = list(seed)
        except TypeError:  # not a seed (the env refuses it)
            return [None] * n
        return (seeds + [None] * n)[:n]

    def _begin_failed(
        self, i: int, seed: Any, options: Any, rng: dict[str, Any] | None, exc: Exception
    ) -> None:
        stream = self._streams[i]
        stream.block.pending = self._pending_rows(i)
        stream.end_open()
        notes: list[str] = []
        stream.begin(seed, options, rng, notes)
        stream.end_error(exc, "reset")

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        """Step every sub-env and record each sub-env's step; the results are returned untouched."""
        if self._closed:
            self._file.check_open()
        try:
            result = self.env.step(actions)
        except Exception as exc:
            self._on_step_error(exc)
            raise
        try:
            self._record_step(actions, result)
        except Exception as exc:  # never break the training loop over recording trouble
            self._idle = None
            self._file.trouble(exc)
        return result

    def _record_step(self, actions: Any, result: tuple[Any, ...]) -> None:
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
            term, term_given = _flags(terminated, n)
            trunc, trunc_given = _flags(truncated, n)
        ended = (term | trunc).tolist()
        ends = [i for i, e in enumerate(ended) if e] if True in ended else []
        mode = self._mode
        resetting = self._resetting  # NEXT_STEP: the sub-envs this step only resets
        idle = self._idle
        if idle is None:
            idle = self._idle = {
                i for i, s in enumerate(self._streams) if s.episode is None or s.episode.ended
            }
        if (
            self._batchable
            and (
                (type(infos) is dict and not infos)
                or (type(infos) is list and infos == self._no_infos)
            )
            and (mode is not AutoresetMode.SAME_STEP or not ends)
            and (not idle or idle.issubset(resetting))  # else: notes (before reset, after end)
            and term_given is None  # else: flags to note (not bool)
            and trunc_given is None
            and type(rewards) is np.ndarray
            and rewards.shape == (n,)
            and rewards.dtype.kind in "biuf"
            and _fits(obs, self._obs_shape, self._obs_dtype)
            and _fits(actions, self._act_shape, self._act_dtype)
        ):
            self._batch_step(obs, actions, rewards, term, trunc, ends, resetting)
        else:
            self._drain()
            self._idle = None
            self._record_step_slow(
                list(iterate(self._obs_space, obs)),
                list(iterate(self._act_space, actions)),
                _per_env(rewards, n),
                term.tolist() if term_given is None else term_given,
                trunc.tolist() if trunc_given is None else trunc_given,
                ended,
                infos,
            )
        if mode is AutoresetMode.NEXT_STEP:
            self._resetting = ends
            if ends and not self._rng_in_info:
                self._pending_rng = self._capture(ends)

    def _batch_step(
        self,
        obs: np.ndarray[Any, Any],
        actions: np.ndarray[Any, Any],
        rewards: Any,
        term: np.ndarray[Any, np.dtype[np.bool_]],
        trunc: np.ndarray[Any, np.dtype[np.bool_]],
        ends: list[int],
        resetting: list[int],
    ) -> None:
        """A step without info: keep the whole batch; hand rows to the streams in bulk later.

        Only episode boundaries are handled per sub-env: the NEXT_STEP autoresets (reset rows)
        and the endings (at the rows they will have: each block's ``pending`` counts the rows
        batched for it).
        """
        file = self._file
        now = file.clock()
        rew = np.array(rewards, dtype=np.float64)  # every conversion before any append
        self._p_obs.append(obs.copy())
        self._p_act.append(actions.copy())
        self._p_rew.append(rew)
        self._p_time.append(now)
        self._p_mask.append(resetting)
        self._p_len += 1
        if resetting or ends:
            streams, skipped, pending = self._streams, self._p_skip, self._p_len
            for i in resetting:
                # NEXT_STEP autoreset: the reset row of the sub-env's next episode, not a step.
                skipped[i] += 1
                streams[i].block.pending = pending - skipped[i]
                rng = self._pending_rng.pop(i, None)
                streams[i].end_open()
                self._begin(i, None, None, rng, obs[i], _EMPTY, now)
            idle = self._idle
            if idle:
                idle.difference_update(resetting)
            for i in ends:
                if resetting and i in resetting:
                    continue  # a reset step has no flags (Gymnasium clears them)
                block = streams[i].block
                block.pending = pending - skipped[i]
                streams[i].end_step(block.rows() - 1, bool(term[i]), bool(trunc[i]), _EMPTY)
                if idle is not None:
                    idle.add(i)
        self._since_flush += 1
        if self._since_flush >= self._block_steps or now >= file.flush_at:
            file.auto_flush()
        elif self._p_len >= _BATCH_STEPS:
            self._drain()

    def _pending_rows(self, i: int) -> int:
        """Rows batched for sub-env ``i`` and not yet handed to its stream."""
        return self._p_len - self._p_skip[i]

    def _drain(self) -> None:
        """Hand the batched rows over to each sub-env's stream (before any other row)."""
        if not self._p_obs:
            return
        obs = np.stack(self._p_obs)
        act = np.stack(self._p_act)
        rew = np.stack(self._p_rew)
        times = np.array(self._p_time, dtype=np.int64)
        masks = self._p_mask
        self._p_obs, self._p_act, self._p_rew, self._p_time, self._p_mask = [], [], [], [], []
        self._p_len = 0
        if not any(self._p_skip):
            for i, stream in enumerate(self._streams):
                stream.extend(obs[:, i], act[:, i], rew[:, i], times)
            return
        self._p_skip = [0] * self._n
        stepped = np.ones((len(masks), self._n), dtype=np.bool_)
        for t, skipped in enumerate(masks):
            if skipped:
                stepped[t, skipped] = False
        for i, stream in enumerate(self._streams):
            rows = stepped[:, i]
            stream.extend(obs[rows, i], act[rows, i], rew[rows, i], times[rows])

    def _on_flush(self) -> None:
        self._drain()
        self._since_flush = 0

    def _record_step_slow(
        self,
        obs_rows: list[Any],
        act_rows: list[Any],
        reward_list: list[Any],
        term_list: list[Any],
        trunc_list: list[Any],
        ended: list[bool],
        infos: Any,
    ) -> None:
        """A step with info, autoresets or (SAME_STEP) ended episodes: sub-env by sub-env.

        The flags are as given where one is to be noted (see :func:`_flags`), for the stream to
        note as it would a single env's; ``ended`` is their reading.
        """
        streams = self._streams
        mode = self._mode
        resetting = set(self._resetting)
        now = self._file.clock()
        n = self._n
        sub_infos, unmasked = _env_infos(infos, n)
        for i in range(n):
            info = sub_infos[i]
            if i in resetting:
                # NEXT_STEP autoreset: the reset row of the sub-env's next episode, not a step.
                rng = self._rng_from_info(info)
                if rng is None:
                    rng = self._pending_rng.pop(i, None)
                self._streams[i].end_open()
                self._begin(i, None, None, rng, obs_rows[i], info, now, None, unmasked)
                continue
            if unmasked is not None:
                streams[i].note_next_row([unmasked])
            if mode is AutoresetMode.SAME_STEP and ended[i]:
                if isinstance(info, Mapping):
                    final = info.get("final_info")
                    step_info = final if isinstance(final, Mapping) else _EMPTY
                    final_obs = info["final_obs"] if "final_obs" in info else obs_rows[i]
                    reset_info: Any = {
                        k: v for k, v in info.items() if k not in ("final_info", "final_obs")
                    }
                else:  # neither the vector dict form nor a list of dicts (noted)
                    step_info = reset_info = info
                    final_obs = obs_rows[i]
                streams[i].step(
                    act_rows[i],
                    (final_obs, reward_list[i], term_list[i], trunc_list[i], step_info),
                )
                rng = self._rng_from_info(reset_info)
                why = (
                    None
                    if rng is not None
                    else "SAME_STEP autoreset ran inside step(): the sub-env's RNG state before it "
                    "cannot be read from outside; wrap the sub-envs in episode_audit.ResetRngInfo "
                    "(gym.make_vec(..., wrappers=[ResetRngInfo])) to make such episodes replayable"
                )
                self._begin(i, None, None, rng, obs_rows[i], reset_info, now, why, unmasked)
                continue
            streams[i].step(
                act_rows[i], (obs_rows[i], reward_list[i], term_list[i], trunc_list[i], info)
            )

    def _on_step_error(self, exc: Exception) -> None:
        """The vector step raised ``exc``: end the open episodes as ``error`` (``step``).

        An autoreset that raised is first recorded where it belongs (:meth:`_failed_autoresets`).
        """
        self._idle = None
        try:
            self._drain()
            self._failed_autoresets(exc)
        except Exception as trouble:  # the loop sees the env's error, not the recorder's
            self._file.trouble(trouble)
        self._file.end_with_error(self._streams, exc, "step")

    def _failed_autoresets(self, exc: Exception) -> None:
        """Record the autoresets of the step that raised ``exc`` that failed, as failed resets.

        Each becomes an episode of its sub-env ended ``error`` during ``reset`` (as a single env's
        ``reset()`` that raised), with the RNG state the reset started from.

        - ``NEXT_STEP``: the step was to reset the sub-envs whose episodes ended on the step
          before (those episodes have their endings already). Which one raised is known for a
          ``SyncVectorEnv`` (by :class:`ResetRngInfo`, else the sub-env whose ``reset`` is in
          the exception's traceback); otherwise every one of them gets the error. The sub-envs
          not recorded so stay due for their autoreset (a ``SyncVectorEnv`` retries it on its
          next step), from their RNG states read again.
        - ``SAME_STEP``: the reset ran after the step that ended the episode, and that step's
          result never left the vector env; :class:`ResetRngInfo` (installed on a
          ``SyncVectorEnv``'s sub-envs by default) kept it: the step is recorded (the episode's
          true ending), then the failed reset. Without it the episode ends ``error`` like the
          others.
        """
        mode = self._mode
        if mode is AutoresetMode.DISABLED:
            return
        failed = self._wrapper_failures(exc)
        if mode is AutoresetMode.SAME_STEP:
            for i, (state, last) in failed.items():
                if last is not None:
                    self._streams[i].step(*last)
                    self._begin_failed(i, None, None, state, exc)
            return
        resetting = self._resetting
        if not resetting:
            return
        if not failed:
            raiser = self._sync_raiser(exc)
            if raiser is None:  # not known: every autoreset of the step may have raised
                failed = dict.fromkeys(resetting, (None, None))
            elif raiser[1] == "reset":
                failed = {raiser[0]: (None, None)}
        for i in resetting:
            if i in failed:
                state = failed[i][0]
                if state is None:
                    state = self._pending_rng.get(i)
                self._begin_failed(i, None, None, state, exc)
        if self._sync is not None and not self._rng_in_info:
            self._pending_rng = self._capture(resetting)  # a failed step may have drawn

    def _wrapper_failures(self, exc: Exception) -> dict[int, tuple[Any, Any]]:
        """The sub-envs whose :class:`ResetRngInfo` saw its reset raise ``exc`` (Sync only).

        ``{i: (RNG state before the reset, (action, result) of the step before it)}``.
        """
        out: dict[int, tuple[Any, Any]] = {}
        if self._sync is None:
            return out
        for i, sub in enumerate(self._sync.envs):
            wrapper = _rng_wrapper(sub)
            if wrapper is None:
                continue
            failed = wrapper._failed_reset
            if failed is not None and failed[0] is exc:
                out[i] = (failed[1], failed[2])
                wrapper._failed_reset = None
        return out

    def _sync_raiser(self, exc: Exception) -> tuple[int, str] | None:
        """The ``SyncVectorEnv`` sub-env whose ``reset`` or ``step`` raised ``exc``, if known.

        The sub-env's own method is in the exception's traceback (the vector env calls it).
        """
        if self._sync is None:
            return None
        envs = {id(env): i for i, env in enumerate(self._sync.envs)}
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

    def flush(self) -> None:
        """Write everything recorded so far to the file now."""
        self._file.check_open()
        self._file.flush()

    def close(self, **kwargs: Any) -> None:
        """Finish the evidence file (open episodes are recorded as ``incomplete``) and close.

        Safe to call more than once. The vector env is closed even if finishing fails.
        """
        if getattr(self, "_closed", True):
            return
        self._closed = True
        try:
            self._file.close()
        finally:
            self.env.close(**kwargs)

    def __enter__(self) -> RecordVectorEvidence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            import warnings

            warnings.warn(
                f"episode-audit: RecordVectorEvidence for {getattr(self, 'path', '?')} was not "
                "closed; call close() or use it as a context manager",
                ResourceWarning,
                stacklevel=2,
            )


def _reset_targets(options: Any, n: int) -> tuple[list[int], Any]:
    """The sub-envs a ``reset(options=options)`` resets, and the options their episodes record.

    Only a mapping's ``reset_mask`` (a mask of ``n`` values) selects sub-envs; options that are
    not a mapping are passed to every sub-env and recorded as they are.
    """
    if not isinstance(options, Mapping):
        return list(range(n)), options
    indices: Sequence[int] | np.ndarray[Any, Any] = range(n)
    if "reset_mask" in options:
        try:
            mask = np.asarray(options["reset_mask"]).astype(bool).reshape(-1)
        except Exception:  # not a mask (the env refuses it)
            mask = None
        if mask is not None and mask.size == n:
            indices = np.flatnonzero(mask)
    recorded = {k: v for k, v in options.items() if k != "reset_mask"} or None
    return [int(i) for i in indices], recorded


def _rng_wrapper(env: Any) -> ResetRngInfo | None:
    """The outermost :class:`ResetRngInfo` around ``env``, if any."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, ResetRngInfo):
            return env
        env = env.env
    return None
