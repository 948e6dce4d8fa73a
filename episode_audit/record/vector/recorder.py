"""The vector recorder: :class:`RecordVectorEvidence`, one episode stream per sub-env.

A thin ``gymnasium.vector.VectorWrapper``: it sets the recording up (one
:class:`~episode_audit.record.stream.Stream` per sub-env of one evidence file), records
``reset()`` itself, and hands each step to :class:`~.steps.VectorSteps` and the autoreset
strategy of the env's mode (:mod:`.modes`). See ``docs/recording.md``, "Vector envs".
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv, VectorEnv
from gymnasium.vector.utils import iterate
from gymnasium.wrappers import TimeLimit
from typing_extensions import Unpack

from ...errors import ConfigurationError
from ...format.spaces import codec_for, describe_space
from ...format.wrappers import (
    LAYOUT_REWARD_WRAPPERS,
    LAYOUT_STATE_SNAPSHOTS,
    LAYOUT_VECTOR_WRAPPERS,
    REWARD_CHANGING,
)
from ..file import EvidenceFile, FileRecorder
from ..gym import (
    info_entry_point,
    reward_wrappers,
    warn_unrestorable,
    wrapper_chain,
)
from ..settings import RecorderOptions, RecorderSettings, check_options, run_info
from ..time_limits import counted_limits, limited_spec, time_limits, unread_limits
from .infos import env_infos
from .modes import autoreset_mode, autoreset_strategy
from .resets import recorded_per_env, refused, reset_targets, seeds_of, shared_changed
from .rng import (
    SPEC_IF_SENDABLE,
    LocalSubEnvs,
    ResetRngInfo,
    SubEnvRng,
    has_own_keys,
    without_installed,
)
from .steps import VectorSteps
from .workers import rng_unaskable

__all__ = ["RecordVectorEvidence", "sub_reward_wrappers", "sub_wrappers", "vector_layout"]


class RecordVectorEvidence(FileRecorder, gym.vector.VectorWrapper):
    """Record every sub-env episode of a vector env to one MCAP evidence file.

    Each sub-env is a stream of its own (its index is the episodes' ``env_index``); an episode
    stores its reset seed or the sub-env's RNG state before the reset, so every sub-env episode,
    those an autoreset started included, can be replayed on its own by rebuilding one sub-env
    (``docs/format.md``, "Vector files", says how each autoreset mode is recorded and why).

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
        install_rng_info: For a ``SyncVectorEnv`` in ``SAME_STEP`` mode, or whose sub-envs have
            state to snapshot (e.g. ``NormalizeObservation``), wrap its sub-envs in
            :class:`ResetRngInfo` in place (default), so autoreset episodes are replayable. An
            ``AsyncVectorEnv``'s sub-envs: ``gym.make_vec(..., wrappers=[..., ResetRngInfo])``.
        **options: The recorder options, as for :class:`~episode_audit.RecordEvidence` (see
            :class:`~episode_audit.record.settings.RecorderSettings`; ``block_steps`` counts
            rows per sub-env).
    """

    def __init__(
        self,
        env: VectorEnv[Any, Any, Any],
        path: str | os.PathLike[str],
        *,
        install_rng_info: bool = True,
        **options: Unpack[RecorderOptions],
    ) -> None:
        check_options(options, "RecordVectorEvidence.__init__()")
        _check_vector_env(env)
        super().__init__(env)
        settings = RecorderSettings(**options)
        base = env.unwrapped
        mode = autoreset_mode(env)
        sync = base if isinstance(base, SyncVectorEnv) else None
        async_env = base if isinstance(base, AsyncVectorEnv) else None
        _check_sub_envs(sync)
        self._sub_envs = sync is not None or async_env is not None
        n = int(env.num_envs)
        self._n = n
        sub_spec, rng_unasked = _sub_spec(env, sync, async_env)
        notes: list[str] = []
        no_rng_note: str | None = None
        if not self._sub_envs:
            no_rng_note = (
                f"{type(base).__name__} has no sub-envs (a vector_entry_point env): its episodes "
                "cannot be replayed on their own"
            )
            notes.append(no_rng_note)
        self._rng = SubEnvRng(sync, async_env, rng_unasked)
        snapshots = self._rng.snapshots(installing=install_rng_info)
        same_step = mode is AutoresetMode.SAME_STEP
        if (same_step or snapshots) and sync is not None and install_rng_info:
            self._rng.install_wrappers()
        self._installed = any(self._rng.installed)
        """Whether the recorder put a :class:`ResetRngInfo` on a sub-env (whose info keys the
        loop does not get: :func:`~.rng.without_installed`)."""
        obs_space, act_space = env.single_observation_space, env.single_action_space
        layout = _layout(env, mode, sync, sub_spec, snapshots, no_rng_note)
        layout.update(self._rng.unsaved_state(sub_spec, snapshots))
        self.run_info = run_info(
            settings=settings,
            spec=sub_spec,
            observation_space=describe_space(obs_space),
            action_space=describe_space(act_space),
            layout=layout,
            notes=notes,
            info_of=info_entry_point(sync.envs[0] if sync is not None and sync.envs else env),
        )
        warn_unrestorable(type(self).__name__, sub_wrappers(sync, sub_spec), layout)
        self._file = EvidenceFile(path, self.run_info, settings, owner=self)
        self.path = self._file.path
        obs_codec = codec_for(obs_space, digest_min_bytes=settings.digest_min_bytes)
        codecs = obs_codec, codec_for(act_space)
        watched = _watched_limits(sync, mode, n)
        self._streams = [
            self._file.add_stream(
                *codecs,
                env_index=i,
                max_episode_steps=limit,
                time_limits=watched[i],
                state=snapshots,
            )
            for i, limit in enumerate(_max_steps(sub_spec, n, sync, async_env, base))
        ]
        self._file.start()
        self._autoreset = autoreset_strategy(
            mode, self._streams, self._rng, self._file.clock, no_rng_note
        )
        self._steps = VectorSteps(
            self._file,
            self._streams,
            self._autoreset,
            env.observation_space,
            env.action_space,
            codecs,
            (obs_space, act_space),
            settings.track_info,
        )
        self._record_step = self._steps.record
        self._obs_space = env.observation_space
        self._opened()

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the vector env (or the sub-envs of ``options["reset_mask"]``) and record it."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            self._enter()
            return self._reset(seed, options)
        finally:
            self._busy = False

    def _reset(
        self, seed: int | list[int | None] | None, options: dict[str, Any] | None
    ) -> tuple[Any, dict[str, Any]]:
        file = self._file
        n = self._n
        indices, passed = reset_targets(options, n)
        per_env = recorded_per_env([passed] * n)  # (before the reset, which may change them)
        seeds = seeds_of(seed, n, self._sub_envs)
        rejected = refused(seed, options, n)
        unseeded = [i for i in indices if seeds[i] is None]
        states = {} if self._rng.in_info else self._rng.capture(unseeded)
        start = file.clock()
        try:
            obs, infos = self.env.reset(seed=seed, options=options)  # type: ignore[arg-type]
        except Exception as exc:
            if not rejected:  # refused before any sub-env was reset: no episode changed
                self._steps.reset_failed(indices, seeds, per_env, states, exc)
            raise
        try:
            per_env = shared_changed(per_env, [reset_targets(options, n)[1]] * n, indices)
            rows = list(iterate(self._obs_space, obs))
            self._steps.record_reset(
                indices, seeds, per_env, states, self._rng, (rows, *env_infos(infos, n)), start
            )
        except Exception as exc:  # never break the training loop over recording trouble
            file.trouble(exc)
        if self._installed and has_own_keys(infos):
            infos = without_installed(infos, self._rng.installed)
        return obs, infos

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        """Step every sub-env and record each sub-env's step; the results are returned untouched."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            if self._gated:
                self._enter()
            try:
                result = self.env.step(actions)
            except Exception as exc:
                self._steps.step_failed(exc)
                raise
            try:
                self._record_step(actions, result)
            except Exception as exc:  # never break the training loop over recording trouble
                self._steps.idle = None
                self._file.trouble(exc)
            if self._installed and has_own_keys(result[4]):  # (an autoreset's: hidden)
                return (*result[:4], without_installed(result[4], self._rng.installed))
            return result
        finally:
            self._busy = False

    def close(self, **kwargs: Any) -> None:
        """Finish the evidence file (open episodes are recorded as ``incomplete``) and close.

        Safe to call more than once. The vector env is closed even if finishing fails.
        """
        self._close_file(lambda: self.env.close(**kwargs))

    def __enter__(self) -> RecordVectorEvidence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _layout(
    env: VectorEnv[Any, Any, Any],
    mode: AutoresetMode,
    sync: SyncVectorEnv | None,
    sub_spec: Any,
    snapshots: bool,
    no_rng_note: str | None,
) -> dict[str, Any]:
    """The run's vector layout: autoreset mode, sub-envs, snapshots, the wrappers around them."""
    base = env.unwrapped
    has_sub_envs = no_rng_note is None  # (the note says the env has none)
    layout = vector_layout(
        int(env.num_envs), mode, type(base).__name__, has_sub_envs, no_rng_note, snapshots=snapshots
    )
    vector_wrappers = _vector_wrappers(env)
    if vector_wrappers:
        layout[LAYOUT_VECTOR_WRAPPERS] = vector_wrappers
    layout.update(_unread_limits(base, mode, sync))
    changing = sub_reward_wrappers(sync, sub_spec) + reward_wrappers(env)
    if changing:
        layout[LAYOUT_REWARD_WRAPPERS] = changing
    return layout


def _unread_limits(base: Any, mode: AutoresetMode, sync: SyncVectorEnv | None) -> dict[str, str]:
    """The layout entries saying why the streams cannot read every sub-env's ``TimeLimit``.

    An ``AsyncVectorEnv``'s workers answer for the outermost only; a ``SyncVectorEnv`` in
    ``SAME_STEP`` mode has zeroed the counts when the streams count the steps themselves, which
    misses one under a frame skip (:func:`~..time_limits.unread_limits`).
    """
    if isinstance(base, AsyncVectorEnv):
        envs = None
    elif sync is not None and mode is AutoresetMode.SAME_STEP:
        envs = sync.envs
    else:
        return {}
    name = type(base).__name__
    return unread_limits(name, envs, "the SameStep autoreset", "record in NextStep mode")


def _check_vector_env(env: Any) -> None:
    """Refuse what is not a ``gymnasium.vector.VectorEnv``, naming the recorder that takes it."""
    if isinstance(env, VectorEnv):
        return
    kind = type(env)
    sb3 = any(c.__module__.startswith("stable_baselines3.") for c in kind.__mro__)
    hint = (
        "a Stable-Baselines3 VecEnv: record it with episode_audit.RecordVecEnvEvidence(venv, path)"
        if sb3
        else "record a single env with RecordEvidence"
    )
    raise ConfigurationError(
        f"RecordVectorEvidence records a gymnasium.vector.VectorEnv, actually: "
        f"{kind.__module__}.{kind.__qualname__}, {hint}"
    )


def _check_sub_envs(sync: SyncVectorEnv | None) -> None:
    """Refuse a ``SyncVectorEnv`` whose sub-envs are not ``gymnasium.Env``s.

    They lack what the recorder reads of each (``unwrapped``, a wrapper chain).
    """
    for i, sub in enumerate(() if sync is None else sync.envs):
        if not isinstance(sub, gym.Env):
            kind = type(sub)
            raise ConfigurationError(
                f"RecordVectorEvidence: sub-env {i} is not a gymnasium.Env, actually: "
                f"{kind.__module__}.{kind.__qualname__}; make it subclass gymnasium.Env (or "
                "record each sub-env with RecordEvidence inside its env function)"
            )


def vector_layout(
    n: int,
    mode: AutoresetMode,
    vector_class: str,
    sub_envs: bool,
    replay_note: str | None,
    *,
    snapshots: bool = False,
) -> dict[str, Any]:
    """The layout metadata of a vector file (``docs/format.md``, "Multi-stream files").

    ``snapshots``: the sub-envs' reset rows hold state snapshots.
    """
    layout: dict[str, Any] = {
        "kind": "vector",
        "num_envs": n,
        "agents": [],
        "autoreset_mode": mode.value,
        "vector_class": vector_class,
        "sub_envs": sub_envs,
    }
    if replay_note:
        layout["replay_note"] = replay_note
    if snapshots:
        layout[LAYOUT_STATE_SNAPSHOTS] = True
    return layout


def _sub_spec(
    env: VectorEnv[Any, Any, Any], sync: SyncVectorEnv | None, async_env: AsyncVectorEnv | None
) -> tuple[Any, str | None]:
    """The spec of one sub-env (what replay rebuilds), or ``None``; and a why.

    The why: for an ``AsyncVectorEnv``, why its workers may not be asked for ``np_random``
    (:func:`_worker_spec`); else ``None``.
    """
    try:
        if sync is not None:
            return limited_spec(sync.envs[0].spec, sync.envs[0]), None
        if async_env is not None:
            return _worker_spec(async_env)
    except Exception as exc:
        return None, f"its sub-env could not be looked at here ({type(exc).__name__})"
    spec = env.spec
    if spec is None:
        return None, None
    kwargs = {
        k: v
        for k, v in spec.kwargs.items()
        if k not in ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")
    }
    limit = _own_limit(env.unwrapped, spec)
    spec = dataclasses.replace(spec, kwargs=kwargs)
    return (spec if limit is None else dataclasses.replace(spec, max_episode_steps=limit)), None


def _worker_spec(async_env: AsyncVectorEnv) -> tuple[Any, str | None]:
    """Sub-env 0's spec, asked of a worker only when it can send it; and a why.

    The why: why the workers may not be asked for ``np_random`` (``None``: they may;
    :func:`~.workers.rng_unaskable`).

    A worker that fails in answering (its spec does not pickle: a lambda among the env's
    ``make()`` kwargs or a wrapper's, ``TransformObservation(env, lambda o: ...)``; or reading
    it raises) ends, which breaks the vector env. So the workers are asked first what they
    answer safely (``has_wrapper_attr``, a bool): :class:`~.rng.ResetRngInfo` outermost gives
    the spec when it pickles (and the RNG states, safely). Otherwise the spec is read off a
    sub-env built here by the first env function, whose classes say whether ``np_random`` may
    be asked, then closed (``AsyncVectorEnv``'s constructor builds one here too, for its
    spaces).
    """
    call = async_env.call
    if all(call("has_wrapper_attr", SPEC_IF_SENDABLE)) and call("class_name")[0] == (
        ResetRngInfo.__name__
    ):
        sendable, spec = call(SPEC_IF_SENDABLE)[0]
        if sendable:
            return spec, None
    return _built_spec(async_env)


def _built_spec(async_env: AsyncVectorEnv) -> tuple[Any, str | None]:
    """The spec of a sub-env built here by the first env function, then closed; and a why.

    The why: why the workers may not be asked for ``np_random``, read off that sub-env's
    classes (:func:`~.workers.rng_unaskable`).
    """
    env_fns = getattr(async_env, "env_fns", None)
    if not env_fns:
        return None, rng_unaskable(None)
    env = env_fns[0]()
    try:
        return env.spec, rng_unaskable(env)
    finally:
        with contextlib.suppress(Exception):
            env.close()


def _own_limit(base: Any, spec: Any) -> int | None:
    """The step limit a vector env without sub-envs (a ``vector_entry_point`` env) counts itself.

    Gymnasium's (``CartPoleVectorEnv``) keep it as ``max_episode_steps`` and truncate a row when
    its step count reaches it; ``gym.make_vec`` passes it the ``max_episode_steps`` asked for,
    else the registered one, as a constructor kwarg (which its spec's ``kwargs`` keep; the
    spec's own ``max_episode_steps`` stays the registered one, which no ``TimeLimit`` applies).
    The attribute, else that kwarg; ``None`` when neither is a positive int.

    >>> import gymnasium as gym
    >>> envs = gym.make_vec("CartPole-v1", 2, vectorization_mode="vector_entry_point",
    ...                     max_episode_steps=12)
    >>> envs.spec.max_episode_steps, _own_limit(envs.unwrapped, envs.spec)
    (500, 12)
    """
    kwargs = getattr(spec, "kwargs", None)
    try:
        own = getattr(base, "max_episode_steps", None)
    except Exception:  # the env's own attribute: not a limit
        own = None
    for limit in (own, kwargs.get("max_episode_steps") if isinstance(kwargs, dict) else None):
        if type(limit) is int and limit > 0:
            return limit
    return None


def _max_steps(
    sub_spec: Any,
    n: int,
    sync: SyncVectorEnv | None,
    async_env: AsyncVectorEnv | None,
    base: Any,
) -> list[int | None]:
    """Each sub-env's step limit in its own steps, for its stream to count.

    The stream counts it where it does not read the ``TimeLimit``s themselves
    (:func:`_watched_limits`). A ``SyncVectorEnv``'s sub-envs are searched for their
    ``TimeLimit``s directly (:func:`~..time_limits.counted_limits`: the smallest of those
    over no multi-step wrapper, none when each is under one, the spec's when there is none).
    A vector env without sub-envs (``base``, a ``vector_entry_point`` env) counts its own
    (:func:`_own_limit`). An ``AsyncVectorEnv``'s workers are asked for
    ``_max_episode_steps`` (the outermost ``TimeLimit``'s: a worker's chain cannot be walked),
    but only when every one says it has it (``has_wrapper_attr``, which every
    ``gymnasium.Env`` has): a worker asked for an attribute its env lacks raises, and that
    ends the worker. Otherwise the spec's.
    """
    limits: list[int | None] = [getattr(sub_spec, "max_episode_steps", None)] * n
    found: Sequence[Any] = ()
    if sync is not None:
        return counted_limits(sync.envs, limits[0])
    if async_env is None:
        found = [_own_limit(base, sub_spec)] * n
    else:
        try:
            if all(async_env.call("has_wrapper_attr", "_max_episode_steps")):
                found = async_env.get_attr("_max_episode_steps")
        except Exception:  # the spec's limit, then
            found = ()
    for i, limit in enumerate(found):
        if isinstance(limit, int) and not isinstance(limit, bool):
            limits[i] = limit
    return limits


def _watched_limits(
    sync: SyncVectorEnv | None, mode: AutoresetMode, n: int
) -> list[tuple[TimeLimit[Any, Any], ...]]:
    """Each sub-env's ``TimeLimit``s, for its stream to read at an episode's end; or none.

    A ``SyncVectorEnv``'s, unless it resets a sub-env inside the step that ended its episode
    (``SAME_STEP``: the counts are zeroed by the time the ending is recorded). Read like the
    single-env recorder reads them, they say a limit was reached in whatever steps it counts
    (one under a frame-skipping wrapper counts the env's own).
    """
    if sync is None or mode is AutoresetMode.SAME_STEP:
        return [()] * n
    return [time_limits(sub) for sub in sync.envs]


def _vector_wrappers(env: Any) -> list[str]:
    """The entry points of the vector wrappers the recorder wraps, innermost first."""
    chain: list[str] = []
    try:
        while isinstance(env, gym.vector.VectorWrapper) and len(chain) < 64:
            chain.append(f"{type(env).__module__}:{type(env).__qualname__}")
            env = env.env
    except Exception:  # an env's own attribute access: the chain walked so far
        pass
    return chain[::-1]


def sub_wrappers(local: LocalSubEnvs | None, sub_spec: Any) -> list[str]:
    """The entry points of the first sub-env's wrappers: walked, else as its spec names them.

    ``local``: a vector env whose sub-envs are in this process (``SyncVectorEnv``, SB3's
    ``DummyVecEnv``); otherwise the spec (``additional_wrappers``) is all there is.
    """
    if local is not None and local.envs:
        return wrapper_chain(local.envs[0])
    wrappers = getattr(sub_spec, "additional_wrappers", None) or ()
    return [str(getattr(w, "entry_point", "")) for w in wrappers]


def sub_reward_wrappers(local: LocalSubEnvs | None, sub_spec: Any) -> list[str]:
    """The first sub-env's wrappers that change its reward: walked, else as its spec names them.

    ``local``: as for :func:`sub_wrappers`; otherwise those of the spec's
    ``additional_wrappers`` that :data:`~episode_audit.format.wrappers.REWARD_CHANGING` names.
    """
    if local is not None and local.envs:
        return reward_wrappers(local.envs[0])
    wrappers = sub_wrappers(None, sub_spec)
    return [w for w in wrappers if w.rpartition(":")[2] in REWARD_CHANGING]
