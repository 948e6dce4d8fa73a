"""Every Gymnasium MuJoCo v5 and v4 env's reward terms sum to its reward with no option."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import pytest

from episode_audit import RecordEvidence, check, open_evidence
from episode_audit.record.settings import KNOWN_TERMS

pytest.importorskip("mujoco")

MUJOCO_V5 = sorted(
    env_id
    for env_id, spec in gym.registry.items()
    if env_id.endswith("-v5")
    and isinstance(spec.entry_point, str)
    and spec.entry_point.startswith("gymnasium.envs.mujoco")
)
MUJOCO_V4 = sorted(
    env_id
    for env_id, spec in gym.registry.items()
    if env_id.endswith("-v4")
    and isinstance(spec.entry_point, str)
    and spec.entry_point.startswith("gymnasium.envs.mujoco")
)


def record(env: gym.Env, path: Path, steps: int = 40, **options: object) -> Path:
    with RecordEvidence(env, path, **options) as rec:  # type: ignore[arg-type]
        rec.reset(seed=0)
        rec.action_space.seed(0)
        for _ in range(steps):
            _, _, terminated, truncated, _ = rec.step(rec.action_space.sample())
            if terminated or truncated:
                rec.reset()
    return path


def test_the_mujoco_v5_envs_are_all_here() -> None:
    assert len(MUJOCO_V5) == 11 and set(KNOWN_TERMS) <= set(MUJOCO_V5) | set(MUJOCO_V4)


@pytest.mark.parametrize("env_id", MUJOCO_V5)
def test_each_mujoco_v5_env_checks_clean_with_no_terms_option(env_id: str, tmp_path: Path) -> None:
    path = record(gym.make(env_id), tmp_path / "run.mcap")
    result = check([path], require_terms=True)
    assert [f.message for f in result.findings if f.severity == "error"] == []
    assert open_evidence(path).steps().column("terms").null_count == 0


@pytest.mark.parametrize("env_id", MUJOCO_V4)
def test_each_mujoco_v4_env_checks_clean_with_no_terms_option(env_id: str, tmp_path: Path) -> None:
    """A v4 env whose info has no ``reward_*`` keys has no terms (a note), never an error."""
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "(?s).*is out of date", DeprecationWarning)
            env = gym.make(env_id)
    except ImportError as exc:  # (Pusher-v4 needs mujoco < 3)
        pytest.skip(str(exc))
    path = record(env, tmp_path / "run.mcap")
    assert [f.message for f in check([path]).findings if f.severity == "error"] == []


def test_terms_given_are_kept_over_the_known_ones(tmp_path: Path) -> None:
    env = gym.make("HumanoidStandup-v5")
    path = record(env, tmp_path / "given.mcap", steps=5, constant_terms={"one": 1.0})
    assert open_evidence(path).run.reward_terms["constants"] == {"one": 1.0}
    env = gym.make("InvertedDoublePendulum-v5")
    path = record(env, tmp_path / "auto.mcap", steps=5, reward_terms="auto")
    assert open_evidence(path).run.reward_terms["source"] == "auto"
    result = check([path])
    assert [f.code for f in result.findings if f.severity == "error"] == ["terms_sum_mismatch"]
