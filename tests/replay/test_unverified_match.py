"""An env factory's env whose match with the recording cannot be verified (replay/mismatch.py).

A factory's env without a spec (built by its class, not ``gym.make``) and wrappers that record
no arguments (SB3's Atari wrappers) cannot be held to the recorded arguments: built otherwise,
they differ with nothing wrong. Nor can any factory's env be held to a recording that holds no
spec (its env was not made with ``gym.make``). An episode that differs in such an env is
``not_replayable`` naming why, never ``diverged``; one that replays the same is ``identical``.
Without a spec, a class that is not the recorded entry point's (or, with no recorded spec, not
the class the recorder wrapped) does not match. A PettingZoo factory's env cannot be held to
the recorded ``env_kwargs``: unverified in the same way, unless its name or PettingZoo module
is not the recorded one.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.envs.classic_control.pendulum import PendulumEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.wrappers import ClipAction, TimeLimit

from episode_audit import (
    RecordAECEvidence,
    RecordEvidence,
    RecordParallelEvidence,
    RecordVectorEvidence,
    replay,
)
from tests.support.walk_game import WalkGame

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
    assert [e.unverified for e in other.episodes] == [_NO_SPEC] * 2
    assert other.to_dict()["episodes"][0]["unverified"] == _NO_SPEC
    assert {
        e.unverified
        for e in replay([path], env_factory=lambda: TimeLimit(HalfCheetahEnv(), 10)).episodes
    } == {None}


def test_a_vector_recording_without_a_spec_that_differs_is_not_replayable(tmp_path: Path) -> None:
    path = tmp_path / "pendulums.mcap"
    envs = gym.vector.SyncVectorEnv([lambda: TimeLimit(PendulumEnv(), 5)] * 2)
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=0)
        for _ in range(6):
            rec.step(rec.action_space.sample())
    assert _verdicts(path, lambda: TimeLimit(PendulumEnv(), 5)) == {("identical", None)}
    other = replay([path], env_factory=lambda: TimeLimit(PendulumEnv(g=5.0), 5)).episodes
    assert [e.status for e in other] == ["not_replayable"] * 2  # (and 2 unstarted, apart)
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


class _Scale(gym.RewardWrapper[Any, Any], gym.utils.RecordConstructorArgs):
    """Rewards times ``k``, its arguments recorded in the spec."""

    def __init__(self, env: gym.Env[Any, Any], k: float = 1.0) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, k=k)
        gym.RewardWrapper.__init__(self, env)
        self.k = k

    def reward(self, reward: SupportsFloat) -> float:
        return self.k * float(reward)


class _ScaleUnrecorded(gym.RewardWrapper[Any, Any]):
    """The same wrapper in another release, which records no arguments (``kwargs`` null)."""

    def __init__(self, env: gym.Env[Any, Any], k: float = 1.0) -> None:
        super().__init__(env)
        self.k = k

    def reward(self, reward: SupportsFloat) -> float:
        return self.k * float(reward)


_ScaleUnrecorded.__name__ = _ScaleUnrecorded.__qualname__ = "_Scale"  # (its entry point)


@pytest.mark.parametrize("recorded", [_Scale, _ScaleUnrecorded], ids=["kwargs", "null"])
def test_wrapper_arguments_recorded_on_one_side_only_are_unverified(
    tmp_path: Path, recorded: Callable[..., gym.Env[Any, Any]]
) -> None:
    """Not a mismatch: what one side did not record cannot be compared with the other's."""
    path = _record(tmp_path / "cartpole.mcap", recorded(gym.make("CartPole-v1"), k=2.0))
    rebuilt = _ScaleUnrecorded if recorded is _Scale else _Scale
    same = _verdicts(path, lambda: rebuilt(gym.make("CartPole-v1"), k=2.0))
    assert same == {("identical", None)}
    other = replay([path], env_factory=lambda: rebuilt(gym.make("CartPole-v1"), k=3.0)).episodes
    assert [e.status for e in other] == ["not_replayable"] * 2
    assert other[0].reason == (
        f"differed at step 0 (reward) {_UNVERIFIED}the arguments of wrapper(s) _Scale are not "
        "recorded (they do not derive from gymnasium.utils.RecordConstructorArgs), so the "
        "rebuilt ones' cannot be compared with the recording's"
    )


