"""Record episodes of any registered Gymnasium environment with a built-in or given policy.

The library behind ``episode-audit record``: :func:`record_episodes` makes the env, wraps it in
:class:`~episode_audit.record.gym.RecordEvidence`, and runs ``episodes`` episodes seeded ``seed``,
``seed + 1``, ... .
"""

from __future__ import annotations

import os
import warnings
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from ._usercode import import_modules, load_callable
from .errors import ConfigurationError, EpisodeAuditError, RecorderError
from .format.columns import counted, error_text
from .record.gym import RecordEvidence
from .record.lock import check_output_path, refuse_existing, refuse_indexed_overwrite

__all__ = ["RecordSummary", "RecordingError", "record_episodes"]

Policy = Callable[[Any], Any]


class RecordingError(RecorderError):
    """The env or the policy raised while recording.

    The file keeps the episode as ``error`` when the env raised, ``incomplete`` when the policy did.
    """


@dataclass
class RecordSummary:
    """What :func:`record_episodes` wrote."""

    path: str
    episodes: int
    steps: int
    outcomes: dict[str, int] = field(default_factory=dict)

    def __str__(self) -> str:
        """``recorded 2 episodes (10 steps) to PATH: truncated 2`` (``1 episode``, ``1 step``)."""
        counts = ", ".join(f"{k} {v}" for k, v in sorted(self.outcomes.items()))
        episodes, steps = counted(self.episodes, "episode"), counted(self.steps, "step")
        return f"recorded {episodes} ({steps}) to {self.path}: {counts}"


def _policy(name: str, env: gym.Env[Any, Any], seed: int) -> Policy:
    if name == "random":
        space = env.action_space
        space.seed(seed)
        return lambda obs: space.sample()
    if name in ("scripted", "hacker"):
        from .tasks import make_policy

        try:
            return make_policy(name, env, seed=seed)
        except ConfigurationError as exc:
            raise ConfigurationError(f"--policy {name}: {exc}") from None
    if ":" in name:
        factory = load_callable(name)
        try:
            policy = factory(env, seed)
        except Exception as exc:
            raise ConfigurationError(
                f"--policy {name}: the factory raised {error_text(exc)}"
            ) from None
        if not callable(policy):
            raise ConfigurationError(f"--policy {name}: expected a callable obs -> action")
        return policy  # type: ignore[no-any-return]
    raise ConfigurationError(
        f"--policy: expected random, scripted, hacker or MODULE:CALLABLE, got {name!r}"
    )


def record_episodes(
    env_id: str,
    out: str | os.PathLike[str],
    *,
    policy: str = "random",
    episodes: int = 10,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    max_episode_steps: int | None = None,
    tags: Mapping[str, str] | None = None,
    imports: Sequence[str] = (),
    overwrite: bool = False,
    on_episode: Callable[[], None] | None = None,
    overwrite_option: str = "overwrite=True",
    imports_option: str = "imports=['{module}']",
) -> RecordSummary:
    """Record ``episodes`` episodes of ``env_id`` to ``out``.

    ``out`` may be a path template (``run-{index}.mcap``: the first free one), never with
    ``overwrite``; without it, a file at ``out`` is refused before the env is made. The errors
    name it ``overwrite_option`` (``--overwrite`` on the command line). An ``env_id`` whose
    namespace no imported module registered (``ALE/Pong-v5`` without ``ale_py``) is refused
    saying what to import, as ``imports_option`` (``--import {module}`` on the command line).

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "cp.mcap"
    >>> summary = record_episodes("CartPole-v1", path, episodes=2, max_episode_steps=5)
    >>> print(summary)  # doctest: +ELLIPSIS
    recorded 2 episodes (10 steps) to ...cp.mcap: truncated 2
    """
    import_modules(imports)
    _check_counts(episodes, seed, max_episode_steps)
    check_output_path(out)  # (a FIFO would block the recorder, /dev/null lose the evidence)
    if overwrite:
        refuse_indexed_overwrite(out, overwrite_option=overwrite_option)
    else:
        refuse_existing(out, overwrite_option=overwrite_option)
    env = _make_env(env_id, env_kwargs, max_episode_steps, imports_option)
    # Everything that can be wrong with the arguments is found before the file is touched:
    # a usage error never leaves a file behind, nor replaces one (--overwrite).
    try:
        act = _policy(policy, env, seed)
    except BaseException:
        env.close()
        raise
    steps = 0
    run_tags = {"policy": policy, **(tags or {})}
    with warnings.catch_warnings():
        # the recorder's own trouble (a full disk) is said once, by the error below
        warnings.filterwarnings("ignore", category=RuntimeWarning, module="episode_audit")
        with RecordEvidence(env, out, tags=run_tags, overwrite=overwrite) as recorder:
            path = str(recorder.path)
            for i in range(episodes):
                steps += _record_episode(recorder, act, i, seed + i, path)
                if on_episode is not None:
                    on_episode()
    from .read import open_evidence

    if recorder.trouble is not None:
        raise RecorderError(_trouble_message(path, recorder.trouble))
    outcomes = Counter(open_evidence(path).episodes().column("outcome").to_pylist())
    return RecordSummary(path, episodes, steps, dict(outcomes))


