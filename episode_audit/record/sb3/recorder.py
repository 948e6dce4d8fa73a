"""The Stable-Baselines3 recorder: :class:`RecordVecEnvEvidence`, one stream per sub-env.

A ``VecEnvWrapper`` over any SB3 ``VecEnv``: the vector wing records (streams, batched steps,
the ``SAME_STEP`` autoreset strategy); this module reads SB3's step (:mod:`.results`) and its
``reset()`` arguments (``seed()`` / ``set_options()``, kept on the base VecEnv until the next
reset). See ``docs/recording.md``, "Stable-Baselines3".
"""

from __future__ import annotations

import os
import threading
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space, iterate
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv, VecEnvWrapper
from typing_extensions import Unpack

from ...errors import ConfigurationError, RecorderWarning
from ...format.records import RunInfo
from ...format.spaces import codec_for, describe_space
from ...format.wrappers import LAYOUT_REWARD_WRAPPERS
from ..file import EvidenceFile, FileRecorder
from ..gym import warn_unrestorable
from ..settings import RecorderOptions, RecorderSettings, check_options, run_info
from ..vector.infos import env_infos
from ..vector.recorder import vector_layout
from ..vector.resets import recorded_per_env, shared_changed
from ..vector.rng import SubEnvRng, without_installed
from ..vector.steps import VectorSteps
from .results import Sb3SameStep, StepReader
from .stack import VecStack

__all__ = ["RecordVecEnvEvidence"]

_NO_RNG_WORKER = (
    "{cls} resets a sub-env inside its worker, where its RNG state cannot be read from "
    "outside: wrap each sub-env in episode_audit.ResetRngInfo (make_vec_env(..., "
    "wrapper_class=ResetRngInfo) or in the env factory) to make such episodes replayable"
)