# --------------------------------------------------------------------------------------------
# PettingZoo: what a game's layout records of its env (env_name, env_module, env_kwargs)
# --------------------------------------------------------------------------------------------


def _pistonball(**kwargs: Any) -> Any:
    """Four pistons, five cycles: each cycle pays every piston ``time_penalty`` and its move."""
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
        warnings.simplefilter("ignore", DeprecationWarning)
        pistonball = pytest.importorskip("pettingzoo.butterfly.pistonball_v6")
    return pistonball.parallel_env(n_pistons=4, max_cycles=5, **kwargs)


def _record_game(path: Path, env: Any, env_kwargs: dict[str, Any] | None) -> Path:
    """Two games (seeds 0 and 1), every agent taking its action space's first sample."""
    with RecordParallelEvidence(env, path, env_kwargs=env_kwargs) as game:
        for seed in (0, 1):
            game.reset(seed=seed)
            while game.agents:
                game.step({a: game.action_space(a).sample() * 0 for a in game.agents})
    return path


def _clipped(low: Any) -> gym.Env[Any, Any]:
    """Pendulum (rewards in [-16.3, 0]) with its rewards clipped below at ``low``."""
    return gym.wrappers.ClipReward(gym.make("Pendulum-v1", max_episode_steps=10), min_reward=low)


def test_a_wrapper_argument_held_only_as_a_placeholder_is_unverified(tmp_path: Path) -> None:
    """``np.float32(-2.0)`` is not JSON: the file keeps its placeholder, its type only. Against
    a plain ``-2.0`` (or another float32) nothing says whether the values differ: the env's
    match is unverified, not a difference; an episode that differs is not ``diverged``."""
    path = _record(tmp_path / "clipped.mcap", _clipped(np.float32(-2.0)))
    assert _verdicts(path, lambda: _clipped(-2.0)) == {("identical", None)}
    assert _verdicts(path, lambda: _clipped(np.float32(-2.0))) == {("identical", None)}
    held = '{"episode_audit.unrecorded": "float32"}'
    for rebuilt, shown in ((-1.0, "-1.0"), (np.float32(-1.0), held)):
        cause = (
            f"ClipReward's argument 'min_reward' {held} recorded vs {shown} rebuilt, and a "
            "placeholder (a value JSON cannot hold) keeps only its type"
        )
        other = replay([path], env_factory=lambda low=rebuilt: _clipped(low)).episodes
        assert [e.status for e in other] == ["not_replayable"] * 2
        assert [e.unverified for e in other] == [cause] * 2
        assert other[0].reason is not None
        assert other[0].reason.endswith(f"(reward) {_UNVERIFIED}{cause}")


def test_a_factory_game_env_that_differs_is_not_replayable(tmp_path: Path) -> None:
    """The factory's constructor arguments cannot be compared with the recorded env_kwargs."""
    kwargs = {"n_pistons": 4, "max_cycles": 5}
    path = _record_game(tmp_path / "pistons.mcap", _pistonball(), kwargs)
    assert _verdicts(path, _pistonball) == {("identical", None)}
    assert {e.status for e in replay([path]).episodes} == {"identical"}  # (from env_kwargs)
    other = replay([path], env_factory=lambda: _pistonball(time_penalty=-0.5)).episodes
    assert [e.status for e in other] == ["not_replayable"] * 8
    assert all(e.divergence is not None for e in other)  # (its difference kept)
    assert other[0].reason == (
        f"differed at step 0 (reward) {_UNVERIFIED}the env factory's env cannot be verified to "
        'be built with the recorded env_kwargs {"max_cycles": 5, "n_pistons": 4}; replay '
        "without --env-factory to build it with them"
    )


