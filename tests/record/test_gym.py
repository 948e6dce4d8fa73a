from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest

from episode_audit import (
    ConfigurationError,
    EndingRules,
    RecorderError,
    RecordEvidence,
    RecordVectorEvidence,
    open_evidence,
)
from episode_audit.format.unrecorded import placeholder
from tests.support.envs import ScriptedEnv
from tests.support.limits import record_two_episodes, skipping_pendulum

REPO = Path(__file__).resolve().parents[2]


def test_cartpole_time_limit_example(tmp_path: Path) -> None:
    path = tmp_path / "cartpole.mcap"
    env = RecordEvidence(gym.make("CartPole-v1", max_episode_steps=3), path)
    env.reset(seed=5)
    env.action_space.seed(5)
    flags = []
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        flags.append((terminated, truncated))
    env.close()
    assert flags == [(False, False), (False, False), (False, True)]

    ev = open_evidence(path)
    assert ev.finished
    steps = ev.steps()
    assert list(zip(steps["terminated"].to_pylist(), steps["truncated"].to_pylist())) == flags
    assert steps["outcome"].to_pylist() == [None, None, "truncated"]
    assert steps["label"].to_pylist() == [None, None, "time_limit"]
    (episode,) = ev.episodes().to_pylist()
    assert episode["outcome"] == "truncated"
    assert episode["truncation_reason"] == "time_limit"
    assert episode["seed"] == 5
    assert episode["length"] == 3
    assert ev.run.env_id == "CartPole-v1"
    assert ev.run.env_spec is not None and ev.run.env_spec["max_episode_steps"] == 3


def _terms_env() -> ScriptedEnv:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        terms = {"success_bonus": 10.0, "distance_penalty": -0.04, "collision_penalty": 0.0}
        obs = np.zeros(2, np.float32)
        return obs, 9.96, True, False, {"reward_terms": terms, "success": True}

    return ScriptedEnv(step_fn=step)


def test_reward_terms_example(tmp_path: Path) -> None:
    path = tmp_path / "terms.mcap"
    with RecordEvidence(_terms_env(), path) as env:
        env.reset(seed=1)
        env.step(0)
    ev = open_evidence(path)
    steps = ev.steps().to_pylist()
    assert len(steps) == 1
    assert dict(steps[0]["terms"]) == {
        "success_bonus": 10.0,
        "distance_penalty": -0.04,
        "collision_penalty": 0.0,
    }
    assert steps[0]["reward"] == 9.96
    assert steps[0]["terminated"] is True
    (episode,) = ev.episodes().to_pylist()
    assert episode["outcome"] == "success"
    assert dict(episode["term_totals"])["success_bonus"] == 10.0


