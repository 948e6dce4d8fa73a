"""An env factory's env whose match with the recording cannot be verified (replay/mismatch.py).

A factory's env without a spec (built by its class, not ``gym.make``) and wrappers that record
no arguments (SB3's Atari wrappers) cannot be held to the recorded arguments: built otherwise,
they differ with nothing wrong. Nor can any factory's env be held to a recording that holds no
spec (its env was not made with ``gym.make``). An episode that differs in such an env is
``not_replayable`` naming why, never ``diverged``; one that replays the same is ``identical``.
Without a spec, a class that is not the recorded entry point's (or, with no recorded spec, not
the class the recorder wrapped) does not match.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.envs.classic_control.pendulum import PendulumEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.wrappers import ClipAction, TimeLimit

from episode_audit import RecordEvidence, RecordVectorEvidence, replay

_UNVERIFIED = "in an env whose match with the recording could not be verified: "


def _record(path: Path, env: gym.Env[Any, Any], steps: int = 10) -> Path:
    """Two episodes (seeds 0 and 1) of ``steps`` random steps, or fewer where one ends."""
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for seed in (0, 1):
            rec.reset(seed=seed)
            for _ in range(steps):
                _, _, terminated, truncated, _ = rec.step(rec.action_space.sample())
                if terminated or truncated:
                    break
    return path


def _verdicts(path: Path, factory: Callable[[], gym.Env[Any, Any]]) -> set[tuple[str, Any]]:
    return {(e.status, e.reason) for e in replay([path], env_factory=factory).episodes}


def test_a_factory_env_without_a_spec_that_differs_is_not_replayable(tmp_path: Path) -> None:
    path = _record(tmp_path / "cheetah.mcap", gym.make("HalfCheetah-v5", max_episode_steps=10))
    same = _verdicts(path, lambda: TimeLimit(HalfCheetahEnv(), 10))
    assert same == {("identical", None)}
    other = replay([path], env_factory=lambda: TimeLimit(HalfCheetahEnv(ctrl_cost_weight=0.3), 10))
    assert [e.status for e in other.episodes] == ["not_replayable"] * 2
    assert all(e.divergence is not None for e in other.episodes)  # (its difference kept)
    assert other.episodes[0].reason == (
        f"differed at step 0 (reward) {_UNVERIFIED}the env factory's env has no spec, so its "
        'arguments cannot be compared with the recording\'s ("HalfCheetah-v5", kwargs {}); '
        "make the factory build it with gymnasium.make so they can be"
    )
    made = _verdicts(path, lambda: gym.make("HalfCheetah-v5", max_episode_steps=10))
    assert made == {("identical", None)}


class _Copy(gym.Env[Any, Any]):
    """Not CartPole's class, stepping a CartPole inside it with its reward doubled."""

    def __init__(self) -> None:
        self.inner = CartPoleEnv()
        self.observation_space = self.inner.observation_space
        self.action_space = self.inner.action_space

    def reset(self, *, seed: int | None = None, options: Any = None) -> tuple[Any, dict[str, Any]]:
        return self.inner.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.inner.step(action)
        return obs, 2 * float(reward), terminated, truncated, info


def test_a_factory_env_without_a_spec_of_another_class_does_not_match(tmp_path: Path) -> None:
    path = _record(tmp_path / "cartpole.mcap", gym.make("CartPole-v1"))
    assert _verdicts(path, lambda: TimeLimit(_Copy(), 500)) == {
        (
            "not_replayable",
            "the rebuilt env does not match the recording: env entry point "
            '"gymnasium.envs.classic_control.cartpole:CartPoleEnv" recorded vs class '
            f'"{__name__}:_Copy" rebuilt; make the --env-factory build the env as recorded',
        )
    }


_NO_SPEC = (
    "the recording holds no env spec (its env was not made with gymnasium.make) to verify the "
    "env factory's env against; record an env made with gymnasium.make so it can be"
)


