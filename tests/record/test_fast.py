"""The compiled step (record/fast.py, record/csrc/) against the pure-Python path.

Each scenario is recorded twice in this process, compiled and pure Python, on the same
deterministic clock: every message, channel and metadata record of the two files must be the
same bytes (but the run's wall-clock start and end times).
"""

from __future__ import annotations

import gc
import itertools
import os
import time
import warnings
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from mcap.reader import make_reader

from episode_audit import RecordEvidence, open_evidence
from episode_audit.errors import RecorderError
from episode_audit.record import fast, native
from tests.support.envs import ScriptedEnv

needs_compiled = pytest.mark.skipif(
    native.NATIVE is None, reason="the compiled step is not built (no C compiler at install)"
)


def test_the_compiled_step_is_built_where_the_install_requires_it() -> None:
    # make test installs with EPISODE_AUDIT_REQUIRE_EXTENSION=1: a failed build fails there
    if os.environ.get("EPISODE_AUDIT_REQUIRE_EXTENSION") != "1":
        pytest.skip("EPISODE_AUDIT_REQUIRE_EXTENSION is not set: the extension is optional")
    assert native.NATIVE is not None


def _odd_env() -> ScriptedEnv:
    """Common steps mixed with every kind of step the compiled path hands to Python."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        t = env.t
        obs: Any = np.full(3, t / 100, np.float32)
        reward: Any = 0.25 * t
        terminated: Any = t % 29 == 0
        truncated: Any = False
        info: dict[str, Any] = {"reward_dist": -0.1 * t, "reward_ctrl": 0.01}
        if t % 7 == 0:
            obs = obs.astype(np.float64)  # cast, noted
        if t % 11 == 0:
            obs = [0.1, 0.2, 0.3]  # converted, noted
        if t % 13 == 0:
            reward = np.float32(0.5)
        if t % 3 == 0:  # numpy scalars read in place: float32, float64; others as float() does
            info["reward_ctrl"], reward = np.float32(0.01 * t), np.float64(reward)
        if t % 5 == 0:
            info["reward_dist"] = [np.float64(-0.1 * t), np.float16(0.3), 2, np.bool_(True)][t % 4]
        if t % 17 == 0:
            reward = "1.5"  # not a number: recorded as null, noted
        if t % 19 == 0:
            info["reward_bonus"] = 1.0  # a new key set: the plan changes
        if t % 23 == 0:
            terminated = np.bool_(t % 2 == 0)  # a numpy bool
        if t % 31 == 0:
            info = {}
        if t % 37 == 0:
            obs = np.full(3, np.nan, np.float32)[::-1]  # not contiguous
        return obs, reward, terminated, truncated, info

    return ScriptedEnv(
        step_fn=step,
        observation_space=gym.spaces.Box(-1.0, 1.0, (3,), np.float32),
        action_space=gym.spaces.MultiDiscrete([3, 4]),
    )


def _image_env() -> ScriptedEnv:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        obs = np.full((8, 8, 3), env.t % 256, np.uint8)
        return obs, 1.0, False, env.t % 50 == 0, {}

    def reset(env: ScriptedEnv) -> tuple[Any, Any]:
        return np.zeros((8, 8, 3), np.uint8), {}

    return ScriptedEnv(
        step_fn=step,
        reset_fn=reset,
        observation_space=gym.spaces.Box(0, 255, (8, 8, 3), np.uint8),
        action_space=gym.spaces.MultiBinary(4),
    )


def _endings_env() -> gym.Env[Any, Any]:
    """Endings of every kind: by the flags alone (the time limit too) and by the rules' keys."""
    infos: list[dict[str, Any]] = [
        {},
        {"is_success": True},
        {"failure": "fell", "x": 1.0},
        {"truncation_reason": "budget"},
        {"success": np.bool_(False)},
        {"x": 0.5},
    ]

    steps = itertools.count(1)

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        n = next(steps)  # (across episodes: each info's keys hold for 40 steps)
        info = infos[n // 40 % len(infos)]
        return np.full(2, n, np.float32), 1.0, n % 5 == 0, n % 7 == 0, dict(info)

    return gym.wrappers.TimeLimit(
        ScriptedEnv(
            step_fn=step,
            observation_space=gym.spaces.Box(-1e6, 1e6, (2,), np.float32),
            action_space=gym.spaces.Discrete(3),
        ),
        max_episode_steps=4,
    )


class _AnySeedEnv(ScriptedEnv):
    """Takes any seed (Gymnasium's own reset refuses those that are not a Python int >= 0)."""

    def reset(
        self, *, seed: Any = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        plain = type(seed) is int and 0 <= seed < 2**63
        return super().reset(seed=seed if plain else None, options=options)


def _resets_env() -> ScriptedEnv:
    """Resets of every kind: observations the compiled reset takes, and ones it hands on."""

    def reset(env: ScriptedEnv) -> Any:
        n = next(resets)
        if n % 5 == 3:
            return np.zeros(2, np.float64), {}  # cast, noted
        if n % 5 == 4:
            return np.zeros(2, np.float32), {"x": 1.0}
        if n % 11 == 10:
            return [np.zeros(2, np.float32), {}]  # not a tuple
        return np.full(2, n, np.float32), {}

    resets = itertools.count()
    return _AnySeedEnv(
        step_fn=lambda env, action: (np.ones(2, np.float32), 1.0, env.t % 6 == 0, False, {}),
        reset_fn=reset,
        observation_space=gym.spaces.Box(-1e6, 1e6, (2,), np.float32),
        action_space=gym.spaces.Discrete(2),
    )


def _reset_arguments(episode: int) -> dict[str, Any]:
    """A seeded reset, mostly; every few episodes one of the kinds the compiled reset hands on."""
    kinds: list[dict[str, Any]] = [
        {"seed": None},
        {"seed": np.int64(episode)},
        {"seed": episode, "options": {"level": 2}},
        {"seed": -1},
        {"seed": 2**64},
    ]
    return kinds[episode // 2 % len(kinds)] if episode % 2 else {"seed": 100 + episode}


SCENARIOS: dict[str, tuple[Callable[[], gym.Env[Any, Any]], int, dict[str, Any]]] = {
    # flushes due at resets too (the clock ticks 1 us a read)
    "resets": (_resets_env, 400, {"block_steps": 1000, "flush_every_s": 40e-6}),
    "endings": (_endings_env, 480, {"block_steps": 32}),
    "cartpole": (lambda: gym.make("CartPole-v1"), 700, {"block_steps": 100}),
    "halfcheetah_terms": (lambda: gym.make("HalfCheetah-v5"), 400, {"block_steps": 64}),
    "odd_values": (_odd_env, 300, {"block_steps": 40}),
    "images": (_image_env, 160, {"block_steps": 1000}),
}


def _record(
    make: Callable[[], gym.Env[Any, Any]], steps: int, options: dict[str, Any], path: Path
) -> tuple[int, int]:
    """Record; return the steps the compiled path took and those it handed to Python."""
    env = make()
    env.action_space.seed(3)
    odd_resets = make is _resets_env
    with RecordEvidence(env, path, **{"flush_every_s": 1e9, **options}) as rec:
        rec.reset(seed=0)
        episode = 0
        for t in range(steps):
            _, _, terminated, truncated, _ = rec.step(env.action_space.sample())
            if terminated or truncated or t % 97 == 96:  # (and now and then mid-episode)
                episode += 1
                rec.reset(**_reset_arguments(episode) if odd_resets else {"seed": 100 + episode})
        if steps % 3 == 0:
            rec.step(env.action_space.sample())  # a step after an ending, maybe
            rec.step(env.action_space.sample())
        step = rec._record_step
        resets[path.stem] = getattr(step, "compiled_resets", 0)
        return getattr(step, "compiled_steps", 0), getattr(step, "python_steps", steps)


resets: dict[str, int] = {}  # the resets the compiled path recorded, by file stem


_WALL = {"start_time", "end_time"}  # datetime.now(), not the clock patched here


def _contents(path: Path) -> list[Any]:
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        out: list[Any] = [
            sorted((c.id, c.topic, c.schema_id, c.metadata) for c in summary.channels.values())
        ]
        for _, channel, message in reader.iter_messages(log_time_order=False):
            out.append((channel.topic, message.log_time, message.publish_time, message.data))
        for record in reader.iter_metadata():
            out.append((record.name, {k: v for k, v in record.metadata.items() if k not in _WALL}))
    return out


@needs_compiled
@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_compiled_and_pure_python_write_the_same_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    make, steps, options = SCENARIOS[name]
    files, taken = {}, {}
    for mode in ("compiled", "pure"):
        ticks = itertools.count(1_000_000_000, 1_000)
        monkeypatch.setattr(time, "monotonic_ns", ticks.__next__)
        monkeypatch.setattr(time, "time_ns", lambda: 1_700_000_000_000_000_000)
        monkeypatch.setenv(fast.PURE_PYTHON_ENV, "1" if mode == "pure" else "0")
        files[mode] = tmp_path / f"{mode}.mcap"
        taken[mode] = _record(make, steps, options, files[mode])
    assert taken["pure"][0] == 0
    compiled_steps, python_steps = taken["compiled"]
    if name == "odd_values":  # about 2 steps in 5 are odd: handed to Python
        assert compiled_steps > steps // 2 and python_steps > steps // 4
    else:  # all but those that find a column block full
        assert compiled_steps > steps * 0.95
    assert resets["pure"] == 0
    # (odd_values resets to an observation of the wrong shape: the Python path records it)
    assert resets["compiled"] >= {"odd_values": 0, "halfcheetah_terms": 1, "images": 1}.get(
        name, 20
    )
    compiled, pure = _contents(files["compiled"]), _contents(files["pure"])
    assert len(compiled) == len(pure)
    for a, b in zip(compiled, pure, strict=True):
        assert a == b


@needs_compiled
def test_the_compiled_step_is_used_and_the_switch_turns_it_off(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap") as rec:
        assert type(rec._record_step).__name__ == "StepRecorder"
    monkeypatch.setenv(fast.PURE_PYTHON_ENV, "1")
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "b.mcap") as rec:
        assert type(rec._record_step).__name__ != "StepRecorder"
    assert not fast.compiled()


@needs_compiled
def test_the_recorders_step_is_compiled_where_its_class_step_is_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    class Counting(RecordEvidence[Any, Any]):
        calls = 0

        def step(self, action: Any) -> Any:
            Counting.calls += 1
            return super().step(action)

    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap") as rec:
        assert type(vars(rec)["step"]).__name__ == "WrapperStep"
        assert rec.step is vars(rec)["step"] and rec._compiled_step is rec.step
    with Counting(gym.make("CartPole-v1"), tmp_path / "b.mcap") as sub:
        sub.reset(seed=0)
        sub.step(0)
        assert "step" not in vars(sub) and Counting.calls == 1  # (its own step kept)
    monkeypatch.setenv(fast.PURE_PYTHON_ENV, "1")
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "c.mcap") as rec:
        assert "step" not in vars(rec) and rec._compiled_step is None


@needs_compiled
def test_the_compiled_recorder_step_hands_other_calls_to_the_python_step(
    tmp_path: Path,
) -> None:
    rec = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap")
    rec.reset(seed=0)
    _, reward, terminated, _, _ = rec.step(action=1)  # (a keyword: Python's)
    assert reward == 1.0 and not terminated and not rec._busy
    with pytest.raises(TypeError, match="unexpected keyword argument 'act'"):
        rec.step(act=1)
    assert not rec._busy
    rec.step(np.int64(0))
    rec.close()
    with pytest.raises(RecorderError, match="the recorder is closed"):
        rec.step(0)  # (gated: the Python step raises it)
    assert open_evidence(tmp_path / "a.mcap").steps(columns=["action"]).column(0).to_pylist() == [
        1,
        0,
    ]


@needs_compiled
def test_the_compiled_recorder_step_records_the_envs_error_and_raises_it(
    tmp_path: Path,
) -> None:
    def failing(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        if env.t == 3:
            raise ValueError("the simulator diverged")
        return np.zeros(2, np.float32), 1.0, False, False, {}

    rec = RecordEvidence(ScriptedEnv(step_fn=failing), tmp_path / "a.mcap")
    rec.reset(seed=0)
    rec.step(np.int64(0))
    rec.step(np.int64(1))
    with pytest.raises(ValueError, match="the simulator diverged") as raised:
        rec.step(np.int64(2))
    assert raised.value.__context__ is None and not rec._busy
    rec.close()
    episode = open_evidence(tmp_path / "a.mcap").episodes().to_pylist()[0]
    assert episode["outcome"] == "error" and episode["length"] == 2
    assert (episode["error_type"], episode["error_message"], episode["error_during"]) == (
        "ValueError",
        "the simulator diverged",
        "step",
    )


@needs_compiled
def test_a_compiled_recorder_step_keeps_its_recorder_as_a_bound_method_would(
    tmp_path: Path,
) -> None:
    rec = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap")
    rec.reset(seed=0)
    step = rec.step
    alive = weakref.ref(rec)
    del rec
    gc.collect()
    recorder = alive()
    assert recorder is not None  # (held by its step, which the collector sees)
    assert step(0)[1] == 1.0
    recorder.close()
    del recorder, step
    gc.collect()
    assert alive() is None  # (the cycle through its dict is the collector's to free)


@needs_compiled
def test_the_compiled_paths_per_episode_objects_are_left_out_of_the_collector(
    tmp_path: Path,
) -> None:
    # an episode, its ending and its rows hold no reference that could lead back to them: the
    # cyclic collector need not scan them (they are freed by their reference counts)
    import gc

    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap") as rec:
        stream = rec._stream
        for seed in (1, 2):
            rec.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = rec.step(rec.action_space.sample())
                done = terminated or truncated
        rec.reset(seed=3)
        block = stream.block
        # (a block's first segment is made in Python, with the block)
        made = [stream.episode, *block.segments[1:], *block.resets, *block.ends.values()]
        made += [*block.flags.values(), *rec._file.pending, *(p[0] for p in rec._file.pending)]
        assert len(made) >= 10
        assert [item for item in made if gc.is_tracked(item)] == []


@needs_compiled
def test_the_vector_recorders_per_episode_objects_are_left_out_of_the_collector(
    tmp_path: Path,
) -> None:
    import gc

    from episode_audit import RecordVectorEvidence

    env = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with RecordVectorEvidence(env, tmp_path / "v.mcap") as rec:
        rec.reset(seed=0)
        actions = np.zeros(2, dtype=np.int64)
        while len(rec._file.pending) < 4:
            rec.step(actions)
        made: list[Any] = [*rec._file.pending, *(pair[0] for pair in rec._file.pending)]
        for stream in rec._streams:
            block = stream.block
            made += [stream.episode, *block.segments[1:], *block.resets]
            made += [*block.ends.values(), *block.flags.values()]
        assert [item for item in made if gc.is_tracked(item)] == []


class _OddBatches(gym.vector.VectorWrapper):
    """A CartPole vector env whose steps now and then hold what the compiled batched step hands
    to Python: rewards as a list or of int / float16 dtype, flags as a list, observations as
    float64 or not contiguous, an info with a value, actions of another int dtype."""

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        self._t = 0

    def step(self, actions: Any) -> Any:
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        self._t += 1
        kind = self._t % 11
        if kind == 1:
            rewards = rewards.tolist()
        elif kind == 2:
            rewards = rewards.astype(np.int16)
        elif kind == 3:
            rewards = rewards.astype(np.float16)
        elif kind == 4:
            terminated = terminated.tolist()
        elif kind == 5:
            obs = obs.astype(np.float64)
        elif kind == 6:
            obs = np.asfortranarray(np.repeat(obs, 2, axis=0)[::2])
        elif kind == 7:
            info = {"x": np.ones(len(rewards))}
        return obs, rewards, terminated, truncated, info


def _vector(mode: str, odd: bool = False) -> Any:
    kwargs = {"autoreset_mode": gym.vector.AutoresetMode[mode]}
    env = gym.make_vec("CartPole-v1", 4, vectorization_mode="sync", vector_kwargs=kwargs)
    return _OddBatches(env) if odd else env


VECTOR_SCENARIOS: dict[str, tuple[Callable[[], Any], int, dict[str, Any]]] = {
    "next_step": (lambda: _vector("NEXT_STEP"), 700, {"block_steps": 300}),
    "same_step": (lambda: _vector("SAME_STEP"), 500, {"block_steps": 200}),
    "disabled": (lambda: _vector("DISABLED"), 400, {"block_steps": 1000}),
    "odd_batches": (lambda: _vector("NEXT_STEP", odd=True), 600, {"block_steps": 250}),
}


autoresets: dict[Any, int] = {}  # the autoresets the compiled path began, by scenario


def _record_vector(
    make: Callable[[], Any], steps: int, options: dict[str, Any], path: Path
) -> tuple[int, int]:
    """Record a vector env; the vector steps the compiled path took, and those it did not."""
    from episode_audit import RecordVectorEvidence

    env = make()
    rng = np.random.default_rng(5)
    taken = [0, 0]
    with warnings.catch_warnings():  # (_OddBatches: "the steps it recorded are that wrapper's")
        warnings.simplefilter("ignore", UserWarning)
        rec = RecordVectorEvidence(env, path, **{"flush_every_s": 1e9, **options})
    with rec:
        compiled = rec._steps._compiled
        if compiled is not None:

            def counted(*args: Any) -> Any:
                ends = compiled(*args)
                taken[ends is None] += 1
                return ends

            rec._steps._compiled = counted
        begin = rec._autoreset.compiled_begin
        if begin is not None:

            def begun(*args: Any) -> Any:
                took = begin(*args)
                autoresets[make] = autoresets.get(make, 0) + (took is not None)
                return took

            rec._autoreset.compiled_begin = begun
        rec.reset(seed=0)
        disabled = rec._autoreset.mode is gym.vector.AutoresetMode.DISABLED
        for t in range(steps):
            actions = rng.integers(0, 2, size=4)
            if t % 13 == 5:
                actions = actions.astype(np.int32)
            _, _, terminated, truncated, _ = rec.step(actions)
            if disabled and (np.asarray(terminated) | np.asarray(truncated)).any():
                rec.reset(options={"reset_mask": np.asarray(terminated) | truncated})
            elif t % 150 == 149:  # a partial reset mid-episode
                rec.reset(seed=[t, None, None, None], options={"reset_mask": np.eye(4)[0] > 0})
    return taken[0], taken[1]


@needs_compiled
@pytest.mark.parametrize("name", sorted(VECTOR_SCENARIOS))
def test_compiled_and_pure_python_write_the_same_vector_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    make, steps, options = VECTOR_SCENARIOS[name]
    files, taken = {}, {}
    for mode in ("compiled", "pure"):
        ticks = itertools.count(1_000_000_000, 1_000)
        monkeypatch.setattr(time, "monotonic_ns", ticks.__next__)
        monkeypatch.setattr(time, "time_ns", lambda: 1_700_000_000_000_000_000)
        monkeypatch.setenv(fast.PURE_PYTHON_ENV, "1" if mode == "pure" else "0")
        files[mode] = tmp_path / f"{mode}.mcap"
        taken[mode] = _record_vector(make, steps, options, files[mode])
    assert taken["pure"] == (0, 0)
    compiled_steps, declined = taken["compiled"]
    if name == "odd_batches":  # 7 steps in 11 hold a value it hands on (some, new buffers)
        assert compiled_steps > steps // 6 and declined > steps // 6
    elif name == "same_step":  # it takes no step that ends an episode in SAME_STEP mode
        assert compiled_steps > steps // 2 and declined > steps // 20
    elif name == "disabled":  # the step after each reset() finds out which sub-envs are idle
        assert compiled_steps > steps // 2
    else:
        assert compiled_steps > steps * 0.8
    if name in ("next_step", "odd_batches", "same_step"):  # and its autoresets, begun in C
        assert autoresets.get(make, 0) > 20
    compiled, pure = _contents(files["compiled"]), _contents(files["pure"])
    assert len(compiled) == len(pure)
    for a, b in zip(compiled, pure, strict=True):
        assert a == b