def test_terms_whose_keys_change_and_are_absent_at_reset(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        terms: dict[str, float] = {"distance": -0.1}
        if env.t % 3 == 0:
            terms["collision_penalty"] = -1.0
        if env.t == 5:
            return (
                np.zeros(2, np.float32),
                sum(terms.values()),
                True,
                False,
                {
                    "reward_terms": terms,
                    "failure": "collision",
                },
            )
        return np.zeros(2, np.float32), sum(terms.values()), False, False, {"reward_terms": terms}

    path = tmp_path / "changing.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=step), path) as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(1)
    ev = open_evidence(path)
    terms = [dict(t) for t in ev.steps()["terms"].to_pylist()]
    assert [sorted(t) for t in terms] == [
        ["distance"],
        ["distance"],
        ["collision_penalty", "distance"],
        ["distance"],
        ["distance"],
    ]
    (episode,) = ev.episodes().to_pylist()
    assert episode["outcome"] == "failure"
    assert episode["failure_label"] == "collision"
    assert dict(episode["term_totals"]) == pytest.approx(
        {"distance": -0.5, "collision_penalty": -1.0}
    )


@pytest.mark.parametrize("env_id", ["Reacher-v5", "HalfCheetah-v5"])
def test_mujoco_reward_terms_with_no_configuration(tmp_path: Path, env_id: str) -> None:
    pytest.importorskip("mujoco")
    path = tmp_path / f"{env_id}.mcap"
    with RecordEvidence(gym.make(env_id, max_episode_steps=40), path) as env:
        env.reset(seed=3)
        env.action_space.seed(3)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
    steps = open_evidence(path).steps()
    assert steps.num_rows == 40
    rewards = steps["reward"].to_numpy()
    for reward, terms in zip(rewards, steps["terms"].to_pylist()):
        names = [k for k, _ in terms]
        assert names and all(k.startswith("reward_") for k in names)
        assert math.fsum(v for _, v in terms) == pytest.approx(reward, abs=1e-12, rel=1e-12)


SPACES: dict[str, gym.Space[Any]] = {
    "box_f32": gym.spaces.Box(-1.0, 1.0, (3,), np.float32),
    "box_f64_2d": gym.spaces.Box(-np.inf, np.inf, (2, 3), np.float64),
    "box_image": gym.spaces.Box(0, 255, (8, 8, 3), np.uint8),
    "box_int16_scalar": gym.spaces.Box(-5, 5, (), np.int16),
    "discrete": gym.spaces.Discrete(5, start=-2),
    "multidiscrete": gym.spaces.MultiDiscrete([[2, 3], [4, 5]]),
    "multibinary": gym.spaces.MultiBinary([2, 2]),
    "text": gym.spaces.Text(8),
    "dict": gym.spaces.Dict(
        {
            "pos": gym.spaces.Box(-1, 1, (2,), np.float32),
            "mode": gym.spaces.Discrete(3),
            "pair": gym.spaces.Tuple((gym.spaces.MultiBinary(3), gym.spaces.Text(4))),
        }
    ),
    "tuple": gym.spaces.Tuple((gym.spaces.Discrete(2), gym.spaces.Box(0, 1, (2,), np.float16))),
    "sequence_fallback": gym.spaces.Sequence(gym.spaces.Discrete(4)),
}


def _assert_same(a: Any, b: Any) -> None:
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray)
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, dict):
        assert list(a) == list(b)
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b)
        for x, y in zip(a, b):
            _assert_same(x, y)
    else:
        assert a == b


@pytest.mark.parametrize("name", sorted(SPACES))
def test_every_space_round_trips_through_the_file(tmp_path: Path, name: str) -> None:
    space = SPACES[name]
    space.seed(7)
    samples = [space.sample() for _ in range(6)]

    def reset(env: ScriptedEnv) -> tuple[Any, Any]:
        return samples[0], {}

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        return samples[env.t], 0.5, False, env.t == 5, {}

    env = ScriptedEnv(step_fn=step, reset_fn=reset, observation_space=space, action_space=space)
    path = tmp_path / "spaces.mcap"
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        for i in range(5):
            rec.step(samples[i + 1])
    ev = open_evidence(path)
    codec_obs = ev.observation_codec
    codec_act = ev.action_codec
    assert codec_obs is not None and codec_act is not None
    steps = ev.steps()
    obs = codec_obs.decode(steps["observation"].combine_chunks())
    actions = codec_act.decode(steps["action"].combine_chunks())
    for i in range(5):
        _assert_same(samples[i + 1], obs[i])
        _assert_same(samples[i + 1], actions[i])
    reset_obs = codec_obs.decode(ev.resets()["observation"].combine_chunks())
    _assert_same(samples[0], reset_obs[0])


def test_digest_mode_stores_hashes_of_images(tmp_path: Path) -> None:
    space = gym.spaces.Box(0, 255, (32, 32, 3), np.uint8)
    path = tmp_path / "digest.mcap"
    env = ScriptedEnv(
        observation_space=space,
        reset_fn=lambda e: (np.zeros((32, 32, 3), np.uint8), {}),
        step_fn=lambda e, a: (np.full((32, 32, 3), e.t, np.uint8), 0.0, False, False, {}),
    )
    with RecordEvidence(env, path, digest_min_bytes=1024) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            rec.step(0)
    column = open_evidence(path).steps()["observation"]
    assert column.type == pa.binary(16)
    assert len(set(column.to_pylist())) == 3