def test_a_recording_without_a_spec_that_differs_from_a_factory_env_is_not_replayable(
    tmp_path: Path,
) -> None:
    path = _record(tmp_path / "cheetah.mcap", TimeLimit(HalfCheetahEnv(), 10))
    assert _verdicts(path, lambda: TimeLimit(HalfCheetahEnv(), 10)) == {("identical", None)}
    made = _verdicts(path, lambda: gym.make("HalfCheetah-v5", max_episode_steps=10))
    assert made == {("identical", None)}
    other = replay([path], env_factory=lambda: TimeLimit(HalfCheetahEnv(ctrl_cost_weight=0.3), 10))
    assert [e.status for e in other.episodes] == ["not_replayable"] * 2
    assert all(e.divergence is not None for e in other.episodes)  # (its difference kept)
    assert other.episodes[0].reason == f"differed at step 0 (reward) {_UNVERIFIED}{_NO_SPEC}"


def test_a_vector_recording_without_a_spec_that_differs_is_not_replayable(tmp_path: Path) -> None:
    path = tmp_path / "pendulums.mcap"
    envs = gym.vector.SyncVectorEnv([lambda: TimeLimit(PendulumEnv(), 5)] * 2)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(6):
            rec.step(rec.action_space.sample())
    assert _verdicts(path, lambda: TimeLimit(PendulumEnv(), 5)) == {("identical", None)}
    other = replay([path], env_factory=lambda: TimeLimit(PendulumEnv(g=5.0), 5)).episodes
    assert [e.status for e in other] == ["not_replayable"] * 2 + ["identical"] * 2  # (0 steps)
    assert other[0].reason is not None and other[0].reason.endswith(f"{_UNVERIFIED}{_NO_SPEC}")


def test_a_recording_without_a_spec_holds_no_wrappers_to_compare(tmp_path: Path) -> None:
    """Its wrappers are not recorded: a factory's gym.make env with them is not said to differ."""
    path = _record(tmp_path / "pendulum.mcap", ClipAction(TimeLimit(PendulumEnv(), 10)))
    made = _verdicts(path, lambda: ClipAction(gym.make("Pendulum-v1", max_episode_steps=10)))
    assert made == {("identical", None)}


def test_a_factory_env_that_is_not_the_class_recorded_without_a_spec_does_not_match(
    tmp_path: Path,
) -> None:
    """The run names the class the recorder wrapped (``reward_terms.info_of``)."""
    path = _record(tmp_path / "cartpole.mcap", CartPoleEnv())
    assert _verdicts(path, CartPoleEnv) == {("identical", None)}
    assert _verdicts(path, lambda: gym.make("CartPole-v1")) == {("identical", None)}
    assert _verdicts(path, _Copy) == {
        (
            "not_replayable",
            "the rebuilt env does not match the recording: the recorder wrapped "
            '"gymnasium.envs.classic_control.cartpole:CartPoleEnv" (the recording holds no env '
            f'spec), which the rebuilt env ("{__name__}:_Copy") neither is nor wraps; make the '
            "--env-factory build the env as recorded",
        )
    }


def _pong(skip: int) -> gym.Env[Any, Any]:
    """Pong (its RAM) in SB3's Atari wrappers, which record no arguments."""
    ale_py = pytest.importorskip("ale_py")
    wrappers = pytest.importorskip("stable_baselines3.common.atari_wrappers")
    gym.register_envs(ale_py)
    env = gym.make("PongNoFrameskip-v4", obs_type="ram", max_episode_steps=100)
    env = wrappers.MaxAndSkipEnv(wrappers.NoopResetEnv(env, noop_max=5), skip=skip)
    return wrappers.ClipRewardEnv(env)


def test_wrappers_that_record_no_arguments_and_differ_are_not_replayable(tmp_path: Path) -> None:
    path = _record(tmp_path / "pong.mcap", _pong(skip=4), steps=5)
    assert _verdicts(path, lambda: _pong(skip=4)) == {("identical", None)}
    other = replay([path], env_factory=lambda: _pong(skip=2)).episodes
    assert [e.status for e in other] == ["not_replayable"] * 2
    assert other[0].reason == (
        f"differed at step 0 (observation) {_UNVERIFIED}the arguments of wrapper(s) "
        "NoopResetEnv, MaxAndSkipEnv are not recorded (they do not derive from "
        "gymnasium.utils.RecordConstructorArgs), so the rebuilt ones' cannot be compared with "
        "the recording's"
    )
