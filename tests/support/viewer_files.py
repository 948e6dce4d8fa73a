"""Evidence files the viewer-export tests open: camera frames, a vector env, a PettingZoo game,
random CartPole; what their resets hold."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from episode_audit import RecordAECEvidence, RecordEvidence, RecordVectorEvidence, open_evidence
from tests.support.envs import ScriptedEnv

CAMERA = spaces.Dict(
    {
        "camera": spaces.Box(0, 255, (24, 32, 3), np.uint8),
        "state": spaces.Box(-1.0, 1.0, (2,), np.float32),
        "mode": spaces.Discrete(3),
    }
)


def _camera_obs(env: ScriptedEnv) -> dict[str, Any]:
    pixels = np.zeros((24, 32, 3), np.uint8)
    pixels[:, :, 0] = env.t * 10  # each frame differs
    pixels[env.t % 24, :, 1] = 255
    state = np.array([env.t / 10, -env.t / 10], np.float32)
    return {"camera": pixels, "state": state, "mode": env.t % 3}


def _camera_step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
    terms = {"progress": 0.5, "effort": -0.25 * float(action)}
    if env.t == 4 and getattr(env, "seed_value", None) == 0:  # seed 1: cut off at 6 steps
        return _camera_obs(env), 0.25, True, False, {"reward_terms": terms, "failure": "collision"}
    return _camera_obs(env), 0.5 - 0.25 * float(action), False, False, {"reward_terms": terms}


class _Camera(ScriptedEnv):
    seed_value: int | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.seed_value = seed
        super().reset(seed=seed)
        return _camera_obs(self), {}


def camera_env() -> gym.Env[Any, Any]:
    """Image + state observations (``camera``, ``state``, ``mode``), 6 steps at most."""
    return gym.wrappers.TimeLimit(
        _Camera(step_fn=_camera_step, observation_space=CAMERA, action_space=spaces.Discrete(2)),
        6,
    )


def camera_file(path: Path) -> Path:
    """Two episodes of image + state observations: a ``collision`` failure (4 steps), then
    a time-limit truncation (6 steps)."""
    env = camera_env()
    with RecordEvidence(env, path, tags={"policy": "scripted"}) as rec:
        for seed in (0, 1):
            rec.reset(seed=seed)
            done = False
            while not done:
                _, _, term, trunc, _ = rec.step(1)
                done = term or trunc
    return path


def vector_file(path: Path) -> Path:
    """CartPole x3 (sync, NEXT_STEP autoreset), 40 vector steps."""
    envs = gym.make_vec("CartPole-v1", 3, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for t in range(40):
            rec.step(np.array([t % 2, 1, 0]))
    return path


def camera_vector_file(path: Path) -> Path:
    """Two :func:`camera_env` sub-envs (sync), 8 vector steps."""
    envs = gym.vector.SyncVectorEnv([camera_env, camera_env])
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(8):
            rec.step(np.array([1, 0]))
    return path


def aec_file(path: Path) -> Path:
    """Two tic-tac-toe games with random legal moves."""
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import tictactoe_v3

    with RecordAECEvidence(tictactoe_v3.env(), path) as env:
        for seed in (0, 1):
            env.reset(seed=seed)
            rng = np.random.default_rng(seed)
            for _agent in env.agent_iter():
                obs, _, term, trunc, _ = env.last()
                legal = np.flatnonzero(obs["action_mask"])
                env.step(None if term or trunc else int(rng.choice(legal)))
    return path


def random_cartpole_file(path: Path, steps: int, **options: Any) -> Path:
    """CartPole-v1 with random actions (seed 0) for ``steps`` steps, reset whenever it ends;
    ``options`` are the recorder's (``block_steps=64``: many chunks)."""
    with RecordEvidence(gym.make("CartPole-v1"), path, **options) as env:
        env.action_space.seed(0)
        env.reset(seed=0)
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
    return path


VIEWER_FILES = {
    "camera": camera_file,
    "vector": vector_file,
    "camera_vector": camera_vector_file,
    "aec": aec_file,
}
"""Each kind of evidence file above, by name: ``make(path)`` records it."""


def recorded_resets(source: Path) -> list[dict[str, Any]]:
    """Each reset of ``source`` as ``Evidence.resets()`` holds it, for a viewer export to show:
    its stream's prefix (``/env_N``, ``/AGENT``, none for one env), episode, time and decoded
    observation, in the resets table's order."""
    ev = open_evidence(source)
    resets = ev.resets()
    codec = ev.observation_codec
    assert codec is not None
    observations = codec.decode(resets.column("observation"))
    single = ev.run.layout["kind"] == "single"
    rows = []
    for row, observation in zip(resets.to_pylist(), observations, strict=True):
        agent, index = row.get("agent"), row["env_index"]
        prefix = "" if single else f"/{agent}" if agent else f"/env_{index}"
        rows.append(
            {
                "prefix": prefix,
                "episode": row["episode"],
                "time_ns": row["time_ns"],
                "observation": observation,
            }
        )
    return rows


def leaves(value: Any, path: tuple[str, ...] = ()) -> dict[tuple[str, ...], Any]:
    """A decoded observation's values by Dict key path: ``{("state",): array, ...}``."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in leaves(item, (*path, key)).items()}
    return {path: value}