def test_unseeded_reset_is_replayable_in_a_fresh_process(tmp_path: Path) -> None:
    path = tmp_path / "unseeded.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=11)
        env.action_space.seed(0)
        for _ in range(3):
            env.reset()
            for _ in range(4):
                env.step(env.action_space.sample())
    ev = open_evidence(path)
    third = ev.episode(2)
    assert third.record["seed"] is None and third.record["rng_state"] is not None
    actions = third.steps["action"].to_pylist()
    expected = ev.observation_codec.decode(third.steps["observation"].combine_chunks())  # type: ignore[union-attr]
    reset_expected = ev.observation_codec.decode(
        pa.array([third.reset["observation"]], ev.observation_codec.arrow_type)
    )  # type: ignore[union-attr]
    script = textwrap.dedent(
        f"""
        import json, sys, gymnasium as gym, numpy as np
        from episode_audit.record.seeding import restore_rng_state
        env = gym.make("CartPole-v1")
        restore_rng_state(env, json.loads({third.record["rng_state"]!r}))
        obs, _ = env.reset()
        out = [obs.tolist()]
        for a in {actions!r}:
            out.append(env.step(a)[0].tolist())
        print(json.dumps(out))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, cwd=REPO
    )
    import json

    got = json.loads(result.stdout)
    assert np.array_equal(np.array(got[0], np.float32), reset_expected[0])
    for i, obs in enumerate(expected):
        assert np.array_equal(np.array(got[i + 1], np.float32), obs)


def test_bad_values_are_recorded_and_noted_never_raised(tmp_path: Path) -> None:
    class Unserializable:
        pass

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        if env.t == 1:
            return np.zeros(2, np.float32), float("nan"), False, False, {"thing": Unserializable()}
        if env.t == 2:
            return (
                np.zeros(2, np.float32),
                1.0,
                False,
                False,
                {"reward_terms": {"a": "oops", "b": 1.0}},
            )
        if env.t == 3:
            return np.zeros(5, np.float32), 1.0, False, False, {}
        if env.t == 4:
            return np.zeros(2, np.float32), "one", False, False, []
        return np.full(2, 9.0, np.float32), 1.0, False, True, {}

    path = tmp_path / "bad.mcap"
    with RecordEvidence(ScriptedEnv(step_fn=step), path, info_keys="all") as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(0)
    steps = open_evidence(path).steps().to_pylist()
    assert math.isnan(steps[0]["reward"])
    assert "info_unserializable" in steps[0]["notes"]
    assert "term_not_numeric" in steps[1]["notes"]
    assert math.isnan(dict(steps[1]["terms"])["a"]) and dict(steps[1]["terms"])["b"] == 1.0
    assert "observation_invalid" in steps[2]["notes"] and steps[2]["observation"] is None
    assert "reward_not_numeric" in steps[3]["notes"] and "info_not_dict" in steps[3]["notes"]
    assert steps[4]["outcome"] == "truncated" and steps[4]["label"] == "external"


def test_env_error_is_recorded_and_reraised(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        if env.t == 3:
            raise RuntimeError("simulator exploded")
        return np.zeros(2, np.float32), 1.0, False, False, {}

    path = tmp_path / "error.mcap"
    env = RecordEvidence(ScriptedEnv(step_fn=step), path)
    env.reset(seed=0)
    env.step(0)
    env.step(0)
    with pytest.raises(RuntimeError, match="simulator exploded"):
        env.step(0)
    # the file is valid even before close()
    ev = open_evidence(path)
    (episode,) = ev.episodes().to_pylist()
    assert episode["outcome"] == "error" and episode["length"] == 2
    assert episode["error_type"] == "RuntimeError"
    assert episode["error_message"] == "simulator exploded"
    env.close()
    assert open_evidence(path).finished


def test_close_is_idempotent_records_incomplete_and_refuses_reuse(tmp_path: Path) -> None:
    path = tmp_path / "incomplete.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    env.reset(seed=1)
    env.step(0)
    env.close()
    env.close()
    with pytest.raises(RecorderError, match="the recorder is closed"):
        env.step(0)
    with pytest.raises(RecorderError, match="the recorder is closed"):
        env.reset()
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert episode["outcome"] == "incomplete" and episode["length"] == 1


def test_reset_before_the_end_marks_incomplete(tmp_path: Path) -> None:
    path = tmp_path / "reset.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=1)
        env.step(0)
        env.reset(seed=2)
        env.step(0)
    outcomes = open_evidence(path).episodes()["outcome"].to_pylist()
    assert outcomes == ["incomplete", "incomplete"]


def test_both_flags_set_counts_the_task_ending(tmp_path: Path) -> None:
    env = ScriptedEnv(
        step_fn=lambda e, a: (np.zeros(2, np.float32), 1.0, True, True, {"failure": "collision"})
    )
    path = tmp_path / "both.mcap"
    with RecordEvidence(gym.wrappers.TimeLimit(env, 1), path) as rec:
        rec.reset(seed=0)
        rec.step(0)
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert episode["outcome"] == "failure" and episode["failure_label"] == "collision"
    assert episode["truncation_reason"] == "time_limit"
    assert episode["terminated"] and episode["truncated"]


@pytest.mark.parametrize(
    ("make", "limit"),
    [
        (lambda: gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 500), 200),
        (
            lambda: gym.wrappers.TimeLimit(gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 30), 80),
            30,
        ),
        (lambda: gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 25), 25),
    ],
    ids=["registered-inside", "two-own", "outer-smaller"],
)
def test_every_time_limit_in_the_chain_counts_and_the_smallest_is_recorded(
    tmp_path: Path, make: Any, limit: int
) -> None:
    """An inner TimeLimit ends the episode before a larger outer one: ``time_limit``, and the
    spec the file records says the limit in effect (Gymnasium's names the outermost)."""
    path = tmp_path / "nested.mcap"
    with RecordEvidence(make(), path) as rec:
        rec.action_space.seed(0)
        for seed in (0, 1):
            rec.reset(seed=seed)
            for _ in range(limit):
                rec.step(rec.action_space.sample())
    ev = open_evidence(path)
    episodes = ev.episodes().select(["length", "outcome", "truncation_reason"]).to_pylist()
    assert (
        episodes
        == [{"length": limit, "outcome": "truncated", "truncation_reason": "time_limit"}] * 2
    )
    assert ev.run.env_spec is not None and ev.run.env_spec["max_episode_steps"] == limit


_SKIP = {"name": "MaxAndSkipObservation", "kwargs": {"skip": 4}}


@pytest.mark.parametrize(
    ("limit", "length", "wrappers"),
    [
        (30, 30, [_SKIP, {"name": "TimeLimit", "kwargs": {"max_episode_steps": 30}}]),
        (60, 50, [_SKIP, {"name": "TimeLimit", "kwargs": {"max_episode_steps": 60}}]),
        (None, 50, [_SKIP]),
    ],
    ids=["outer-ends", "inner-ends", "inner-only"],
)
def test_a_time_limit_over_a_frame_skip_is_recorded_where_it_counts(
    tmp_path: Path, limit: int | None, length: int, wrappers: list[dict[str, Any]]
) -> None:
    """The one over MaxAndSkipObservation counts its steps, the registered one under it the
    env's (200 of them: 50 steps): each ends episodes as ``time_limit``, and the spec has each
    where it was (``gym.make`` of it builds the same chain)."""
    path = record_two_episodes(tmp_path / "skip.mcap", skipping_pendulum(limit), length)
    ev = open_evidence(path)
    episodes = ev.episodes().select(["length", "outcome", "truncation_reason"]).to_pylist()
    assert (
        episodes
        == [{"length": length, "outcome": "truncated", "truncation_reason": "time_limit"}] * 2
    )
    spec = ev.run.env_spec
    assert spec is not None and spec["max_episode_steps"] == 200
    assert [{k: w[k] for k in ("name", "kwargs")} for w in spec["additional_wrappers"]] == wrappers
    rebuilt = gym.make(gym.envs.registration.EnvSpec.from_json(json.dumps(spec)))
    assert str(rebuilt) == str(skipping_pendulum(limit))


class _Unrecorded(gym.Wrapper[Any, Any, Any, Any]):
    """A wrapper that records no arguments (not ``RecordConstructorArgs``: ``kwargs`` null)."""

    def __init__(self, env: gym.Env[Any, Any], k: int = 1) -> None:
        super().__init__(env)
        self.k = k


def test_a_spec_with_placeholders_keeps_a_wrapper_that_records_no_arguments_null(
    tmp_path: Path,
) -> None:
    """Null says its arguments are unknown; ``{}`` would say it had none."""
    env = _Unrecorded(gym.wrappers.TransformReward(gym.make("CartPole-v1"), lambda r: 2 * r))
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
    spec = open_evidence(path).run.env_spec
    assert spec is not None
    assert [(w["name"], w["kwargs"]) for w in spec["additional_wrappers"]] == [
        ("TransformReward", {"func": placeholder(env.env.func)}),
        ("_Unrecorded", None),
    ]


def _autoreset_pendulum(limit: int = 30) -> gym.Env[Any, Any]:
    return gym.wrappers.Autoreset(gym.make("Pendulum-v1", max_episode_steps=limit))


def test_autoreset_right_under_the_recorder_begins_an_episode_at_each_hidden_reset(
    tmp_path: Path,
) -> None:
    """Gymnasium's Autoreset resets the env inside the step after an episode's end: that step
    returns the next episode's first observation, recorded as its reset row."""
    path = tmp_path / "autoreset.mcap"
    returned = []
    with RecordEvidence(_autoreset_pendulum(), path) as rec:
        rec.action_space.seed(0)
        rec.reset(seed=0)
        for _ in range(75):
            returned.append(rec.step(rec.action_space.sample())[0])
    ev = open_evidence(path)
    episodes = ev.episodes().select(["length", "outcome", "seed"]).to_pylist()
    assert [(e["length"], e["outcome"], e["seed"]) for e in episodes] == [
        (30, "truncated", 0),
        (30, "truncated", None),
        (13, "incomplete", None),
    ]
    resets = ev.resets()
    first = [np.asarray(o, np.float32) for o in resets["observation"].to_pylist()]
    assert np.array_equal(first[1], returned[30]) and np.array_equal(first[2], returned[61])
    assert resets["rng_state"].to_pylist()[1] is not None
    assert ev.steps().num_rows == 73


def test_custom_success_rule_and_unlabeled_failure(tmp_path: Path) -> None:
    env = ScriptedEnv(
        step_fn=lambda e, a: (np.zeros(2, np.float32), 1.0, True, False, {"goal": e.t > 1})
    )
    path = tmp_path / "rules.mcap"
    with RecordEvidence(env, path, ending_rules=EndingRules(success_fn=lambda i: i["goal"])) as rec:
        rec.reset(seed=0)
        rec.step(0)
        rec.reset(seed=0)
        rec.step(0)
    outcomes = open_evidence(path).episodes().select(["outcome", "failure_label"]).to_pylist()
    assert outcomes == [
        {"outcome": "failure", "failure_label": "unlabeled"},
        {"outcome": "failure", "failure_label": "unlabeled"},
    ]


def test_existing_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "keep.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(
        ConfigurationError,
        match=r"file exists; evidence is never overwritten — choose another path \(the template "
        r"'keep-\{index\}\.mcap' takes the first free one\)",
    ):
        RecordEvidence(gym.make("CartPole-v1"), path)
    assert path.read_bytes() == b"precious"


def test_wrong_arguments_are_configuration_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="block_steps: expected an integer >= 1"):
        RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap", block_steps=0)
    with pytest.raises(ConfigurationError, match="reward terms source"):
        RecordEvidence(gym.make("CartPole-v1"), tmp_path / "b.mcap", reward_terms="everything")


