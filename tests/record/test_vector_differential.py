"""The vector recorder's batched path (and its compiled step) writes what the sub-env by sub-env
path writes, over steps whose infos, flags and reward terms are drawn at random.

The reference is a recorder whose steps all go sub-env by sub-env on the pure-Python path
(``VectorSteps`` not batchable). The infos come in Gymnasium's vector dict form, as a list of
per-sub-env dicts (``DictInfoToList``), and from an SB3 ``DummyVecEnv``. Each scenario mixes
what the batched path takes (reward terms in every sub-env's info) with what it must hand on: a
term missing or added in one sub-env, a term that is an int, a numpy float or NaN, an info with
another key, endings with labels, both flags at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.wrappers.vector import DictInfoToList

from episode_audit import RecordVectorEvidence
from episode_audit.record import fast
from episode_audit.record.vector import steps as steps_module
from tests.support.batching import InfoReading, messages
from tests.support.envs import ScriptedEnv

N = 4
STEPS = 400


def _info(rng: np.random.Generator, ended: bool, merged: bool) -> dict[str, Any]:
    """A sub-env's step info: usually two float terms, now and then something else.

    ``merged``: a ``SyncVectorEnv`` merges the infos into arrays typed by the first sub-env's
    value (an int there, a NaN after it, and its step raises): the int term gets a name of its
    own there.
    """
    a, b = float(rng.normal()), float(rng.normal())
    kind = rng.integers(0, 20)
    if kind == 0:
        return {"reward_a": a}  # a term missing
    if kind == 1:
        return {"reward_a": a, "reward_b": b, "reward_c": 0.5}  # one more
    if kind == 2:  # an int term
        return (
            {"reward_a": a, "reward_b": b, "reward_n": 1}
            if merged
            else {"reward_a": 1, "reward_b": b}
        )
    if kind == 6:
        return {"reward_a": np.float32(a), "reward_b": b}  # a numpy float
    if kind == 3:
        return {"reward_a": float("nan"), "reward_b": b}
    if kind == 4:
        return {}
    if kind == 5:
        return {"reward_a": a, "reward_b": b, "x": np.ones(2)}  # a key that is no term
    info: dict[str, Any] = {"reward_a": a, "reward_b": b}
    if ended and kind < 12:
        info["success" if kind < 9 else "failure"] = True if kind < 9 else "fell"
    return info


def _sub_env(index: int, seed: int, merged: bool) -> ScriptedEnv:
    rng = np.random.default_rng([seed, index])

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        obs = rng.uniform(-1, 1, 3).astype(np.float32)
        terminated = bool(rng.random() < 0.04)
        truncated = bool(rng.random() < 0.02) or env.t >= 60
        info = _info(rng, terminated or truncated, merged)
        reward = sum(v for k, v in info.items() if k.startswith("reward_") and type(v) is float)
        return obs, float(reward), terminated, truncated, info

    def reset(env: ScriptedEnv) -> tuple[Any, dict[str, Any]]:
        return rng.uniform(-1, 1, 3).astype(np.float32), {}

    return ScriptedEnv(
        step_fn=step,
        reset_fn=reset,
        observation_space=gym.spaces.Box(-1.0, 1.0, (3,), np.float32),
        action_space=gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
    )


def _record(path: Path, stack: str, mode: AutoresetMode, seed: int) -> None:
    """Record ``STEPS`` random steps of ``N`` sub-envs: a ``SyncVectorEnv`` (its infos in the
    vector dict form, or as a list through ``DictInfoToList``), or an SB3 ``DummyVecEnv``."""
    thunks = [lambda i=i: _sub_env(i, seed, stack != "sb3") for i in range(N)]
    actions = np.random.default_rng(seed).uniform(-1, 1, (STEPS, N, 2)).astype(np.float32)
    if stack == "sb3":
        from stable_baselines3.common.vec_env import DummyVecEnv

        from episode_audit import RecordVecEnvEvidence

        with RecordVecEnvEvidence(DummyVecEnv(thunks), path, flush_every_s=1e9) as venv:
            venv.seed(seed)
            venv.reset()
            for t in range(STEPS):
                venv.step(actions[t])
        return
    envs: Any = SyncVectorEnv(thunks, autoreset_mode=mode)
    if stack == "list":
        envs = DictInfoToList(envs)
    with RecordVectorEvidence(envs, path, flush_every_s=1e9) as rec:  # (one block a stream)
        rec.reset(seed=seed)
        for t in range(STEPS):
            _, _, terminated, truncated, _ = rec.step(actions[t])
            ended = np.asarray(terminated) | np.asarray(truncated)
            if mode is AutoresetMode.DISABLED and ended.any():
                rec.reset(options={"reset_mask": ended})
            elif t % 97 == 96:  # a partial reset mid-episode
                rec.reset(seed=[t, None, None, None], options={"reset_mask": np.eye(N)[1] > 0})


STACKS = [
    *(("sync", mode) for mode in ("NEXT_STEP", "SAME_STEP", "DISABLED")),
    ("list", "NEXT_STEP"),
    ("list", "SAME_STEP"),
    ("sb3", "SAME_STEP"),
]


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize(("stack", "mode"), STACKS)
def test_batched_steps_write_what_sub_env_by_sub_env_steps_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stack: str, mode: str, seed: int
) -> None:
    if stack == "sb3":
        pytest.importorskip("stable_baselines3")
    # (fixed clocks; counts the infos the batched path took)
    reading = InfoReading(monkeypatch, "step_terms" if stack == "sync" else "list_terms")
    batched = 0
    real = steps_module.VectorSteps._batched

    def counted(self: Any, *args: Any, **kwargs: Any) -> None:
        nonlocal batched
        batched += 1
        real(self, *args, **kwargs)

    monkeypatch.setattr(steps_module.VectorSteps, "_batched", counted)
    reading.run(declining=False)
    _record(tmp_path / "batched.mcap", stack, AutoresetMode[mode], seed)
    taken = sum(reading.taken)

    # the reference: every step sub-env by sub-env, on the pure-Python path
    monkeypatch.setenv(fast.PURE_PYTHON_ENV, "1")
    init = steps_module.VectorSteps.__init__

    def unbatched(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        self._batchable, self._compiled, self._terms = False, None, None
        self._batch.terms = None

    monkeypatch.setattr(steps_module.VectorSteps, "__init__", unbatched)
    batched_steps, batched = batched, 0
    _record(tmp_path / "sub_envs.mcap", stack, AutoresetMode[mode], seed)
    assert batched == 0
    # the batched path took a good share of the steps, and handed on the others
    assert STEPS // 4 < batched_steps < STEPS * 0.9
    assert taken > STEPS // 4
    assert messages(tmp_path / "batched.mcap") == messages(tmp_path / "sub_envs.mcap")
