"""Stable-Baselines3 benchmarks (run by bench/run.py when SB3 is installed).

- ``ppo``: a real PPO training run on CartPole-v1 (single-thread torch, DummyVecEnv x4), with
  and without RecordVecEnvEvidence, alternating in one process; the wall-time ratio.
- ``vecenv``: RecordVecEnvEvidence's cost per sub-env step over a bare DummyVecEnv of
  CartPole-v1, and of Reacher-v5 (reward terms in every info): fixed random actions, SB3's
  autoreset, the recorded and two bare VecEnvs taking turns a slice of steps at a time.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np


def available() -> bool:
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def _cartpole() -> gym.Env[Any, Any]:
    return gym.make("CartPole-v1")


def _ratios(base: list[float], other: list[float]) -> dict[str, Any]:
    per_round = [o / b for b, o in zip(base, other, strict=True)]
    return {
        "ratio_median": statistics.median(per_round),
        "ratio_of_minimums": min(other) / min(base),
        "ratios": [round(x, 4) for x in per_round],
    }


def bench_ppo(tmp: Path, steps: int, rounds: int) -> dict[str, Any]:
    """Wall time of ``PPO(...).learn(steps)`` recorded / bare, alternating which goes first."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from episode_audit.record.sb3 import RecordVecEnvEvidence

    torch.set_num_threads(1)

    def run(recorded: bool, r: int, name: str = "ppo") -> float:
        venv: Any = DummyVecEnv([_cartpole] * 4)
        if recorded:
            venv = RecordVecEnvEvidence(venv, tmp / f"{name}-{r}.mcap", overwrite=True)
        model = PPO("MlpPolicy", venv, n_steps=256, seed=r)
        start = time.perf_counter()
        model.learn(steps)
        venv.close()
        return time.perf_counter() - start

    run(True, 0, "warm")  # warm up (imports, first torch kernels)
    bare: list[float] = []
    rec: list[float] = []
    for r in range(rounds):
        order = (False, True) if r % 2 == 0 else (True, False)
        for recorded in order:
            (rec if recorded else bare).append(run(recorded, r))
    return {
        "env": "CartPole-v1 x4 (DummyVecEnv), PPO n_steps=256, torch 1 thread",
        "steps": steps,
        "rounds": rounds,
        "bare_s": [round(t, 3) for t in bare],
        "recorded_s": [round(t, 3) for t in rec],
        **_ratios(bare, rec),
    }


def _stepper(venv: Any) -> Callable[[np.ndarray[Any, Any]], None]:
    venv.seed(0)
    venv.reset()

    def loop(actions: np.ndarray[Any, Any]) -> None:
        for row in actions:
            venv.step(row)

    return loop


Interleaved = Callable[[Mapping[str, Callable[[Any], None]], Any, int], dict[str, float]]
Actions = Callable[[str, int, int], np.ndarray[Any, Any]]


def bench_vecenv(
    tmp: Path,
    interleaved: Interleaved,
    vector_actions: Actions,
    num_envs: int,
    steps: int,
    rounds: int,
    slice_steps: int,
    env_id: str = "CartPole-v1",
) -> dict[str, Any]:
    """Per-sub-env-step overhead of RecordVecEnvEvidence over a bare DummyVecEnv of ``env_id``:
    recorded, bare and bare again take turns ``slice_steps`` vector steps at a time
    (``interleaved``: bench/run.py's). The recorder records every round as one run, flushing as
    often as it would alone (as bench/run.py's ``bench_record``); its ``close()`` is timed
    apart. The actions are ``vector_actions(env_id, steps, num_envs)`` (bench/run.py's)."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from episode_audit.record.sb3 import RecordVecEnvEvidence

    def make() -> gym.Env[Any, Any]:
        return gym.make(env_id)

    actions = vector_actions(env_id, steps, num_envs)
    warm = RecordVecEnvEvidence(DummyVecEnv([make] * num_envs), tmp / "w.mcap", overwrite=True)
    _stepper(warm)(actions[:1000])
    warm.close()
    kinds = ("bare", "bare_again", "rec")
    # one run over every round, flushing as often as alone: bench/run.py's bench_record
    rec = RecordVecEnvEvidence(
        DummyVecEnv([make] * num_envs),
        tmp / f"sb3-vecenv-{env_id}.mcap",
        overwrite=True,
        flush_every_s=len(kinds),
    )
    rec_loop = _stepper(rec)
    bare_t, again_t, rec_t = [], [], []
    for _ in range(rounds):
        venvs = {
            "bare": DummyVecEnv([make] * num_envs),
            "bare_again": DummyVecEnv([make] * num_envs),
        }
        loops = {**{k: _stepper(v) for k, v in venvs.items()}, "rec": rec_loop}
        seconds = interleaved(loops, actions, slice_steps)
        for venv in venvs.values():
            venv.close()
        bare_t.append(seconds["bare"])
        again_t.append(seconds["bare_again"])
        rec_t.append(seconds["rec"])
    t0 = time.perf_counter()
    rec.close()
    close_ms = (time.perf_counter() - t0) * 1e3
    sub_steps = steps * num_envs
    return {
        "env": f"{env_id} x{num_envs} (SB3 DummyVecEnv)",
        "vector_steps": steps,
        "rounds": rounds,
        "bare_us_per_sub_env_step": statistics.median(bare_t) / sub_steps * 1e6,
        "recorded_us_per_sub_env_step": statistics.median(rec_t) / sub_steps * 1e6,
        "overhead_us_per_sub_env_step": statistics.median(
            [(rt - bt) / sub_steps * 1e6 for rt, bt in zip(rec_t, bare_t, strict=True)]
        ),
        **_ratios(bare_t, rec_t),
        "aa_median": statistics.median(a / b for a, b in zip(again_t, bare_t, strict=True)),
        "close_ms": close_ms,
    }


def bench(tmp: Path, interleaved: Interleaved, vector_actions: Actions) -> dict[str, Any]:
    """Both SB3 benchmarks, or why they were skipped."""
    if not available():
        return {"skipped": "SB3 not installed (pip install 'episode-audit[sb3]')"}
    return {
        "ppo_training": bench_ppo(tmp, 4096, 3),
        "vecenv_recorder": bench_vecenv(tmp, interleaved, vector_actions, 8, 6000, 7, 100),
        # reward terms in every sub-env's info
        "vecenv_recorder_mujoco": bench_vecenv(
            tmp, interleaved, vector_actions, 8, 1500, 7, 25, env_id="Reacher-v5"
        ),
    }