@pytest.mark.parametrize(
    ("path", "message"),
    [
        (
            b"a.mcap",
            r"^path: expected a path \(a str or pathlib\.Path\), got b'a\.mcap' \(bytes\); pass",
        ),
        (None, r"^path: expected a path \(a str or pathlib\.Path\), got None \(NoneType\); pass"),
        (
            "",
            r"^path: expected a path, got an empty string; pass a file's path",
        ),  # (not the current folder)
    ],
)
def test_a_path_that_is_not_one_is_a_configuration_error(
    path: Any, message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigurationError, match=message):
        RecordEvidence(gym.make("CartPole-v1"), path)
    with pytest.raises(ConfigurationError, match=message):
        RecordVectorEvidence(gym.make_vec("CartPole-v1", 2), path)
    assert list(tmp_path.iterdir()) == []


def test_wrapped_env_still_passes_check_env(tmp_path: Path) -> None:
    from gymnasium.utils.env_checker import check_env

    with RecordEvidence(gym.make("CartPole-v1").unwrapped, tmp_path / "c.mcap") as env:
        with warnings.catch_warnings():
            # advisory warnings about CartPole's own infinite bounds and about wrappers
            warnings.filterwarnings("ignore", message=".*different from the unwrapped version")
            warnings.filterwarnings("ignore", message=".*infinity")
            check_env(env, skip_render_check=True)


