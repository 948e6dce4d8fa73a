"""Wrappers a user declares transparent (``transparent_wrappers=``): replay leaves them out.

A real user wrapper class, defined here, that only counts steps: declared, its episodes replay
identical without it and replay says so; undeclared, they are not replayable (replay does not
know it). Declaring a wrapper that does change steps cannot forge a verdict: replay diverges.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import pytest

from episode_audit import RecordEvidence, open_evidence, replay
from episode_audit.errors import ConfigurationError

ENTRY = f"{__name__}:StepLogger"


class StepLogger(gym.Wrapper[Any, Any, Any, Any], gym.utils.RecordConstructorArgs):
    """Counts steps (a user's logging wrapper): never changes one."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.steps = 0

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        self.steps += 1
        return self.env.step(action)


class Doubler(gym.Wrapper[Any, Any, Any, Any], gym.utils.RecordConstructorArgs):
    """Doubles the reward: declaring it transparent is a mistake replay catches."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(reward) * 2.0, terminated, truncated, info


def record(path: Path, wrapper: type[gym.Wrapper[Any, Any, Any, Any]], **options: Any) -> Path:
    env = wrapper(gym.make("CartPole-v1", max_episode_steps=15))
    with RecordEvidence(env, path, **options) as recorded:
        for seed in (1, 2):
            recorded.reset(seed=seed)
            for t in range(15):
                _, _, terminated, truncated, _ = recorded.step(t % 2)
                if terminated or truncated:
                    break
    return path


@pytest.mark.parametrize("declared", [StepLogger, ENTRY])
def test_a_declared_wrapper_is_left_out_and_replay_says_so(tmp_path: Path, declared: Any) -> None:
    path = record(tmp_path / "run.mcap", StepLogger, transparent_wrappers=[declared])
    assert open_evidence(path).run.recorder["transparent_wrappers"] == [ENTRY]
    result = replay([path])
    assert [e.status for e in result.episodes] == ["identical", "identical"]
    notes = [n for ns in result.notes.values() for n in ns]
    assert any("without the recorded wrapper StepLogger" in n and "declared" in n for n in notes)


def test_an_undeclared_user_wrapper_is_not_replayable(tmp_path: Path) -> None:
    path = record(tmp_path / "run.mcap", StepLogger)
    assert "transparent_wrappers" not in open_evidence(path).run.recorder
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert all("StepLogger" in (e.reason or "") for e in result.episodes)
    assert (result.episodes[0].reason or "").endswith(  # (trusted, it is built as recorded)
        "; pass --env-factory MODULE:CALLABLE that builds the env, or --trust-entry-points to "
        "build the recorded wrappers as they are"
    )


def test_a_wrapper_declared_transparent_that_changes_steps_diverges(tmp_path: Path) -> None:
    path = record(tmp_path / "run.mcap", Doubler, transparent_wrappers=[Doubler])
    result = replay([path])
    assert {e.status for e in result.episodes} == {"diverged"}


def test_a_known_wrapper_keeps_its_rule(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    env = gym.wrappers.NormalizeObservation(gym.make("CartPole-v1", max_episode_steps=5))
    declared = ["gymnasium.wrappers.stateful_observation:NormalizeObservation"]
    with RecordEvidence(env, path, transparent_wrappers=declared) as recorded:
        recorded.reset(seed=0)
        recorded.step(0)
    result = replay([path])
    # rebuilt, its state restored from the snapshot (its rule), not left out as declared
    assert {e.status for e in result.episodes} == {"identical"}
    assert not any("NormalizeObservation" in n for ns in result.notes.values() for n in ns)


@pytest.mark.parametrize("bad", ["no_colon", 3, "a:b c"])
def test_a_bad_declaration_is_refused(tmp_path: Path, bad: Any) -> None:
    env = gym.make("CartPole-v1")
    with pytest.raises(ConfigurationError, match="transparent_wrappers: expected wrapper classes"):
        RecordEvidence(env, tmp_path / "run.mcap", transparent_wrappers=[bad])
    assert not (tmp_path / "run.mcap").exists()
