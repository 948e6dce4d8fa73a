"""Record SB3 evaluations, each to a file of its own, tagged with the checkpoint and the step.

- :func:`recording` — record a VecEnv for a while: the recorder goes directly over the base
  VecEnv (under ``VecNormalize``, so that ``sync_envs_normalization`` still pairs the stacks),
  and comes out again, its file finished, the VecEnv left open.
- :func:`record_evaluation` — ``evaluate_policy`` recorded.
- :class:`RecordEvalCallback` — an ``EvalCallback`` whose every evaluation is recorded.
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from ...errors import ConfigurationError
from ..settings import RecorderOptions
from .recorder import RecordVecEnvEvidence

__all__ = ["RecordEvalCallback", "record_evaluation", "recording"]


@contextmanager
def recording(
    venv: VecEnv, path: str | os.PathLike[str], options: RecorderOptions | None = None
) -> Iterator[tuple[VecEnv, RecordVecEnvEvidence]]:
    """Record ``venv`` inside the ``with`` block; yields the VecEnv to use and the recorder.

    The recorder is put directly over the base VecEnv (inside ``venv``'s wrappers, which are
    changed in place and restored on exit); on exit its file is finished and ``venv`` stays open.
    """
    lowest: VecEnvWrapper | None = None
    env: Any = venv
    while isinstance(env, VecEnvWrapper):
        lowest, env = env, env.venv
    recorder = RecordVecEnvEvidence(env, path, **(options or {}))
    try:
        if lowest is None:
            yield recorder, recorder
        else:
            lowest.venv = recorder
            try:
                yield venv, recorder
            finally:
                lowest.venv = env
    finally:
        recorder.finish()


def _tags(
    model: BaseAlgorithm,
    kind: str,
    checkpoint: str | None,
    step: int | None,
    deterministic: bool,
    options: RecorderOptions | None,
) -> RecorderOptions:
    """The recorder options of an evaluation: its tags added to the user's."""
    step = model.num_timesteps if step is None else step
    algo = type(model).__name__
    tags = {
        "evaluation": kind,
        "algorithm": algo,
        "training_step": str(step),
        "checkpoint": (checkpoint or "{algo}@{step}").format(algo=algo, step=step),
        "deterministic": str(deterministic),
    }
    out: RecorderOptions = dict(options or {})  # type: ignore[assignment]
    out["tags"] = {**tags, **(out.get("tags") or {})}
    return out


def record_evaluation(
    model: BaseAlgorithm,
    env: gym.Env[Any, Any] | VecEnv,
    path: str | os.PathLike[str],
    *,
    n_eval_episodes: int = 10,
    deterministic: bool = True,
    checkpoint: str | None = None,
    step: int | None = None,
    options: RecorderOptions | None = None,
) -> tuple[list[float], list[int]]:
    """Run SB3's ``evaluate_policy`` on ``env`` and record it to ``path``.

    The file is tagged ``evaluation`` (``evaluate_policy``), ``algorithm``, ``training_step``
    (``step``, default ``model.num_timesteps``), ``checkpoint`` (``checkpoint`` formatted with
    ``{algo}`` and ``{step}``, default ``"{algo}@{step}"``) and ``deterministic``, beside the
    tags in ``options``. The sub-envs that reached their share of episodes keep stepping
    until the others do (``evaluate_policy`` ignores those episodes; the file keeps them).

    Returns:
        Each counted episode's return and length, as ``evaluate_policy(...,
        return_episode_rewards=True)`` returns them.
    """
    venv = env if isinstance(env, VecEnv) else DummyVecEnv([lambda: env])
    opts = _tags(model, "evaluate_policy", checkpoint, step, deterministic, options)
    with recording(venv, path, opts) as (recorded, _):
        rewards, lengths = evaluate_policy(
            model,
            recorded,
            n_eval_episodes=n_eval_episodes,
            deterministic=deterministic,
            return_episode_rewards=True,
        )
    return list(rewards), list(lengths)  # type: ignore[arg-type]


class RecordEvalCallback(EvalCallback):
    """An ``EvalCallback`` that records every evaluation to a file of its own.

    Example:
        ``model.learn(10_000, callback=RecordEvalCallback(eval_env, "evals/eval-{step}.mcap",
        eval_freq=2_000))`` writes ``evals/eval-2000.mcap``, ``evals/eval-4000.mcap``, …
        (``{step}``: the model's ``num_timesteps``; parent folders are made).

    Args:
        eval_env: The env to evaluate on, as for ``EvalCallback``.
        path: The file of each evaluation, a template with ``{step}``.
        checkpoint: The ``checkpoint`` tag, a template with ``{algo}`` and ``{step}`` (e.g. the
            file a ``CheckpointCallback`` saves: ``"ckpt/rl_model_{step}_steps.zip"``).
        options: Recorder options for every file (``tags`` are added to).
        **kwargs: ``EvalCallback``'s own arguments (``eval_freq``, ``n_eval_episodes``, …).
    """

    def __init__(
        self,
        eval_env: gym.Env[Any, Any] | VecEnv,
        path: str = "evaluations/eval-{step}.mcap",
        *,
        checkpoint: str | None = None,
        options: RecorderOptions | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(eval_env, **kwargs)
        self.path_template = path
        self.checkpoint = checkpoint
        self.options = options
        self.recorded: list[Path] = []
        """The files written so far."""

    def _init_callback(self) -> None:
        """At ``learn()``'s start: refuse a later evaluation's file an earlier run left.

        A file is never overwritten (unless ``options`` say ``overwrite``): met at its
        evaluation, it would stop ``learn()`` after the training spent until then.
        """
        super()._init_callback()
        if not (self.options or {}).get("overwrite"):
            _refuse_earlier_evaluations(self.path_template, self.model.num_timesteps)

    def _on_step(self) -> bool:
        if not (self.eval_freq > 0 and self.n_calls % self.eval_freq == 0):
            return bool(super()._on_step())
        path = Path(self.path_template.format(step=self.num_timesteps))
        path.parent.mkdir(parents=True, exist_ok=True)
        opts = _tags(
            self.model, "EvalCallback", self.checkpoint, None, self.deterministic, self.options
        )
        env = self.eval_env
        with recording(env, path, opts) as (recorded, recorder):
            self.eval_env = recorded
            try:
                return bool(super()._on_step())
            finally:
                self.eval_env = env
                self.recorded.append(recorder.path)


_STEP_FIELD = re.compile(r"\{step(?::[^{}]*)?\}")


def _refuse_earlier_evaluations(template: str, step: int) -> None:
    """Raise if a file of ``template`` for a step after ``step`` exists (an earlier run's).

    Files of steps up to ``step`` (a ``learn()`` that continues this run) are not in the way.
    A template whose other braces are not plain text is not looked for.
    """
    parts = _STEP_FIELD.split(template)
    if len(parts) != 2 or any(c in "".join(parts) for c in "{}[]*?"):
        return
    head, tail = parts
    found = re.compile(re.escape(head) + r"0*(\d+)" + re.escape(tail) + r"\Z")
    for name in sorted(glob.glob(glob.escape(head) + "*" + glob.escape(tail))):
        matched = found.match(name)
        if matched and int(matched.group(1)) > step:
            raise ConfigurationError(
                f"{name}: an evaluation file an earlier run left, which RecordEvalCallback "
                "would meet mid-training and not overwrite; give this run its own folder "
                "(path=...), remove the old files, or pass options={'overwrite': True}"
            )