KILL_SCRIPT = """
import sys, time, gymnasium as gym
from episode_audit import RecordEvidence
env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], block_steps=300, flush_every_s=0.05)
env.reset(seed=0)
env.action_space.seed(0)
n = 0
while True:
    _, _, term, trunc, _ = env.step(env.action_space.sample())
    n += 1
    if term or trunc:
        env.reset()
    if n % 500 == 0:
        env.flush()
        print(n, flush=True)
"""


def test_sigkill_mid_run_keeps_every_flushed_step(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(path)], stdout=subprocess.PIPE, text=True, cwd=REPO
    )
    assert proc.stdout is not None
    reported = 0
    deadline = time.monotonic() + 60
    while reported < 5000 and time.monotonic() < deadline:
        reported = int(proc.stdout.readline())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    assert reported >= 5000
    ev = open_evidence(path)
    assert not ev.finished and ev.torn
    # every count printed was flushed before the print
    assert ev.steps(columns=["episode"]).num_rows >= reported
    episodes = ev.episodes()
    assert episodes.num_rows > 10
    assert (
        episodes.filter(pa.compute.equal(episodes["ended"], True)).num_rows >= episodes.num_rows - 1
    )


def test_reset_options_are_recorded_once_and_used_by_replay(tmp_path: Path) -> None:
    import json

    from mcap.reader import make_reader

    from episode_audit import replay
    from episode_audit.format import names as fmt

    path = tmp_path / "options.mcap"
    options = {"low": -0.01, "high": 0.01}
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), path) as env:
        env.reset(seed=4, options=options)
        for _ in range(5):
            env.step(0)
    ev = open_evidence(path)
    assert json.loads(ev.resets()["options"][0].as_py()) == options
    assert json.loads(ev.episodes()["options"][0].as_py()) == options
    with open(path, "rb") as f:
        (record,) = [
            json.loads(m.data)
            for _, c, m in make_reader(f).iter_messages()
            if c.topic == fmt.TOPIC_EPISODE_END
        ]
    assert record["options"] == options
    assert replay([path]).count("identical") == 1


