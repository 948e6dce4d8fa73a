"""Where the recorder sits: the reward-changing wrappers under it are recorded and named.

A CleanRL-style ``SyncVectorEnv`` loop on Reacher-v5 (whose info holds ``reward_dist`` and
``reward_ctrl``, the reward being their sum): with ``NormalizeReward`` (and ``TransformReward``)
inside each sub-env, under the recorder, the file holds their rewards and the env's terms:
``check`` does not hold the terms against those rewards (no ``terms_sum_mismatch``), and its
``rewards_changed`` note names the wrappers and says so; with a vector ``NormalizeReward`` over
the recorder, the file holds the env's own rewards and checks clean.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.check import Finding, check
from episode_audit.format.wrappers import LAYOUT_REWARD_WRAPPERS

NORMALIZE = "gymnasium.wrappers.stateful_reward:NormalizeReward"
TRANSFORM = "gymnasium.wrappers.transform_reward:TransformReward"


def cleanrl_env(normalize_reward: bool) -> gym.Env[Any, Any]:
    """CleanRL's continuous-control stack (ppo_continuous_action.py), on Reacher-v5."""
    env = gym.make("Reacher-v5", max_episode_steps=20)
    env = gym.wrappers.FlattenObservation(env)
    env = gym.wrappers.RecordEpisodeStatistics(env)
    env = gym.wrappers.ClipAction(env)
    if normalize_reward:
        env = gym.wrappers.NormalizeReward(env, gamma=0.99)
        env = gym.wrappers.TransformReward(env, lambda r: float(np.clip(r, -10, 10)))
    return env


def run_loop(envs: gym.vector.VectorEnv[Any, Any, Any], steps: int = 60) -> None:
    envs.action_space.seed(0)
    envs.reset(seed=0)
    for _ in range(steps):
        envs.step(envs.action_space.sample())
    envs.close()


def mismatches(path: Path) -> list[str]:
    return [f.message for f in check([path]).findings if f.code == "terms_sum_mismatch"]


def unchecked(path: Path, wrappers: str, it: str = "it") -> Finding:
    """The file's ``rewards_changed`` note, which says its terms were not checked; no mismatch."""
    result = check([path])
    assert "terms_sum_mismatch" not in {f.code for f in result.findings}, result.findings
    (found,) = [f for f in result.findings if f.code == "rewards_changed"]
    assert (found.severity, found.episode, found.step) == ("note", None, None)
    assert re.fullmatch(
        rf"the recorded rewards and returns are {wrappers}'s, not the env's: the recorder sat "
        rf"over {it}; the reward terms of \d+ step\(s\) were not checked against these rewards, "
        r"the terms being the env's \(the wrappers change the reward, not its terms\): record "
        rf"beneath {it} \(innermost\) for the env's own rewards, checked against their terms",
        found.message,
    ), found.message
    return found


def test_normalize_reward_under_the_recorder_leaves_the_terms_unchecked(tmp_path: Path) -> None:
    """The env's terms sum to the env's reward, not to the wrappers': no terms_sum_mismatch
    (one error per episode before), the note says why the terms were not checked."""
    path = tmp_path / "below.mcap"
    sync = gym.vector.SyncVectorEnv([lambda: cleanrl_env(True)] * 2)
    envs = RecordVectorEvidence(sync, path)  # (NormalizeReward's state is snapshot: no warning)
    run_loop(envs)
    run = open_evidence(path).run
    assert run.layout[LAYOUT_REWARD_WRAPPERS] == [NORMALIZE, TRANSFORM]
    found = unchecked(path, "NormalizeReward, TransformReward", "them")
    assert f"of {open_evidence(path).steps().num_rows} step(s)" in found.message  # each has terms
    assert not [f for f in check([path]).findings if f.severity == "error"]
    # whose info: the user's outermost wrapper, not the recorder's own ResetRngInfo over it
    assert run.reward_terms["info_of"] == TRANSFORM


def test_vector_normalize_reward_over_the_recorder_checks_clean(tmp_path: Path) -> None:
    path = tmp_path / "above.mcap"
    sync = gym.vector.SyncVectorEnv([lambda: cleanrl_env(False)] * 2)
    envs = gym.wrappers.vector.NormalizeReward(RecordVectorEvidence(sync, path), gamma=0.99)
    run_loop(envs)
    run = open_evidence(path).run
    assert LAYOUT_REWARD_WRAPPERS not in run.layout
    result = check([path])
    assert not [f for f in result.findings if f.severity != "note"], result.findings
    assert "missing_terms" not in {f.code for f in result.findings}  # terms were checked


def test_a_vector_reward_wrapper_under_the_recorder_is_named(tmp_path: Path) -> None:
    path = tmp_path / "vector-below.mcap"
    sync = gym.vector.SyncVectorEnv([lambda: cleanrl_env(False)] * 2)
    scaled = gym.wrappers.vector.TransformReward(sync, lambda r: r * 2.0)
    with pytest.warns(UserWarning, match="TransformReward"):
        envs = RecordVectorEvidence(scaled, path)
    run_loop(envs)
    assert open_evidence(path).run.layout[LAYOUT_REWARD_WRAPPERS] == [
        "gymnasium.wrappers.vector.vectorize_reward:TransformReward"
    ]
    unchecked(path, "TransformReward")


def test_single_env_recorder_names_clip_reward_and_whose_info_it_read(tmp_path: Path) -> None:
    path = tmp_path / "clip.mcap"
    env = gym.wrappers.ClipReward(gym.make("Reacher-v5", max_episode_steps=20), -0.05, 0.0)
    with RecordEvidence(env, path) as recorded:
        recorded.action_space.seed(0)
        recorded.reset(seed=0)
        for _ in range(20):
            recorded.step(recorded.action_space.sample())
    run = open_evidence(path).run
    assert run.layout[LAYOUT_REWARD_WRAPPERS] == ["gymnasium.wrappers.transform_reward:ClipReward"]
    assert run.reward_terms["info_of"] == "gymnasium.wrappers.transform_reward:ClipReward"
    unchecked(path, "ClipReward")


def test_no_reward_wrapper_records_no_key_and_names_the_env(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    with RecordEvidence(gym.make("Reacher-v5", max_episode_steps=5), path) as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())
    run = open_evidence(path).run
    assert LAYOUT_REWARD_WRAPPERS not in run.layout
    assert run.reward_terms["info_of"] == "gymnasium.wrappers.common:TimeLimit"
    assert not mismatches(path)


def test_normalize_reward_under_the_recorder_of_an_env_without_terms_is_noted(
    tmp_path: Path,
) -> None:
    """CartPole reports no terms, so no terms_sum_mismatch: its returns (6.7 for episodes of
    23 steps) read as the env's, and check said nothing of the wrapper."""
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.wrappers.NormalizeReward(gym.make("CartPole-v1")), path) as env:
        env.action_space.seed(0)
        for seed in range(3):
            env.reset(seed=seed)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
    result = check([path])
    (found,) = [f for f in result.findings if f.code == "rewards_changed"]
    assert (found.severity, found.episode, found.step) == ("note", None, None)
    assert found.message == (
        "the recorded rewards and returns are NormalizeReward's, not the env's: the recorder "
        "sat over it; record beneath it (innermost) for the env's own"
    )
    plain = tmp_path / "plain.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), plain) as env:
        env.reset(seed=0)
        env.step(0)
    assert "rewards_changed" not in {f.code for f in check([plain]).findings}
