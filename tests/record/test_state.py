"""State adapters: registration, the shipped adapters' round trips, snapshots at each reset."""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import (
    ConfigurationError,
    RecorderWarning,
    RecordEvidence,
    RecordVectorEvidence,
    StateAdapter,
    check,
    open_evidence,
    register_state_adapter,
)
from episode_audit.format.state import decode_snapshot
from episode_audit.record import state as state_module
from episode_audit.record.state import StateTargets, adapter_for, restore_snapshot


class CountResets(gym.Wrapper[Any, Any, Any, Any]):
    """Adds how many resets it has seen to every observation: state across episodes."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.resets = 0

    def reset(self, **kwargs: Any) -> Any:
        self.resets += 1
        obs, info = self.env.reset(**kwargs)
        return obs + self.resets, info

    def step(self, action: Any) -> Any:
        obs, *rest = self.env.step(action)
        return (obs + self.resets, *rest)


class CountAdapter:
    name = "tests.CountResets"
    needed = "always"

    def get_state(self, obj: CountResets) -> Mapping[str, Any]:
        return {"resets": obj.resets}

    def set_state(self, obj: CountResets, state: Mapping[str, Any]) -> None:
        obj.resets = state["resets"]


@pytest.fixture
def count_adapter() -> Iterator[CountAdapter]:
    """:class:`CountAdapter` registered for :class:`CountResets`, for one test."""
    adapter = CountAdapter()
    register_state_adapter(CountResets, adapter)
    yield adapter
    state_module._ADAPTERS.pop(f"{__name__}:CountResets")
    state_module._BY_TYPE.clear()


def test_a_registered_adapter_applies_to_the_class_and_its_subclasses(
    count_adapter: CountAdapter,
) -> None:
    class Sub(CountResets):
        pass

    assert isinstance(count_adapter, StateAdapter)
    assert adapter_for(CountResets(gym.make("CartPole-v1"))) is count_adapter
    assert adapter_for(Sub(gym.make("CartPole-v1"))) is count_adapter
    assert adapter_for(gym.make("CartPole-v1")) is None


def test_registering_refuses_a_second_adapter_and_what_lacks_the_protocol(
    count_adapter: CountAdapter,
) -> None:
    with pytest.raises(ConfigurationError, match=r"has the adapter 'tests\.CountResets' already"):
        register_state_adapter(CountResets, CountAdapter())
    with pytest.raises(ConfigurationError, match=r"expected an adapter with name, needed"):
        register_state_adapter("x:Y", object())  # type: ignore[arg-type]

    class Sometimes(CountAdapter):
        needed = "sometimes"  # type: ignore[assignment]

    with pytest.raises(ConfigurationError, match="'always' or 'unseeded'"):
        register_state_adapter("x:Y", Sometimes())
    register_state_adapter(CountResets, count_adapter)  # the same one again: fine


@pytest.mark.parametrize("target", [3, "CountingEnv", "my_package.envs.CountingEnv", None])
def test_registering_refuses_a_target_that_names_no_class(
    count_adapter: CountAdapter, target: Any
) -> None:
    with pytest.raises(
        ConfigurationError,
        match=r"^register_state_adapter: expected a class or a 'module:QualName' string as the "
        r"target, got .*; pass e\.g\. MyEnv or 'my_package\.envs:MyEnv'$",
    ):
        register_state_adapter(target, count_adapter)


def _warm(env: gym.Env[Any, Any], steps: int = 200, seed: int = 0) -> None:
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(steps):
        if any(env.step(env.action_space.sample())[2:4]):
            env.reset()


def _same_rollout(a: Any, b: Any, vector: bool = False, steps: int = 60) -> None:
    """Reset both envs with one seed and step them alike: every value must be equal."""
    obs_a, _ = a.reset(seed=11)
    obs_b, _ = b.reset(seed=11)
    assert np.array_equal(obs_a, obs_b)
    a.action_space.seed(3)
    for _ in range(steps):
        action = a.action_space.sample()
        ra, rb = a.step(action), b.step(action)
        assert np.array_equal(ra[0], rb[0]) and np.array_equal(ra[1], rb[1])
        if not vector and (ra[2] or ra[3]):
            a.reset()
            b.reset()


@pytest.mark.parametrize(
    "wrapper", [gym.wrappers.NormalizeObservation, gym.wrappers.NormalizeReward]
)
def test_gymnasium_normalize_wrappers_round_trip(wrapper: Any) -> None:
    warmed, fresh = wrapper(gym.make("CartPole-v1")), wrapper(gym.make("CartPole-v1"))
    _warm(warmed)
    warmed.update_running_mean = False  # a frozen evaluation wrapper stays frozen
    assert len(StateTargets(warmed).targets) == 1
    restore_snapshot(fresh, _snapshot(warmed), seeded=True)
    assert fresh.update_running_mean is False
    _same_rollout(warmed, fresh)


@pytest.mark.parametrize(
    "wrapper",
    [gym.wrappers.vector.NormalizeObservation, gym.wrappers.vector.NormalizeReward],
)
def test_gymnasium_vector_normalize_wrappers_round_trip(wrapper: Any) -> None:
    def make() -> Any:
        return wrapper(gym.make_vec("CartPole-v1", 3, vectorization_mode="sync"))

    warmed, fresh = make(), make()
    warmed.reset(seed=0)
    warmed.action_space.seed(0)
    for _ in range(100):
        warmed.step(warmed.action_space.sample())
    restore_snapshot(fresh, _snapshot(warmed), seeded=True)
    _same_rollout(warmed, fresh, vector=True)


def test_vector_normalize_reward_of_another_gymnasium_is_told_not_restored() -> None:
    """Gymnasium 1.3 added ``_prev_dones`` to it: a snapshot and a wrapper must agree."""
    adapter = adapter_for(gym.wrappers.vector.NormalizeReward(gym.make_vec("CartPole-v1", 2)))
    assert adapter is not None

    def make(with_prev_dones: bool) -> Any:
        env = gym.wrappers.vector.NormalizeReward(gym.make_vec("CartPole-v1", 2))
        if hasattr(env, "_prev_dones") and not with_prev_dones:
            del env._prev_dones  # as Gymnasium 1.2's has none
        elif with_prev_dones:
            env._prev_dones = np.zeros(2, dtype=np.float32)  # as Gymnasium >= 1.3's
        return env

    newer, older = make(True), make(False)
    assert "_prev_dones" in adapter.get_state(newer)
    assert "_prev_dones" not in adapter.get_state(older)
    adapter.set_state(make(True), adapter.get_state(newer))
    adapter.set_state(make(False), adapter.get_state(older))
    with pytest.raises(ValueError, match=r"^only the recorded state has _prev_dones \(another"):
        adapter.set_state(older, adapter.get_state(newer))
    with pytest.raises(ValueError, match=r"^only the rebuilt wrapper has _prev_dones \(another"):
        adapter.set_state(newer, adapter.get_state(older))


def test_sb3_vec_normalize_round_trips_without_the_sb3_recorder() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    def make() -> VecNormalize:
        return VecNormalize(make_vec_env("CartPole-v1", n_envs=2, seed=0))

    warmed, fresh = make(), make()
    warmed.reset()
    for _ in range(150):
        warmed.step(np.array([0, 1]))
    assert (
        adapter_for(warmed) is not None
        and adapter_for(warmed).name == "stable_baselines3.VecNormalize"
    )  # type: ignore[union-attr]
    restore_snapshot(fresh, _snapshot(warmed), seeded=True)
    for attr in ("mean", "var", "count"):
        assert np.array_equal(getattr(fresh.obs_rms, attr), getattr(warmed.obs_rms, attr))
    assert np.array_equal(fresh.returns, warmed.returns)
    obs = np.ones((2, 4))
    assert np.array_equal(fresh.normalize_obs(obs), warmed.normalize_obs(obs))
    assert np.array_equal(fresh.normalize_reward(np.ones(2)), warmed.normalize_reward(np.ones(2)))


def test_ale_state_with_its_rng_round_trips() -> None:
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    played = gym.make("ALE/Pong-v5", obs_type="ram")
    played.reset(seed=3)
    played.action_space.seed(0)
    for _ in range(50):
        played.step(played.action_space.sample())
    fresh = gym.make("ALE/Pong-v5", obs_type="ram")
    snapshot = _snapshot(played)
    restore_snapshot(fresh, snapshot, seeded=False)
    obs_a, _ = played.reset()
    obs_b, _ = fresh.reset()
    assert np.array_equal(obs_a, obs_b)
    actions = np.random.default_rng(0).integers(0, 6, 100)
    for action in actions:  # sticky actions draw from the emulator's RNG
        assert np.array_equal(played.step(action)[0], fresh.step(action)[0])


def _snapshot(env: Any) -> str:
    notes: list[str] = []
    text = StateTargets(env).capture(notes)
    assert text is not None and not notes
    return text


def test_restoring_says_what_is_missing_or_left_over() -> None:
    normalized = gym.wrappers.NormalizeObservation(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match=r"holds no gymnasium\.NormalizeObservation snapshot"):
        restore_snapshot(normalized, None, seeded=True)
    with pytest.raises(ValueError, match=r"rebuilt env has nothing it restores into"):
        restore_snapshot(gym.make("CartPole-v1"), _snapshot(normalized), seeded=True)
    other = gym.wrappers.NormalizeObservation(gym.make("Pendulum-v1"))
    with pytest.raises(ValueError, match="does not fit the rebuilt env's NormalizeObservation"):
        restore_snapshot(other, _snapshot(normalized), seeded=True)
    assert restore_snapshot(normalized, _snapshot(normalized), seeded=True) == [
        "NormalizeObservation"
    ]


# ---------------------------------------------------------------------- the recorders


def _record(env: gym.Env[Any, Any], path: Path, episodes: int = 3) -> Any:
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for ep in range(episodes):
            rec.reset(seed=ep if ep == 0 else None)
            while not any(rec.step(rec.action_space.sample())[2:4]):
                pass
    return open_evidence(path)


def test_a_file_without_state_to_snapshot_has_no_state_column(tmp_path: Path) -> None:
    ev = _record(gym.make("CartPole-v1"), tmp_path / "plain.mcap")
    assert "state" not in ev.resets().column_names


def test_every_reset_row_holds_the_snapshot_taken_before_it(tmp_path: Path) -> None:
    env = gym.wrappers.NormalizeObservation(gym.make("CartPole-v1"))
    _warm(env, 100)
    before = env.obs_rms.count
    ev = _record(env, tmp_path / "norm.mcap")
    states = ev.resets().column("state").to_pylist()
    assert len(states) == 3
    [(name, first)] = decode_snapshot(states[0])
    assert name == "gymnasium.NormalizeObservation"
    assert first["obs_rms.count"] == before  # taken before the reset's own update
    counts = [decode_snapshot(s)[0][1]["obs_rms.count"] for s in states]
    lengths = ev.episodes().column("length").to_pylist()
    assert counts[1] == counts[0] + 1 + lengths[0]  # the reset and each step updated it


def test_an_adapter_that_raises_is_noted_and_recording_goes_on(
    tmp_path: Path, count_adapter: CountAdapter, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(obj: Any) -> Any:
        raise RuntimeError("no state today")

    monkeypatch.setattr(count_adapter, "get_state", broken)
    ev = _record(CountResets(gym.make("CartPole-v1")), tmp_path / "broken.mcap", episodes=2)
    assert ev.resets().column("state").to_pylist() == [None, None]
    notes = ev.resets().column("notes").to_pylist()
    assert all("state_unavailable: RuntimeError: no state today" in n for n in notes)
    assert ev.episodes().column("outcome").to_pylist()[0] in ("failure", "truncated")


@pytest.mark.parametrize("vec", ["SyncVectorEnv", "DummyVecEnv"])
def test_a_sub_env_snapshot_that_raises_is_noted_on_its_reset_row(
    tmp_path: Path, count_adapter: CountAdapter, monkeypatch: pytest.MonkeyPatch, vec: str
) -> None:
    """ResetRngInfo snapshots a sub-env inside its reset (an autoreset: inside the step): an
    adapter that raises there is noted on the reset row, as the single-env recorder notes it."""

    def broken(obj: Any) -> Any:
        raise RuntimeError("no state today")

    monkeypatch.setattr(count_adapter, "get_state", broken)
    make = [lambda: CountResets(gym.make("CartPole-v1", max_episode_steps=10))] * 2
    path = tmp_path / "broken.mcap"
    if vec == "SyncVectorEnv":
        envs: Any = gym.vector.SyncVectorEnv(
            make, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP
        )
        with RecordVectorEvidence(envs, path) as rec:
            rec.reset(seed=1)
            for _ in range(25):
                rec.step(np.zeros(2, dtype=np.int64))
    else:
        pytest.importorskip("stable_baselines3")
        from stable_baselines3.common.vec_env import DummyVecEnv

        from episode_audit import RecordVecEnvEvidence

        with RecordVecEnvEvidence(DummyVecEnv(make), path) as venv:
            venv.seed(1)
            venv.reset()
            for _ in range(25):
                venv.step(np.zeros(2, dtype=np.int64))
    resets = open_evidence(path).resets()
    assert len(resets) == 6  # the reset, then two autoresets of each sub-env
    assert resets.column("state").to_pylist() == [None] * 6
    notes = resets.column("notes").to_pylist()
    assert all(n and "state_unavailable: RuntimeError: no state today" in n for n in notes), notes


def test_vector_sub_envs_are_snapshot_at_every_reset(tmp_path: Path) -> None:
    envs = gym.make_vec(
        "CartPole-v1", 3, vectorization_mode="sync", wrappers=[gym.wrappers.NormalizeObservation]
    )
    with RecordVectorEvidence(envs, tmp_path / "vec.mcap") as rec:
        rec.reset(seed=1)
        rec.action_space.seed(1)
        for _ in range(100):
            rec.step(rec.action_space.sample())
    resets = open_evidence(tmp_path / "vec.mcap").resets()
    states = resets.column("state").to_pylist()
    assert len(states) > 3 and None not in states
    first = {i: decode_snapshot(s)[0][1] for i, s in zip(resets["env_index"].to_pylist(), states)}
    assert set(first) == {0, 1, 2}


@pytest.mark.parametrize("mode", ["async", "sync"])
def test_unsnapshot_sub_envs_are_told_to_wrap_them_in_reset_rng_info(
    tmp_path: Path, mode: str
) -> None:
    """A vector recorder cannot sit inside a sub-env's NormalizeObservation: the warning and
    check's not_replayable say what works, ResetRngInfo outermost in each sub-env."""
    path = tmp_path / "vec.mcap"
    envs = gym.make_vec(
        "CartPole-v1", 2, vectorization_mode=mode, wrappers=[gym.wrappers.NormalizeObservation]
    )
    fix = (
        "wrap each sub-env in episode_audit.ResetRngInfo (outermost, in the env function), "
        "which snapshots NormalizeObservation"
    )
    with pytest.warns(RecorderWarning, match=re.escape(fix)):
        rec = RecordVectorEvidence(envs, path, install_rng_info=False)
    with rec:
        rec.reset(seed=1)
        for _ in range(30):
            rec.step(rec.action_space.sample())
    (found,) = [f.message for f in check([path]).findings if f.code == "not_replayable"]
    assert found.endswith(fix) and "recorder inside" not in found, found
