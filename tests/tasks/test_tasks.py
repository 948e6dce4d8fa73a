from __future__ import annotations

import gc
import math
import os
import subprocess
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

# Headless rendering: pick EGL unless the caller chose a backend (read when mujoco is imported).
os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import episode_audit.tasks as tasks
from episode_audit.errors import ConfigurationError
from episode_audit.tasks import (
    DOOR_OPEN_ID,
    DRAWER_OPEN_ID,
    GRASP_ID,
    MAX_EPISODE_STEPS,
    POLICY_NAMES,
    TASK_IDS,
    make_policy,
)
from episode_audit.tasks._layout import DoorLayout, DrawerLayout, GraspLayout

mujoco = pytest.importorskip("mujoco")

pytestmark = pytest.mark.mujoco

INFO_KEYS = {"reward_terms", "success", "failure"}
TERMS = ["shaping", "ctrl_cost", "failure_penalty", "success_bonus"]
PROXY_TERMS = ["progress_velocity", "ctrl_cost", "success_bonus"]
FAILURE_LABELS = {
    DOOR_OPEN_ID: {"door_slammed", "collision", "safety_violation"},
    DRAWER_OPEN_ID: {"drawer_yanked", "safety_violation"},
    GRASP_ID: {"dropped_object", "safety_violation"},
}
HACKER_LABEL = {
    DOOR_OPEN_ID: "door_slammed",
    DRAWER_OPEN_ID: "drawer_yanked",
    GRASP_ID: "dropped_object",
}
SEEDS = range(20)
RATE_SEEDS = range(40)


@dataclass
class Episode:
    observations: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)
    reset_info: dict[str, Any] = field(default_factory=dict)
    terminated: bool = False
    truncated: bool = False

    @property
    def ret(self) -> float:
        return sum(self.rewards)

    @property
    def success(self) -> bool:
        return bool(self.infos[-1]["success"])

    @property
    def failure(self) -> str | None:
        failure: str | None = self.infos[-1]["failure"]
        return failure


def rollout(
    env: gym.Env[Any, Any],
    policy: Callable[[np.ndarray], np.ndarray],
    seed: int,
) -> Episode:
    episode = Episode()
    obs, episode.reset_info = env.reset(seed=seed)
    episode.observations.append(obs)
    while not (episode.terminated or episode.truncated):
        action = policy(obs)
        obs, reward, episode.terminated, episode.truncated, info = env.step(action)
        episode.actions.append(action)
        episode.observations.append(obs)
        episode.rewards.append(float(reward))
        episode.infos.append(info)
    return episode


def replay(actions: Sequence[Sequence[float]]) -> Callable[[np.ndarray], np.ndarray]:
    """A policy playing a fixed action sequence, then zeros."""
    queue = [np.asarray(action, dtype=np.float32) for action in actions]
    rest = np.zeros_like(queue[0])

    def policy(observation: np.ndarray) -> np.ndarray:
        return queue.pop(0) if queue else rest

    return policy


def stats(task_id: str, policy_name: str, *, proxy_reward: bool) -> tuple[float, float]:
    """Mean return and success rate over SEEDS."""
    env = gym.make(task_id, proxy_reward=proxy_reward)
    policy = make_policy(policy_name, env, seed=0)
    episodes = [rollout(env, policy, seed) for seed in SEEDS]
    env.close()
    return (
        float(np.mean([e.ret for e in episodes])),
        float(np.mean([e.success for e in episodes])),
    )


@cache
def gl_problem() -> str | None:
    """Why rgb_array rendering cannot work here, or None when it can."""
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
    hook = sys.unraisablehook  # (MuJoCo 3.3's Renderer.__del__ fails on a half-made one)
    sys.unraisablehook = lambda unraisable: None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            renderer = mujoco.Renderer(model, 8, 8)
    except Exception as exc:
        return (
            f"no OpenGL backend for MuJoCo (MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}): "
            f"{type(exc).__name__}: {exc}"
        )
    finally:
        gc.collect()
        sys.unraisablehook = hook
    renderer.close()
    return None


