"""Record a Gymnasium env: :class:`RecordEvidence`, every step of every episode into one file.

The wrapper is a thin layer over one :class:`~episode_audit.record.stream.Stream` of an
:class:`~episode_audit.record.file.EvidenceFile` (the recording core, shared with the vector and
PettingZoo recorders); its options are those of
:class:`~episode_audit.record.settings.RecorderSettings`. How steps are recorded, flushed and
noted: ``docs/recording.md``. The wrapper raises only for misuse, e.g. stepping after
``close()``; a bad value from the env is recorded and noted.
"""

from __future__ import annotations

import os
from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec
from typing_extensions import Unpack

from ..format.spaces import codec_for, describe_space
from .file import EvidenceFile, FileRecorder
from .notes import note, short
from .rules import find_time_limit
from .seeding import capture_rng_state
from .settings import (
    RecorderOptions,
    RecorderSettings,
    check_options,
    library_versions,
    run_info,
)
from .state import StateTargets

__all__ = ["RecordEvidence", "library_versions"]


class RecordEvidence(
    FileRecorder,
    gym.Wrapper[gym.core.ObsType, gym.core.ActType, gym.core.ObsType, gym.core.ActType],
):
    """Record every step of every episode of an environment to an MCAP evidence file.

    Wrap the environment once; use it as usual; ``close()`` (or leaving a ``with`` block)
    finishes the file. Each episode stores the reset seed — or, for a reset without a seed, the
    env's RNG state captured just before it — so every episode can be replayed on its own.

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from episode_audit import RecordEvidence, open_evidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "cartpole.mcap"
        >>> with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), path) as env:
        ...     _ = env.reset(seed=5)
        ...     _ = env.action_space.seed(5)
        ...     for _ in range(3):
        ...         _ = env.step(env.action_space.sample())
        >>> ev = open_evidence(path)
        >>> ep = ev.episodes().to_pylist()[0]
        >>> ep["outcome"], ep["truncation_reason"], ep["seed"], ep["length"]
        ('truncated', 'time_limit', 5, 3)

    Args:
        env: The environment to record.
        path: The evidence file to create. An existing file is never overwritten unless
            ``overwrite=True``.
        **options: The recorder options (``tags``, ``reward_terms``, ``constant_terms``,
            ``ending_rules``, ``info_keys``, ``digest_min_bytes``, ``block_steps``,
            ``flush_every_s``, ``fsync``, ``overwrite``, ``command_line``): see
            :class:`~episode_audit.record.settings.RecorderSettings`.
    """

    def __init__(
        self,
        env: gym.Env[gym.core.ObsType, gym.core.ActType],
        path: str | os.PathLike[str],
        **options: Unpack[RecorderOptions],
    ) -> None:
        check_options(options, "RecordEvidence.__init__()")
        gym.Wrapper.__init__(self, env)
        settings = RecorderSettings(**options)
        digest_min_bytes = settings.digest_min_bytes
        obs_codec = codec_for(env.observation_space, digest_min_bytes=digest_min_bytes)
        act_codec = codec_for(env.action_space)
        self._unwrapped = env.unwrapped
        self.run_info = run_info(
            settings=settings,
            spec=env.spec,
            observation_space=describe_space(env.observation_space),
            action_space=describe_space(env.action_space),
            layout={"kind": "single", "num_envs": 1, "agents": []},
        )
        self._file = EvidenceFile(path, self.run_info, settings, owner=self)
        self.path = self._file.path
        # the wrappers (and env) below whose state is snapshot at each reset (.state)
        self._state = StateTargets(env)
        self._stream = self._file.add_stream(
            obs_codec,
            act_codec,
            env_index=0,
            time_limit=find_time_limit(env),
            state=bool(self._state),
        )
        self._file.start()
        self._record_step = self._stream.step
        self._closed = False

    @property
    def spec(self) -> EnvSpec | None:  # type: ignore[override]
        """The wrapped env's spec: recording observes the env, it is not part of it.

        So ``gym.make(recorder.spec)`` builds the same env without a second recorder writing
        to the same file.
        """
        return self.env.spec

    def _check_open(self) -> None:
        self._file.check_open()

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[gym.core.ObsType, dict[str, Any]]:
        """Reset the env, recording the seed (or the RNG state), options and observation.

        The state of the wrappers below that have a state adapter (e.g.
        ``NormalizeObservation``) is snapshot just before the reset (docs/recording.md).
        """
        file = self._file
        file.check_open()
        stream = self._stream
        notes: list[str] = []
        episode = None
        state = None
        try:
            stream.end_open()
            rng_state = capture_rng_state(self._unwrapped) if seed is None else None
            state = self._state.capture(notes) if self._state else None
            episode = stream.begin(seed, options, rng_state, notes)
        except Exception as exc:  # never break the training loop over recording trouble
            file.trouble(exc)
        try:
            result = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            self._on_error(exc, "reset")
            raise
        try:
            try:
                obs, info = result
            except Exception:
                notes.append(note("reset_result_invalid", f"reset() returned {short(result)}"))
                obs, info = None, {}
            if episode is not None:
                stream.record_reset(episode, obs, info, notes, state)
            if file.due():
                file.auto_flush()
        except Exception as exc:
            file.trouble(exc)
        return result

    def step(
        self, action: gym.core.ActType
    ) -> tuple[gym.core.ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env and record the step; the 5-tuple is returned untouched."""
        if self._closed:
            self._check_open()
        try:
            result = self.env.step(action)
        except Exception as exc:
            self._on_error(exc, "step")
            raise
        self._record_step(action, result)
        return result

    def _on_error(self, exc: Exception, during: str) -> None:
        self._file.end_with_error((self._stream,), exc, during)

    def close(self) -> None:
        """Finish the evidence file (an open episode is recorded as ``incomplete``) and close.

        Safe to call more than once. The environment is closed even if finishing fails.
        """
        self._close_file(super().close)

    @property
    def closed(self) -> bool:
        """Whether the evidence file has been finished."""
        return self._closed
