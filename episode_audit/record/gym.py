"""Record a Gymnasium env: :class:`RecordEvidence`, every step of every episode into one file.

The wrapper is a thin layer over one :class:`~episode_audit.record.stream.Stream` of an
:class:`~episode_audit.record.file.EvidenceFile` (the recording core, shared with the vector and
PettingZoo recorders); its options are those of
:class:`~episode_audit.record.settings.RecorderSettings`. How steps are recorded, flushed and
noted: ``docs/recording.md``. The wrapper raises only for misuse, e.g. stepping after
``close()``; a bad value from the env is recorded and noted. :func:`warn_unrestorable` warns,
when a recorder is built, of what will make its episodes' state unrestorable on replay;
:func:`reward_wrappers` finds the wrappers under a recorder that change the reward.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec
from gymnasium.wrappers import Autoreset
from typing_extensions import Unpack

from ..errors import RecorderWarning
from ..format.spaces import codec_for, describe_space
from ..format.wrappers import (
    LAYOUT_REWARD_WRAPPERS,
    LAYOUT_STATE_SNAPSHOTS,
    REWARD_CHANGING,
    state_causes,
    unsaved_state,
)
from .block import Episode
from .endings import NO_ACTION
from .fast import (
    CompiledReset,
    WrapperStep,
    reset_function,
    step_function,
    wrapper_step_function,
)
from .file import EvidenceFile, FileRecorder
from .notes import note, short
from .rules import find_wrapper
from .seeding import capture_rng_state
from .settings import (
    STEP_LIBRARIES,
    RecorderOptions,
    RecorderSettings,
    check_options,
    library_versions,
    run_info,
)
from .state import StateTargets
from .time_limits import limited_spec, time_limits
from .values import recordable_options

__all__ = [
    "STEP_LIBRARIES",
    "RecordEvidence",
    "autoreset_under",
    "entry_point",
    "library_versions",
    "reward_wrappers",
    "warn_unrestorable",
    "wrapper_chain",
]


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
        path: The evidence file to create (a missing folder is created). An existing file
            is never overwritten unless ``overwrite=True``.
        **options: The recorder options (``tags``, ``reward_terms``, ``constant_terms``,
            ``ending_rules``, ``info_keys``, ``digest_min_bytes``, ``block_steps``,
            ``flush_every_s``, ``fsync``, ``overwrite``, ``command_line``,
            ``transparent_wrappers``): see
            :class:`~episode_audit.record.settings.RecorderSettings`.
    """

    __slots__ = ("_busy", "_gated")  # (FileRecorder's flags: the compiled step reads slots)

    _compiled_step: WrapperStep | None = None  # (the instance's step, when compiled)

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
        layout: dict[str, Any] = {"kind": "single", "num_envs": 1, "agents": []}
        # the wrappers (and env) below whose state is snapshot at each reset (.state)
        self._state = StateTargets(env)
        if self._state:
            layout[LAYOUT_STATE_SNAPSHOTS] = True
        changing = reward_wrappers(env)
        if changing:
            layout[LAYOUT_REWARD_WRAPPERS] = changing
        self.run_info = run_info(
            settings=settings,
            spec=limited_spec(env.spec, env),
            observation_space=describe_space(env.observation_space),
            action_space=describe_space(env.action_space),
            layout=layout,
            info_of=entry_point(env),
        )
        warn_unrestorable(type(self).__name__, wrapper_chain(env), self.run_info.layout)
        self._autoreset = autoreset_under(type(self).__name__, env)
        self._file = EvidenceFile(path, self.run_info, settings, owner=self)
        self.path = self._file.path
        self._stream = self._file.add_stream(
            obs_codec,
            act_codec,
            env_index=0,
            time_limits=time_limits(env),
            state=bool(self._state),
        )
        self._file.start()
        self._record_step = step_function(self._stream)
        # (the state snapshot is taken on the Python path only)
        self._fast_reset = None if self._state else reset_function(self._record_step)
        self._opened()
        self._compiled_step = self._install_compiled_step()

    def _install_compiled_step(self) -> WrapperStep | None:
        """Put the compiled :meth:`step` in the instance's dict, where it applies.

        Only for this class's own ``step`` (a subclass that overrides it keeps its own), read
        as a plain attribute ``env``. Attribute lookup finds the instance's ``step`` first (a
        method is not a data descriptor): ``recorder.step(action)`` then runs no Python frame.
        """
        if (
            type(self).step is not RecordEvidence.step
            or any("env" in vars(cls) for cls in type(self).__mro__)
            or self._autoreset is not None  # (its resets are seen by the Python step only)
        ):
            return None
        step = wrapper_step_function(self, self._record_step, RecordEvidence.step)
        if step is not None:
            self.__dict__["step"] = step
        return step

    @property
    def spec(self) -> EnvSpec | None:  # type: ignore[override]
        """The wrapped env's spec: recording observes the env, it is not part of it.

        So ``gym.make(recorder.spec)`` builds the same env without a second recorder writing
        to the same file.
        """
        return self.env.spec

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[gym.core.ObsType, dict[str, Any]]:
        """Reset the env, recording the seed (or the RNG state), options and observation.

        The state of the wrappers below that have a state adapter (e.g.
        ``NormalizeObservation``) is snapshot just before the reset (docs/recording.md).
        """
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            if self._gated:  # (closed, or a flush() / close() under way in another thread)
                self._enter()
            fast = self._fast_reset
            if fast is None or options is not None:
                return self._reset(seed, options, begin=True)
            return self._reset_compiled(fast, seed)
        finally:
            self._busy = False

    def _reset_compiled(
        self, fast: CompiledReset, seed: int | None
    ) -> tuple[gym.core.ObsType, dict[str, Any]]:
        """:meth:`reset` with no options, begun and recorded in C when it is the common case."""
        try:
            episode = fast.begin(seed)  # (the common case: a seeded reset, compiled)
        except Exception as exc:  # never break the training loop over recording trouble
            self._file.trouble(exc)
            return self._reset(seed, None, begin=False)
        if episode is None:
            return self._reset(seed, None, begin=True)
        try:
            result = self.env.reset(seed=seed, options=None)
        except Exception as exc:
            self._on_error(exc, "reset")
            raise
        try:
            if fast.reset_row(episode, result) is None:  # (not the common case)
                self._record_reset(episode, result, [], None)
        except Exception as exc:
            self._file.trouble(exc)
        return result

    def _reset(
        self, seed: int | None, options: dict[str, Any] | None, *, begin: bool
    ) -> tuple[gym.core.ObsType, dict[str, Any]]:
        """:meth:`reset` on the Python path (``begin``: the episode too; else only the reset)."""
        episode, notes, state = self._begin(seed, options) if begin else (None, [], None)
        try:
            result = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            self._on_error(exc, "reset")
            raise
        try:
            self._record_reset(episode, result, notes, state)
        except Exception as exc:
            self._file.trouble(exc)
        return result

    def _begin(
        self, seed: int | None, options: dict[str, Any] | None
    ) -> tuple[Episode | None, list[str], str | None]:
        """Begin an episode before its reset: the episode, its notes, its state snapshot.

        Without a seed, the env's RNG state is read first (replay restores it). Recording
        trouble is the file's: the episode is then ``None``.
        """
        notes: list[str] = []
        try:
            self._stream.end_open()
            rng_state = capture_rng_state(self._unwrapped) if seed is None else None
            state = self._state.capture(notes) if self._state else None
            recorded = recordable_options(options)  # (before the reset, which may change them)
            return self._stream.begin(seed, recorded, rng_state, notes), notes, state
        except Exception as exc:  # never break the training loop over recording trouble
            self._file.trouble(exc)
            return None, notes, None

    def _record_reset(
        self, episode: Episode | None, result: Any, notes: list[str], state: str | None
    ) -> None:
        """Record the reset row of ``episode`` (if it began), then flush when due."""
        try:
            obs, info = result
        except Exception:
            notes.append(note("reset_result_invalid", f"reset() returned {short(result)}"))
            obs, info = None, {}
        if episode is not None:
            self._stream.record_reset(episode, obs, info, notes, state)
        file = self._file
        if file.due():
            file.auto_flush()

    def step(
        self, action: gym.core.ActType
    ) -> tuple[gym.core.ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env and record the step; the 5-tuple is returned untouched.

        With the compiled step (``docs/recording.md``) a recorder's ``step`` is its compiled
        twin, in its instance dict, which does the same and hands this method what it does not
        take (a closed recorder, a flush under way in another thread, keyword arguments).
        """
        if self._busy:  # (a call under way: another thread's is refused)
            self._one_thread()
        self._busy = True  # (read by a flush() or close() in another thread: FileRecorder)
        try:
            if self._gated:
                self._enter()
            autoreset = self._autoreset
            if autoreset is not None and autoreset.autoreset is True:
                return self._step_resetting(action)
            try:
                result = self.env.step(action)
            except Exception as exc:
                self._on_error(exc, "step", action)
                raise
            self._record_step(action, result)
            return result
        finally:
            self._busy = False

    def _step_resetting(
        self, action: gym.core.ActType
    ) -> tuple[gym.core.ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """The step in which the ``Autoreset`` right under the recorder resets the env.

        It returns the next episode's first observation and reset info, and does not take the
        action: the episode begins as a reset without a seed does (from the RNG state read
        just before), and the step is recorded as its reset row. Its action and reward (0) are
        no step of any episode.
        """
        episode, notes, state = self._begin(None, None)
        try:
            result = self.env.step(action)
        except Exception as exc:
            self._on_error(exc, "reset")
            raise
        try:
            valid = isinstance(result, tuple) and len(result) == 5
            self._record_reset(episode, (result[0], result[4]) if valid else result, notes, state)
        except Exception as exc:
            self._file.trouble(exc)
        return result

    def _busy_here(self) -> bool:
        """Whether ``_busy`` is this thread's: inside the compiled step (no frame to find)."""
        step = self._compiled_step
        return step is not None and step.inside_here()

    def _on_error(self, exc: Exception, during: str, action: Any = NO_ACTION) -> None:
        """The env raised ``exc`` during ``during`` (a step's ``action`` is kept for replay).

        The compiled step calls it by name, as ``_on_error(exc, "step", action)``.
        """
        self._file.end_with_error((self._stream,), exc, during, action)

    def close(self) -> None:
        """Finish the evidence file (an open episode is recorded as ``incomplete``) and close.

        Safe to call more than once. The environment is closed even if finishing fails.
        """
        self._close_file(super().close)

    @property
    def closed(self) -> bool:
        """Whether the evidence file has been finished."""
        return self._closed


def autoreset_under(recorder: str, env: Any) -> Autoreset[Any, Any] | None:
    """The ``Autoreset`` right under a recorder (``env`` itself), whose resets it records.

    An ``Autoreset`` deeper in the chain resets the env inside a step the recorder cannot tell
    from another (the wrappers between may count or stack across it): warned of once, its
    later episodes are recorded as steps after the first one's end.
    """
    if isinstance(env, Autoreset):
        return env
    if isinstance(env, gym.Wrapper) and find_wrapper(env.env, Autoreset) is not None:
        warnings.warn(
            f"episode-audit: {recorder}: Autoreset under the recorder, not right under it: "
            "it resets the env inside step(), and the episodes after the first one's end are "
            "recorded as its steps after the end; put Autoreset over the recorder, or right "
            "under it (its resets are then recorded as episodes), or record a vector env "
            "with RecordVectorEvidence",
            RecorderWarning,
            stacklevel=3,
        )
    return None


def wrapper_chain(env: Any) -> list[str]:
    """The entry points (``module:Class``) of the wrappers around ``env``, innermost first.

    Never raises: a chain that cannot be walked gives what was walked.
    """
    chain: list[str] = []
    try:
        while isinstance(env, gym.Wrapper) and len(chain) < 64:
            chain.append(f"{type(env).__module__}:{type(env).__qualname__}")
            env = env.env
    except Exception:  # an env's own attribute access: the chain walked so far
        pass
    return chain[::-1]


def entry_point(obj: Any) -> str:
    """The entry point (``module:Class``) of ``obj``'s class."""
    return f"{type(obj).__module__}:{type(obj).__qualname__}"


_OWN_INFO_WRAPPER = "episode_audit.record.vector.rng:ResetRngInfo"
"""The wrapper a vector recorder installs over each sub-env (it only adds an info key)."""


def info_entry_point(env: Any) -> str:
    """The entry point of the env whose info keys the recorder reads (terms' ``info_of``).

    ``env``'s, or, past the recorder's own ``ResetRngInfo`` (which only adds its RNG key), the
    env's it wraps: a message naming whose keys they are names the user's env.
    """
    for _ in range(8):
        if entry_point(env) != _OWN_INFO_WRAPPER or not hasattr(env, "env"):
            break
        env = env.env
    return entry_point(env)


def reward_wrappers(env: Any) -> list[str]:
    """The entry points of the wrappers around ``env`` that change its reward, innermost first.

    Single or vector wrappers: each ``RewardWrapper`` / ``VectorRewardWrapper``, and those
    :data:`~episode_audit.format.wrappers.REWARD_CHANGING` names (``NormalizeReward``). Never
    raises: a chain that cannot be walked gives what was walked.
    """
    found: list[str] = []
    kinds = (gym.RewardWrapper, gym.vector.VectorRewardWrapper)
    try:
        for _ in range(64):
            if not isinstance(env, (gym.Wrapper, gym.vector.VectorWrapper)):
                break
            if isinstance(env, kinds) or type(env).__name__ in REWARD_CHANGING:
                found.append(entry_point(env))
            env = env.env
    except Exception:  # an env's own attribute access: the chain walked so far
        pass
    return found[::-1]


def warn_unrestorable(recorder: str, wrappers: Iterable[str], layout: Mapping[str, Any]) -> None:
    """Warn once per cause that will make the recorded episodes' state unrestorable on replay.

    ``wrappers``: entry points of the wrappers under the recorder (a sub-env's, for a vector
    env); ``layout``: the file's layout (its vector wrappers, the sub-envs' own state no
    snapshot holds). The causes are those ``check`` and replay read from the file
    (:func:`~episode_audit.format.wrappers.state_causes`,
    :func:`~episode_audit.format.wrappers.unsaved_state`).
    """
    spec = {"additional_wrappers": [{"entry_point": str(w)} for w in wrappers]}
    causes = state_causes(spec, layout)
    unsaved = unsaved_state(layout)  # (a vector recorder's sub-envs' own state)
    if unsaved is not None and not unsaved[1]:
        causes.append(f"episodes an unseeded reset begins cannot be replayed: {unsaved[0]}")
    for cause in causes:
        warnings.warn(f"episode-audit: {recorder}: {cause}", RecorderWarning, stacklevel=3)