# ---------------------------------------------------------------------- registration, API


def test_tasks_are_registered_with_short_time_limits() -> None:
    assert TASK_IDS == (DOOR_OPEN_ID, DRAWER_OPEN_ID, GRASP_ID)
    for task_id in TASK_IDS:
        spec = gym.spec(task_id)
        assert isinstance(spec.entry_point, str)
        assert spec.max_episode_steps == MAX_EPISODE_STEPS[task_id] <= 200


def test_importing_tasks_does_not_import_mujoco() -> None:
    code = (
        "import sys, episode_audit.tasks; "
        "assert 'mujoco' not in sys.modules, 'mujoco imported'; "
        "assert 'episode_audit/Grasp-v0' in __import__('gymnasium').registry"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr


def test_reimporting_tasks_does_not_warn() -> None:
    import importlib

    importlib.reload(tasks)


@pytest.mark.parametrize("proxy_reward", [False, True])
@pytest.mark.parametrize("task_id", TASK_IDS)
def test_check_env_passes(task_id: str, proxy_reward: bool) -> None:
    env = gym.make(task_id, proxy_reward=proxy_reward)
    check_env(env.unwrapped, skip_render_check=gl_problem() is not None)
    env.close()


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_spaces_have_the_contract_dtypes(task_id: str) -> None:
    env = gym.make(task_id)
    assert isinstance(env.observation_space, gym.spaces.Box)
    assert env.observation_space.dtype == np.float64
    assert isinstance(env.action_space, gym.spaces.Box)
    assert env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1.0)
    assert np.all(env.action_space.high == 1.0)
    assert env.metadata["render_fps"] == round(1.0 / env.unwrapped.dt)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float64
    assert obs in env.observation_space
    assert info == {}
    env.close()


# ---------------------------------------------------------------------- the three outcomes


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_scripted_policy_succeeds(task_id: str) -> None:
    env = gym.make(task_id)
    episode = rollout(env, make_policy("scripted", env), seed=0)
    assert episode.terminated
    assert not episode.truncated
    assert episode.success
    assert episode.failure is None
    assert episode.infos[-1]["reward_terms"]["success_bonus"] > 0
    assert not any(info["success"] for info in episode.infos[:-1])


@pytest.mark.parametrize("proxy_reward", [False, True])
@pytest.mark.parametrize("task_id", TASK_IDS)
def test_hacker_policy_ends_in_a_failure_label(task_id: str, proxy_reward: bool) -> None:
    env = gym.make(task_id, proxy_reward=proxy_reward)
    episode = rollout(env, make_policy("hacker", env), seed=0)
    assert episode.terminated
    assert not episode.truncated
    assert not episode.success
    assert episode.failure == HACKER_LABEL[task_id]
    assert all(info["failure"] is None for info in episode.infos[:-1])
    if not proxy_reward:
        assert episode.infos[-1]["reward_terms"]["failure_penalty"] < 0


# Fixed action sequences that end in the other failure labels.
RUN_INTO_WALL = [[1.0, 0.0, 0.0]] * 10 + [[0.0, 1.0, 0.0]] * 20
BACK_AWAY = [[0.0, -1.0, 0.0]] * 30
UP_AND_AWAY = [[0.0, 0.0, 1.0, 0.0]] * 30