def test_a_factory_game_env_of_a_recording_without_env_kwargs_is_unverified(
    tmp_path: Path,
) -> None:
    path = _record_game(tmp_path / "pistons.mcap", _pistonball(), None)
    other = replay([path], env_factory=lambda: _pistonball(time_penalty=-0.5)).episodes
    assert {e.status for e in other} == {"not_replayable"}
    assert other[0].reason is not None and other[0].reason.endswith(
        f"{_UNVERIFIED}the recording holds no env_kwargs (the env's constructor arguments, "
        "which the recorder takes as env_kwargs=) to verify the env factory's env against; "
        "record with them"
    )


def _three_cycles(path: Path, **kwargs: Any) -> Path:
    """Three cycles of pistonball (20 pistons) with ``kwargs``, recorded without env_kwargs=."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.butterfly import pistonball_v6

        env = pistonball_v6.parallel_env(**kwargs)
    with RecordParallelEvidence(env, path) as game:
        game.reset(seed=0)
        for _ in range(3):
            game.step({a: game.action_space(a).sample() * 0 for a in game.agents})
    return path


def test_a_game_env_rebuilt_with_its_defaults_without_env_kwargs_is_unverified(
    tmp_path: Path,
) -> None:
    """Recorded without env_kwargs=, replay builds pistonball with its defaults: a recording
    of ``time_penalty=-0.5`` said ``diverged``; one made with its defaults is identical."""
    path = _three_cycles(tmp_path / "pistons.mcap", time_penalty=-0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        other = replay([path]).episodes
        same = replay([_three_cycles(tmp_path / "defaults.mcap")]).episodes
    assert {e.status for e in other} == {"not_replayable"}
    assert all(e.divergence is not None for e in other)  # (its difference kept)
    assert other[0].reason is not None and other[0].reason.endswith(
        f"{_UNVERIFIED}the recording holds no env_kwargs (the env's constructor arguments, "
        "which the recorder takes as env_kwargs=): the env was rebuilt with its defaults, "
        "which may not be the recorded env's; record with env_kwargs= (env_kwargs={} for the "
        "defaults)"
    )
    assert {e.status for e in same} == {"identical"}


class _WalkGameV1(WalkGame):
    """The next version of the walk game."""

    metadata: dict[str, Any] = {"name": "walk_game_v1"}


def test_a_factory_game_env_of_another_name_does_not_match(tmp_path: Path) -> None:
    path = _record_game(tmp_path / "walk.mcap", WalkGame(max_cycles=4), {"max_cycles": 4})
    assert _verdicts(path, lambda: WalkGame(max_cycles=4)) == {("identical", None)}
    assert _verdicts(path, lambda: _WalkGameV1(max_cycles=4)) == {
        (
            "not_replayable",
            'the rebuilt env does not match the recording: env name "walk_game_v0" recorded vs '
            '"walk_game_v1" rebuilt; make the --env-factory build the env as recorded',
        )
    }


def test_a_factory_game_env_of_another_pettingzoo_module_does_not_match(tmp_path: Path) -> None:
    """(Tic-tac-toe and connect four: the same agents; the env module is the first difference.)"""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import connect_four_v3, tictactoe_v3
    path = tmp_path / "ttt.mcap"
    with RecordAECEvidence(tictactoe_v3.env(), path) as game:
        game.reset(seed=0)
        for agent in game.agent_iter():
            _, _, terminated, truncated, _ = game.last()
            mask = game.observe(agent)["action_mask"]
            game.step(None if terminated or truncated else int(mask.argmax()))
    assert _verdicts(path, connect_four_v3.env) == {
        (
            "not_replayable",
            "the rebuilt env does not match the recording: env module "
            '"pettingzoo.classic.tictactoe_v3" recorded vs "pettingzoo.classic.connect_four_v3" '
            "rebuilt; make the --env-factory build the env as recorded",
        )
    }
