"""Replay restores each episode's state snapshot before its reset: stateful wrappers replay.

Every case here diverged, or was not replayable, before snapshots (see docs/replay.md): a
pre-warmed ``NormalizeObservation`` / ``NormalizeReward`` under the recorder, vector sub-envs
each in one, an unseeded ALE episode replayed alone. A wrapper whose state no adapter holds
still diverges, and says which state was restored.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit import (
    RecordEvidence,
    RecordVectorEvidence,
    ResetRngInfo,
    check,
    open_evidence,
    replay,
)
from episode_audit.record import state as state_module

EPISODES = 6


def _warmed(wrapper: Callable[[gym.Env[Any, Any]], gym.Env[Any, Any]]) -> gym.Env[Any, Any]:
    """CartPole in ``wrapper``, run for a few episodes first (as a trained agent's would be)."""
    env = wrapper(gym.make("CartPole-v1"))
    env.reset(seed=100)
    env.action_space.seed(100)
    for _ in range(300):
        if any(env.step(env.action_space.sample())[2:4]):
            env.reset()
    return env


def _record(env: gym.Env[Any, Any], path: Path) -> Path:
    """Six episodes, seeded and unseeded in turn, under the recorder (outermost)."""
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for ep in range(EPISODES):
            rec.reset(seed=ep if ep % 2 else None)
            while not any(rec.step(rec.action_space.sample())[2:4]):
                pass
    return path


def _statuses(path: Path, **kwargs: Any) -> list[tuple[str, str | None]]:
    return [(e.status, e.reason) for e in replay([path], **kwargs).episodes]


@pytest.mark.parametrize(
    "wrapper", [gym.wrappers.NormalizeObservation, gym.wrappers.NormalizeReward]
)
def test_a_prewarmed_normalize_wrapper_replays_identical_in_order_and_alone(
    tmp_path: Path, wrapper: Any
) -> None:
    path = _record(_warmed(wrapper), tmp_path / "warm.mcap")
    assert _statuses(path) == [("identical", None)] * EPISODES
    assert _statuses(path, episodes=[3]) == [("identical", None)]
    assert _statuses(path, episodes=[4, 2]) == [("identical", None)] * 2


def test_a_file_without_the_snapshots_is_not_replayable_naming_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # as a file recorded before snapshots existed: no adapter registered while recording
    monkeypatch.setattr(state_module, "_ADAPTERS", {})
    monkeypatch.setattr(state_module, "_BY_TYPE", {})
    with pytest.warns(UserWarning, match=r"NormalizeObservation .* \(no state snapshot\)"):
        path = _record(_warmed(gym.wrappers.NormalizeObservation), tmp_path / "old.mcap")
    monkeypatch.undo()
    state_module._BY_TYPE.clear()
    results = replay([path]).episodes
    assert {e.status for e in results} == {"not_replayable"}
    assert results[0].reason is not None
    assert results[0].reason.startswith(
        "the recorded wrapper NormalizeObservation keeps running statistics across episodes, "
        "which the file does not hold (no state snapshot)"
    )
    findings = [f for f in check([path]).findings if f.code == "not_replayable"]
    assert len(findings) == 1 and "NormalizeObservation" in findings[0].message


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("autoreset", ["NextStep", "SameStep"])
def test_sub_envs_each_in_a_normalize_wrapper_replay_identical(
    tmp_path: Path, mode: str, autoreset: str
) -> None:
    # ResetRngInfo outermost in each sub-env snapshots it (installed by the recorder on Sync)
    wrappers = [gym.wrappers.NormalizeObservation] + ([ResetRngInfo] if mode == "async" else [])
    envs = gym.make_vec(
        "CartPole-v1",
        3,
        vectorization_mode=mode,
        wrappers=wrappers,
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode[_UPPER[autoreset]]},
    )
    path = tmp_path / "vec.mcap"
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=1)
        rec.action_space.seed(2)
        for _ in range(250):
            rec.step(rec.action_space.sample())
    results = replay([path]).episodes
    assert len(results) > 3 * 5
    assert {(e.status, e.reason) for e in results} == {("identical", None)}
    alone = replay([path], episodes=[results[-4].episode]).episodes
    assert [e.status for e in alone] == ["identical"]


_UPPER = {"NextStep": "NEXT_STEP", "SameStep": "SAME_STEP"}


def test_an_unseeded_ale_episode_replays_identical_alone(tmp_path: Path) -> None:
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    path = tmp_path / "pong.mcap"
    with RecordEvidence(gym.make("ALE/Pong-v5", obs_type="ram", max_episode_steps=60), path) as rec:
        rec.action_space.seed(0)
        for ep in range(3):
            rec.reset(seed=3 if ep == 0 else None)
            while not any(rec.step(rec.action_space.sample())[2:4]):
                pass
    # the emulator's version is recorded (ale_py was imported): a replay under another says so
    assert open_evidence(path).run.versions["ale_py"] == ale_py.__version__
    # sticky actions draw from the emulator's RNG, which only the snapshot restores
    assert _statuses(path, episodes=[2]) == [("identical", None)]
    assert _statuses(path) == [("identical", None)] * 3


class CountResets(gym.ObservationWrapper[Any, Any, Any]):
    """Adds how many resets it has seen to every observation: state no adapter holds."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.resets = 0

    def reset(self, **kwargs: Any) -> Any:
        self.resets += 1
        return super().reset(**kwargs)

    def observation(self, observation: Any) -> Any:
        return observation + self.resets


def _counting() -> gym.Env[Any, Any]:
    return CountResets(gym.wrappers.NormalizeObservation(gym.make("CartPole-v1")))


def test_state_outside_any_adapter_is_replayed_after_the_episodes_before_it(
    tmp_path: Path,
) -> None:
    # Alone, in a fresh env, episode 3 differs at its reset (the count is not in the
    # snapshot); replay then replays it after episodes 0-2, in recorded order, as recorded.
    path = _record(_counting(), tmp_path / "counting.mcap")
    [result] = replay([path], episodes=[3], env_factory=_counting).episodes
    assert (result.episode, result.status, result.divergence) == (3, "identical", None)


@pytest.fixture
def count_adapter() -> Iterator[None]:
    class Adapter:
        name, needed = "tests.CountResets", "always"

        def get_state(self, obj: CountResets) -> Mapping[str, Any]:
            return {"resets": obj.resets}

        def set_state(self, obj: CountResets, state: Mapping[str, Any]) -> None:
            obj.resets = state["resets"]

    from episode_audit import register_state_adapter

    register_state_adapter(CountResets, Adapter())
    yield
    state_module._ADAPTERS.pop(f"{__name__}:CountResets")
    state_module._BY_TYPE.clear()


def test_a_user_adapter_makes_that_state_replay(tmp_path: Path, count_adapter: None) -> None:
    path = _record(_counting(), tmp_path / "counting.mcap")
    assert _statuses(path, episodes=[3], env_factory=_counting) == [("identical", None)]
    assert _statuses(path, env_factory=_counting) == [("identical", None)] * EPISODES