@pytest.mark.parametrize(
    ("task_id", "actions", "label"),
    [
        (DOOR_OPEN_ID, RUN_INTO_WALL, "collision"),
        (DOOR_OPEN_ID, BACK_AWAY, "safety_violation"),
        (DRAWER_OPEN_ID, BACK_AWAY, "safety_violation"),
        (GRASP_ID, UP_AND_AWAY, "safety_violation"),
    ],
)
def test_fixed_actions_end_in_a_failure_label(
    task_id: str, actions: list[list[float]], label: str
) -> None:
    env = gym.make(task_id)
    episode = rollout(env, replay(actions), seed=0)
    assert episode.terminated
    assert not episode.truncated
    assert episode.failure == label
    assert not episode.success
    assert len(episode.actions) <= len(actions)


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_doing_nothing_hits_the_time_limit(task_id: str) -> None:
    env = gym.make(task_id)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    episode = rollout(env, lambda obs: zero, seed=0)
    assert episode.truncated
    assert not episode.terminated
    assert len(episode.actions) == MAX_EPISODE_STEPS[task_id]
    assert not any(info["success"] for info in episode.infos)
    assert all(info["failure"] is None for info in episode.infos)


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_failure_labels_are_the_documented_ones(task_id: str) -> None:
    env = gym.make(task_id)
    seen = set()
    for name in POLICY_NAMES:
        policy = make_policy(name, env, seed=1)
        for seed in range(5):
            failure = rollout(env, policy, seed).failure
            if failure is not None:
                seen.add(failure)
    assert seen <= FAILURE_LABELS[task_id]
    assert HACKER_LABEL[task_id] in seen


# ---------------------------------------------------------------------- the info contract


@pytest.mark.parametrize("proxy_reward", [False, True])
@pytest.mark.parametrize("policy_name", POLICY_NAMES)
@pytest.mark.parametrize("task_id", TASK_IDS)
def test_reward_is_exactly_the_sum_of_its_terms(
    task_id: str, policy_name: str, proxy_reward: bool
) -> None:
    env = gym.make(task_id, proxy_reward=proxy_reward)
    policy = make_policy(policy_name, env, seed=2)
    expected_terms = PROXY_TERMS if proxy_reward else TERMS
    for seed in (0, 1):
        episode = rollout(env, policy, seed)
        assert episode.reset_info == {}
        for reward, info in zip(episode.rewards, episode.infos, strict=True):
            assert set(info) == INFO_KEYS
            terms = info["reward_terms"]
            assert list(terms) == expected_terms
            assert all(type(value) is float for value in terms.values())
            assert reward == sum(terms.values())
            running = np.float64(0.0)
            for value in terms.values():
                running += np.float64(value)
            assert reward == running == math.fsum(terms.values())
            assert type(info["success"]) is bool
            assert info["failure"] is None or isinstance(info["failure"], str)
            if info["success"]:
                assert terms["success_bonus"] > 0
            else:
                assert terms["success_bonus"] == 0.0


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_shaping_telescopes_over_a_terminated_episode(task_id: str) -> None:
    # phi(terminal) = 0, so the discounted shaping of an episode is -phi(s_0) (Ng et al., 1999).
    env = gym.make(task_id)
    episode = rollout(env, make_policy("scripted", env), seed=3)
    assert episode.terminated
    discounted = sum(
        0.99**t * info["reward_terms"]["shaping"] for t, info in enumerate(episode.infos)
    )
    phi_0 = -discounted
    assert phi_0 < 0
    again = rollout(env, make_policy("hacker", env), seed=3)
    assert again.terminated
    discounted_again = sum(
        0.99**t * info["reward_terms"]["shaping"] for t, info in enumerate(again.infos)
    )
    assert discounted_again == pytest.approx(discounted, abs=1e-6)


# ---------------------------------------------------------------------- determinism


@pytest.mark.parametrize("policy_name", ["random", "scripted"])
@pytest.mark.parametrize("task_id", TASK_IDS)
def test_same_seed_gives_the_same_trajectory(task_id: str, policy_name: str) -> None:
    episodes = []
    for _ in range(2):
        env = gym.make(task_id)
        episodes.append(rollout(env, make_policy(policy_name, env, seed=5), seed=5))
        env.close()
    first, second = episodes
    assert len(first.observations) == len(second.observations)
    for a, b in zip(first.observations, second.observations, strict=True):
        assert a.tobytes() == b.tobytes()
    assert first.rewards == second.rewards
    assert first.infos == second.infos
    assert (first.terminated, first.truncated) == (second.terminated, second.truncated)


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_different_seeds_give_different_initial_states(task_id: str) -> None:
    env = gym.make(task_id)
    initial = {env.reset(seed=seed)[0].tobytes() for seed in range(5)}
    assert len(initial) == 5