def test_the_wrapped_env_passes_gymnasiums_env_checker(tmp_path: Path) -> None:
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "different from the unwrapped version", inf bounds
        with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "checked.mcap") as env:
            check_env(env, skip_render_check=True)


@pytest.mark.parametrize("block_steps", [4, 8, 1000])
def test_rows_stepped_after_the_end_number_on_across_blocks(
    tmp_path: Path, block_steps: int
) -> None:
    """Their step indices went back to the episode's length at every new block (duplicate
    (episode, step) pairs); replay, which compares up to the recorded end, called such an
    episode diverged on its length."""
    from episode_audit import check, replay

    path = tmp_path / "after.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gymnasium's own "step after terminated" warning
        with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=block_steps) as env:
            env.reset(seed=0)
            for _ in range(40):
                env.step(0)  # CartPole ends after 11 of these; the loop steps on
    ev = open_evidence(path)
    (record,) = ev.episodes().to_pylist()
    assert (record["outcome"], record["length"]) == ("failure", 11)
    assert ev.steps(columns=["step"]).column("step").to_pylist() == list(range(40))
    assert [e.status for e in replay([path]).episodes] == ["identical"]
    found = [f for f in check([path]).findings if f.code == "step_after_end"]
    assert [(f.episode, f.severity) for f in found] == [(0, "error")]