class RecordVecEnvEvidence(FileRecorder, VecEnvWrapper):
    """Record every sub-env episode of a Stable-Baselines3 ``VecEnv`` to one evidence file.

    Each sub-env is a stream of its own (its index is the episodes' ``env_index``), recorded as
    :class:`~episode_audit.RecordVectorEvidence` records a ``SAME_STEP`` vector env: SB3
    resets a sub-env inside the step that ends its episode, so that step's row takes
    ``infos[i]["terminal_observation"]``, ``truncated`` is ``infos[i]["TimeLimit.truncated"]``
    and the reset row is the returned observation with ``reset_infos[i]``. An explicit
    ``reset()`` records the seeds ``seed()`` set (sub-env ``i`` gets ``seed + i``) and the
    options ``set_options()`` set. A ``DummyVecEnv``'s sub-envs are wrapped in
    :class:`~episode_audit.ResetRngInfo` in place, so autoreset episodes replay on their own
    too (their RNG state, and the snapshot of state a seed does not set, read at every reset: a
    ``SubprocVecEnv``'s sub-envs need a ``ResetRngInfo`` of their own), and its reward buffer
    is widened to float64 (the recorder hands rewards on as float32, as before) so that the
    file holds each reward exactly. Wrap the ``DummyVecEnv`` /
    ``SubprocVecEnv`` itself, under ``VecNormalize`` and ``VecFrameStack``: over a wrapper that
    changes steps the file holds what that wrapper made (noted; not replayable).

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from stable_baselines3.common.vec_env import DummyVecEnv
        >>> from episode_audit import open_evidence
        >>> from episode_audit.record.sb3 import RecordVecEnvEvidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "sb3.mcap"
        >>> make = lambda: gym.make("CartPole-v1", max_episode_steps=3)
        >>> venv = RecordVecEnvEvidence(DummyVecEnv([make, make]), path)
        >>> _ = venv.seed(5)
        >>> _ = venv.reset()
        >>> for _ in range(3):
        ...     _ = venv.step(np.array([0, 1]))
        >>> venv.close()
        >>> ep = open_evidence(path).episodes().to_pylist()
        >>> [(e["env_index"], e["seed"], e["outcome"], e["length"]) for e in ep[:2]]
        [(0, 5, 'truncated', 3), (1, 6, 'truncated', 3)]

    Args:
        venv: The SB3 VecEnv to record (``DummyVecEnv``, ``SubprocVecEnv``, or a wrapper).
        path: The evidence file to create (never overwritten unless ``overwrite=True``).
        install_rng_info: Wrap a ``DummyVecEnv``'s sub-envs in ``ResetRngInfo`` (default): without
            it, autoreset episodes have neither RNG state nor state snapshots.
        **options: The recorder options, as for :class:`~episode_audit.RecordEvidence`.

    Raises:
        ConfigurationError: ``venv`` is not an SB3 ``VecEnv``, or an option is out of range.
    """

    _closed = True  # until the file is open (read by a half-built object's __del__ too)

    _entries = ("step", "reset", "step_async", "step_wait")  # (see FileRecorder)
    _async_thread: int | None = None  # the thread of the last step_async()

    def __init__(
        self,
        venv: VecEnv,
        path: str | os.PathLike[str],
        *,
        install_rng_info: bool = True,
        **options: Unpack[RecorderOptions],
    ) -> None:
        check_options(options, "RecordVecEnvEvidence.__init__()")
        if not isinstance(venv, VecEnv):
            raise ConfigurationError(
                f"RecordVecEnvEvidence records a Stable-Baselines3 VecEnv, actually: "
                f"{type(venv).__name__}; record a Gymnasium env with RecordEvidence and a "
                "gymnasium.vector env with RecordVectorEvidence"
            )
        settings = RecorderSettings(**options)
        VecEnvWrapper.__init__(self, venv)
        n = int(venv.num_envs)
        self._n = n
        stack = VecStack(venv)
        base = stack.base
        self._base = base
        self._local = stack.local
        remote = None if stack.local is not None else base
        self._rng = SubEnvRng(stack.local, remote)
        snapshots = self._rng.snapshots(installing=install_rng_info)
        if stack.local is not None and install_rng_info:
            self._rng.install_wrappers()
        self._float_rewards = self._widen_rewards(stack)
        spec = stack.sub_env_spec()
        obs_space, act_space = stack.observation_space(venv.observation_space), venv.action_space
        self.run_info = self._describe(stack, settings, spec, snapshots, obs_space)
        if stack.changing:  # (as RecordVectorEvidence warns of what it cannot replay)
            warnings.warn(
                f"episode-audit: {type(self).__name__}: {stack.replay_note()}",
                RecorderWarning,
                stacklevel=2,
            )
        warn_unrestorable(type(self).__name__, stack.sub_wrappers(spec), self.run_info.layout)
        self._file = EvidenceFile(path, self.run_info, settings, owner=self)
        self.path = self._file.path
        codecs = (
            codec_for(obs_space, digest_min_bytes=settings.digest_min_bytes),
            codec_for(act_space),
        )
        limits = stack.step_limits(n, spec)
        streams = [
            self._file.add_stream(*codecs, env_index=i, max_episode_steps=limit, state=snapshots)
            for i, limit in enumerate(limits)
        ]
        self._streams = streams
        self._file.start()
        self._autoreset = Sb3SameStep(streams, self._rng, self._file.clock, None)
        self._autoreset.limits = limits
        if isinstance(base, SubprocVecEnv) or stack.local is None:
            self._autoreset.no_rng_why = _NO_RNG_WORKER.format(cls=type(base).__name__)
        self._obs_batch = batch_space(obs_space, n)
        self._steps = VectorSteps(
            self._file,
            streams,
            self._autoreset,
            self._obs_batch,
            batch_space(act_space, n),
            codecs,
            (obs_space, act_space),
            settings.track_info,
        )
        installed = self._rng.installed if any(self._rng.installed) else None
        self._installed = installed
        """Per sub-env, whether the recorder put its ResetRngInfo there (``None``: on none):
        the VecEnv's ``reset_infos`` of those lose its keys once recorded."""
        self._reader = StepReader(n, lambda: base.reset_infos, installed)
        self._actions: Any = None
        self._opened()

    def _describe(
        self,
        stack: VecStack,
        settings: RecorderSettings,
        spec: Any,
        snapshots: bool,
        obs_space: gym.Space[Any],
    ) -> RunInfo:
        """The run's metadata: the sub-envs' spec, the spaces, the stack's layout and notes.

        ``snapshots``: the sub-envs' resets are snapshot (:class:`~..vector.rng.ResetRngInfo`);
        ``obs_space``: the space of the observations recorded (:meth:`VecStack.observation_space`).
        """
        notes = stack.notes()
        if self._float_rewards is None and stack.local is not None:
            notes.append(
                "DummyVecEnv keeps rewards as float32 and a wrapper sits between it and the "
                "recorder: rewards are recorded as float32"
            )
        layout = vector_layout(
            self._n,
            AutoresetMode.SAME_STEP,
            type(stack.base).__name__,
            not stack.changing,
            stack.replay_note() if stack.changing else None,
            snapshots=snapshots,
        )
        changing = stack.reward_wrappers(spec)
        if changing:
            layout[LAYOUT_REWARD_WRAPPERS] = changing
        layout.update(stack.unread_limits())
        layout.update(self._rng.unsaved_state(spec, snapshots))
        return run_info(
            settings=settings,
            spec=spec,
            observation_space=describe_space(obs_space),
            action_space=describe_space(self.venv.action_space),
            layout=layout,
            notes=notes,
            info_of=stack.info_of(),
        )

    def _widen_rewards(self, stack: VecStack) -> Any:
        """Widen a directly wrapped ``DummyVecEnv``'s float32 reward buffer to float64.

        Returns the dtype to hand rewards on in (``None``: nothing widened).
        """
        local = stack.local
        buf = getattr(local, "buf_rews", None)
        if (
            local is None
            or not stack.direct
            or type(buf) is not np.ndarray
            or buf.dtype == np.float64
        ):
            return None
        if buf.shape != (self._n,) or buf.dtype.kind != "f":
            return None
        local.buf_rews = buf.astype(np.float64)
        return buf.dtype

    # ------------------------------------------------------------------ VecEnv API

    def reset(self) -> Any:
        """Reset every sub-env (with the seeds and options set before) and record it."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            self._enter()
            return self._reset()
        finally:
            self._busy = False

    def _reset(self) -> Any:
        file = self._file
        n, base = self._n, self._base
        seeds = _per_env(getattr(base, "_seeds", None), n)
        passed = [o or None for o in _per_env(getattr(base, "_options", None), n)]
        options = recorded_per_env(passed)  # (before the reset, which may change them)
        indices = list(range(n))
        unseeded = [i for i in indices if seeds[i] is None]
        states = {} if self._rng.in_info else self._rng.capture(unseeded)
        start = file.clock()
        try:
            obs = self.venv.reset()
        except Exception as exc:
            self._steps.reset_failed(indices, seeds, options, states, exc)
            raise
        try:
            options = shared_changed(options, passed, indices)
            rows = list(iterate(self._obs_batch, obs))
            infos = list(_per_env(base.reset_infos, n))
            result = (rows, *env_infos(infos, n))
            self._steps.record_reset(indices, seeds, options, states, self._rng, result, start)
        except Exception as exc:  # never break the training loop over recording trouble
            file.trouble(exc)
        if self._installed is not None and type(base.reset_infos) is list:
            base.reset_infos[:] = without_installed(base.reset_infos, self._installed)
        return obs

    def step_async(self, actions: np.ndarray[Any, Any]) -> None:
        """Start a step of every sub-env (the actions are kept for the record)."""
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._async_thread = threading.get_ident()  # (whose _busy it is: _busy_here)
        self._busy = True  # until step_wait() returns (read by a flush() in another thread)
        try:
            if self._gated:  # closed, or a flush() / close() under way in another thread
                self._enter()
            self._actions = actions
            self.venv.step_async(actions)
        except BaseException:
            self._busy = False
            raise

    def _busy_here(self) -> bool:
        return self._async_thread == threading.get_ident()

    def step_wait(self) -> Any:
        """Finish the step and record each sub-env's share; hand the results on as they are.

        (Rewards in the dtype the VecEnv gave them.)
        """
        try:
            return self._step_wait()
        finally:
            self._busy = False

    def _step_wait(self) -> Any:
        try:
            result = self.venv.step_wait()
        except Exception as exc:
            self._steps.step_failed(exc)
            raise
        try:
            self._steps.record(self._actions, self._reader.read(result))
        except Exception as exc:  # never break the training loop over recording trouble
            self._steps.idle = None
            self._file.trouble(exc)
        if self._float_rewards is not None:
            obs, rewards, dones, infos = result
            return obs, rewards.astype(self._float_rewards), dones, infos
        return result

    def finish(self) -> None:
        """Finish the evidence file, and leave the VecEnv open (e.g. after an evaluation).

        Safe to call more than once; the recorder records nothing after it.
        """
        self._close_file(self._unwiden)

    def close(self) -> None:
        """Finish the evidence file (open episodes end ``incomplete``), then close the VecEnv.

        Safe to call more than once; the VecEnv is closed even if finishing fails.
        """
        if getattr(self, "_closed", True):
            self.venv.close()
            return
        self._close_file(self.venv.close)

    def _unwiden(self) -> None:
        """Give a widened ``DummyVecEnv`` its float32 reward buffer back."""
        if self._float_rewards is not None:
            local = self._local
            if local is not None:
                local.buf_rews = local.buf_rews.astype(self._float_rewards)
            self._float_rewards = None

    def __enter__(self) -> RecordVecEnvEvidence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _per_env(values: Any, n: int) -> list[Any]:
    """``n`` values from a per-sub-env list (``None`` where it has none)."""
    try:
        out = list(values)
    except TypeError:
        return [None] * n
    return (out + [None] * n)[:n]