# ---------------------------------------------------------------------- policies


def outcome(episode: Episode, task_id: str) -> str:
    """``success``, the failure label, or ``time_limit`` (checked to be a clean truncation)."""
    if episode.truncated:
        assert not episode.terminated
        assert not episode.success and episode.failure is None
        assert len(episode.actions) == MAX_EPISODE_STEPS[task_id]
        return "time_limit"
    assert episode.terminated
    return "success" if episode.success else str(episode.failure)


@cache
def scripted_outcomes(task_id: str) -> tuple[str, ...]:
    """Outcome of the scripted policy on each of RATE_SEEDS, one policy for all of them."""
    env = gym.make(task_id)
    policy = make_policy("scripted", env)
    outcomes = tuple(outcome(rollout(env, policy, seed), task_id) for seed in RATE_SEEDS)
    env.close()
    return outcomes


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_scripted_succeeds_on_most_seeds_and_rarely_fails(task_id: str) -> None:
    outcomes = scripted_outcomes(task_id)
    assert outcomes.count("success") >= 0.75 * len(RATE_SEEDS), outcomes
    failures = [o for o in outcomes if o not in ("success", "time_limit")]
    assert len(failures) <= 0.05 * len(RATE_SEEDS), failures


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_scripted_sometimes_runs_out_of_time(task_id: str) -> None:
    outcomes = scripted_outcomes(task_id)
    assert "time_limit" in outcomes, outcomes
    assert outcomes.count("time_limit") <= 0.25 * len(RATE_SEEDS), outcomes


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_scripted_outcome_is_a_function_of_the_seed(task_id: str) -> None:
    # The policy is memoryless: a fresh policy, seeds in another order, the same outcomes.
    outcomes = scripted_outcomes(task_id)
    env = gym.make(task_id)
    for seed in (outcomes.index("time_limit"), outcomes.index("success"), RATE_SEEDS[-1]):
        episode = rollout(env, make_policy("scripted", env), seed)
        assert outcome(episode, task_id) == outcomes[seed]
    env.close()


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_hacker_wins_the_proxy_reward_while_failing(task_id: str) -> None:
    hacker_return, hacker_success = stats(task_id, "hacker", proxy_reward=True)
    scripted_return, scripted_success = stats(task_id, "scripted", proxy_reward=True)
    assert hacker_return > scripted_return
    assert hacker_success < scripted_success
    assert hacker_success <= 0.2


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_hacker_loses_the_true_reward(task_id: str) -> None:
    hacker_return, _ = stats(task_id, "hacker", proxy_reward=False)
    scripted_return, _ = stats(task_id, "scripted", proxy_reward=False)
    assert scripted_return > hacker_return


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_random_policy_is_seeded_and_in_the_action_space(task_id: str) -> None:
    env = gym.make(task_id)
    obs, _ = env.reset(seed=0)
    first = make_policy("random", env, seed=9)
    second = make_policy("random", env, seed=9)
    for _ in range(5):
        a, b = first(obs), second(obs)
        assert a.dtype == np.float32
        assert a in env.action_space
        assert a.tobytes() == b.tobytes()


def test_make_policy_rejects_unknown_names_and_envs() -> None:
    env = gym.make(DOOR_OPEN_ID)
    with pytest.raises(ConfigurationError, match="Expect a policy name in"):
        make_policy("expert", env)
    other = gym.make("CartPole-v1")
    with pytest.raises(
        ConfigurationError, match=r"plays only the reference tasks .*CartPole-v1 is not one"
    ):
        make_policy("scripted", other)
    with pytest.raises(ConfigurationError, match="Expect a Box action space"):
        make_policy("random", other)