def _trouble_message(path: str, trouble: str) -> str:
    """What a recording that failed on the way (a full disk) left, and what to do next."""
    from .read import open_evidence

    try:
        finished = open_evidence(path).finished
    except EpisodeAuditError:
        finished = False
    if finished:
        return (
            f"{path}: recording failed ({trouble}); the file keeps what could be written and "
            f"says what could not: `episode-audit check {path}`"
        )
    return (
        f"{path}: recording failed ({trouble}); the file ends after its last good flush and "
        f"could not be finished: `episode-audit recover {path} OUT.mcap` finishes a copy"
    )


def _check_counts(episodes: int, seed: int, max_episode_steps: int | None) -> None:
    """The number of episodes, the first seed and the time limit are in range."""
    if episodes < 1:
        raise ConfigurationError(f"--episodes: expected at least 1, got {episodes}")
    if seed < 0 or seed + episodes > 2**63:
        raise ConfigurationError(
            f"--seed: expected 0 <= seed and seed + episodes <= 2**63 (seeds are stored as "
            f"int64), got {seed}"
        )
    if max_episode_steps is not None and max_episode_steps < 1:
        raise ConfigurationError(
            f"--max-episode-steps: expected at least 1, got {max_episode_steps}"
        )


_NAMESPACES = {"ALE": "ale_py"}
"""The module whose import registers an env namespace (Gymnasium no longer imports it)."""


def _registered_by(env_id: str) -> str | None:
    """The module registering ``env_id``'s namespace, when it is one :data:`_NAMESPACES` knows.

    >>> _registered_by("ALE/Pong-v5"), _registered_by("Mine/Craft-v0")
    ('ale_py', None)
    """
    namespace = env_id.partition("/")[0] if "/" in env_id else None
    return _NAMESPACES.get(namespace or "")


def _make_env(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None,
    max_episode_steps: int | None,
    imports_option: str,
) -> gym.Env[Any, Any]:
    """``gym.make(env_id, ...)``; anything that goes wrong is a configuration error.

    An unregistered namespace says which module to import (:func:`_registered_by`).
    """
    kwargs = dict(env_kwargs or {})
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = max_episode_steps
    try:
        return gym.make(env_id, **kwargs)
    except gym.error.NamespaceNotFound:
        namespace, module = env_id.partition("/")[0], _registered_by(env_id)
        fix = imports_option.format(module=module or "MODULE")
        whose = ", which registers it" if module else " naming the package that registers it"
        raise ConfigurationError(
            f"cannot make {env_id!r}: no env is registered in namespace {namespace[:80]!r}; "
            f"pass {fix}{whose}"
        ) from None
    except gym.error.Error as exc:
        raise ConfigurationError(f"cannot make {env_id!r}: {exc}") from None
    except Exception as exc:  # the env's own constructor: a bad kwarg, a missing file, ...
        raise ConfigurationError(
            f"cannot make {env_id!r} with {kwargs}: {error_text(exc)}"
        ) from None


def _record_episode(recorder: RecordEvidence, act: Policy, i: int, seed: int, path: str) -> int:
    """Run episode ``i`` (seeded ``seed``) to its end; return its steps.

    An exception from the env or the policy is a :class:`RecordingError` saying how the file
    keeps the episode.
    """
    steps = 0
    try:
        obs, _ = recorder.reset(seed=seed)
        while True:
            try:
                action = act(obs)
            except Exception as exc:  # the policy's fault: the env's episode is open
                raise RecordingError(
                    f"episode {i}: the policy raised {error_text(exc)} (the episode is "
                    f"recorded as incomplete in {path})"
                ) from exc
            obs, _, terminated, truncated, _ = recorder.step(action)
            steps += 1
            if terminated or truncated:
                return steps
    except RecordingError:
        raise
    except Exception as exc:
        raise RecordingError(
            f"episode {i}: {error_text(exc)} (the episode is recorded as error in {path})"
        ) from exc