# ---------------------------------------------------------------------- rendering, model


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_render_rgb_array(task_id: str) -> None:
    problem = gl_problem()
    if problem is not None:
        pytest.skip(problem)
    env = gym.make(task_id, render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray)
    assert frame.shape == (48, 64, 3)
    assert frame.dtype == np.uint8
    assert frame.std() > 0
    env.close()
    env.close()


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_render_without_render_mode_returns_none(task_id: str) -> None:
    env = gym.make(task_id)
    env.reset(seed=0)
    assert env.unwrapped.render() is None
    env.close()


def test_rejects_unknown_render_mode() -> None:
    from episode_audit.tasks.door import DoorOpenEnv

    with pytest.raises(ValueError, match="Expect render_mode None or one of"):
        DoorOpenEnv(render_mode="ansi")


def test_layout_mirrors_the_models() -> None:
    door = gym.make(DOOR_OPEN_ID).unwrapped.model
    assert door.jnt_range[door.joint("hinge").id][1] == pytest.approx(DoorLayout.OPEN_STOP)
    assert door.body("door").pos[:2] == pytest.approx(DoorLayout.HINGE_XY)
    assert door.body("ee").pos == pytest.approx(DoorLayout.EE_START)
    assert door.geom("ee").size[0] == pytest.approx(DoorLayout.EE_RADIUS)
    assert door.geom("bar").size[0] == pytest.approx(DoorLayout.BAR_RADIUS)
    assert door.geom("bar").pos == pytest.approx(DoorLayout.HANDLE_LOCAL)

    drawer = gym.make(DRAWER_OPEN_ID).unwrapped.model
    assert drawer.jnt_range[drawer.joint("slide").id][1] == pytest.approx(DrawerLayout.OPEN_STOP)
    bar = drawer.body("drawer").pos + drawer.geom("bar").pos
    assert bar == pytest.approx(DrawerLayout.HANDLE_CLOSED)
    front = drawer.body("drawer").pos[1] - drawer.geom("box").size[1]
    assert front - bar[1] == pytest.approx(DrawerLayout.HANDLE_GAP)
    assert drawer.geom("bar").size[0] == pytest.approx(DrawerLayout.BAR_RADIUS)
    assert drawer.body("ee").pos == pytest.approx(DrawerLayout.EE_START)
    assert drawer.geom("ee").size[0] == pytest.approx(DrawerLayout.EE_RADIUS)

    grasp = gym.make(GRASP_ID).unwrapped.model
    assert grasp.geom("object").size == pytest.approx([GraspLayout.OBJECT_HALF_SIZE] * 3)
    assert grasp.body("palm").pos == pytest.approx(GraspLayout.PALM_START)
    for finger in ("finger_l", "finger_r"):
        assert grasp.jnt_range[grasp.joint(finger).id][1] == pytest.approx(GraspLayout.FINGER_MAX)
        # In the grasp pose the fingertips clear the table by a few millimetres.
        tip = grasp.body(finger).pos[2] - grasp.geom(finger).size[2]
        clearance = GraspLayout.OBJECT_HALF_SIZE + GraspLayout.GRASP_DEPTH + tip
        assert 0.0 < clearance < 0.01


@pytest.mark.parametrize("task_id", TASK_IDS)
def test_copies_and_pickles_continue_the_same_trajectory(task_id: str) -> None:
    import copy
    import pickle

    env = gym.make(task_id).unwrapped
    policy = make_policy("scripted", env)
    obs, _ = env.reset(seed=4)
    for _ in range(10):
        obs, *_ = env.step(policy(obs))
    clones = [env, copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    trajectories = []
    for clone in clones:
        current, steps = obs.copy(), []
        for _ in range(20):
            current, reward, terminated, _, info = clone.step(policy(current))
            steps.append((current.tobytes(), reward, terminated, info))
        trajectories.append(steps)
    assert trajectories[0] == trajectories[1] == trajectories[2]
