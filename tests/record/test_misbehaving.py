"""Misbehaving environments: the training loop keeps running (or sees only the env's own
exception), the file stays valid, the recorded values are what the env returned, and ``check``
flags each case with its own code."""

from __future__ import annotations

import enum
import json
import math
import re
import signal
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from mcap.reader import make_reader
from pettingzoo import AECEnv, ParallelEnv

from episode_audit import EndingRules, RecordEvidence, check, open_evidence
from episode_audit.check import Finding
from episode_audit.record.writer import EvidenceWriter
from tests.support.envs import ScriptedEnv

ZEROS = np.zeros(2, np.float32)


def loop(env: gym.Env[Any, Any], episodes: int = 2, steps: int = 4) -> list[tuple[Any, ...]]:
    """A user's training loop: resets with seeds, steps, returns every step's 5-tuple."""
    results = []
    for e in range(episodes):
        env.reset(seed=e)
        for _ in range(steps):
            result = env.step(env.action_space.sample())
            results.append(result)
            if result[2] or result[3]:
                break
    return results


def assert_valid(path: Path) -> None:
    """Finished for episode-audit, and readable end to end by mcap's own indexed reader."""
    assert open_evidence(path).finished
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        assert sum(1 for _ in reader.iter_messages()) > 0


def findings(path: Path, code: str) -> list[Finding]:
    return [f for f in check([path]).findings if f.code == code]


def steps_of(path: Path) -> list[dict[str, Any]]:
    return open_evidence(path).steps().to_pylist()


def scripted(path: Path, step_fn: Any, reset_fn: Any = None, **kwargs: Any) -> RecordEvidence:
    env = RecordEvidence(ScriptedEnv(step_fn=step_fn, reset_fn=reset_fn), path, **kwargs)
    env.action_space.seed(0)
    return env


# ---------------------------------------------------------------------------------- exceptions


def test_env_raising_in_step_reraises_the_same_exception_and_the_loop_goes_on(
    tmp_path: Path,
) -> None:
    boom = RuntimeError("simulator exploded")

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        if env.t == 3 and env.raise_once:
            env.raise_once = False
            raise boom
        return ZEROS, 1.0, env.t == 4, False, {}

    path = tmp_path / "step.mcap"
    inner = ScriptedEnv(step_fn=step)
    inner.raise_once = True  # type: ignore[attr-defined]
    with RecordEvidence(inner, path) as env:
        env.reset(seed=0)
        env.step(0)
        env.step(0)
        with pytest.raises(RuntimeError) as raised:
            env.step(1)
        assert raised.value is boom
        assert len(loop(env, episodes=1)) == 4  # the user's loop carries on
    assert_valid(path)
    ev = open_evidence(path)
    assert ev.error_actions().to_pylist() == [{"episode": 0, "action": 1}]  # (for replay)
    first, second = ev.episodes().to_pylist()
    assert (first["outcome"], first["length"], first["error_type"], first["error_message"]) == (
        "error",
        2,
        "RuntimeError",
        "simulator exploded",
    )
    assert second["outcome"] == "failure" and second["length"] == 4
    assert findings(path, "error_episode") == [
        Finding(
            "error",
            "error_episode",
            "the environment raised RuntimeError while taking step 2: simulator exploded",
            str(path),
            0,
            2,
        )
    ]


def test_env_raising_in_reset_reraises_the_same_exception_and_the_loop_goes_on(
    tmp_path: Path,
) -> None:
    boom = ValueError("bad reset")

    def reset(env: ScriptedEnv) -> tuple[Any, ...]:
        if env.np_random_seed == 13:
            raise boom
        return ZEROS, {}

    path = tmp_path / "reset.mcap"
    with scripted(path, None, reset) as env:
        with pytest.raises(ValueError, match="bad reset") as raised:
            env.reset(seed=13)
        assert raised.value is boom
        assert len(loop(env, episodes=1)) == 4
    assert_valid(path)
    first, second = open_evidence(path).episodes().to_pylist()
    assert (first["outcome"], first["error_during"], first["length"]) == ("error", "reset", 0)
    assert second["outcome"] == "incomplete"
    (finding,) = findings(path, "error_episode")
    assert finding == Finding(
        "error",
        "error_episode",
        "the environment raised ValueError during reset: bad reset",
        str(path),
        0,
        None,
    )


def test_keyboard_interrupt_in_step_is_not_swallowed_and_the_episode_stays_incomplete(
    tmp_path: Path,
) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        if env.t == 2:
            raise KeyboardInterrupt
        return ZEROS, 1.0, False, False, {}

    path = tmp_path / "interrupt.mcap"
    env = scripted(path, step)
    env.reset(seed=0)
    env.step(0)
    with pytest.raises(KeyboardInterrupt):
        env.step(0)
    env.close()
    assert_valid(path)
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert (episode["outcome"], episode["length"]) == ("incomplete", 1)
    assert [f.code for f in findings(path, "incomplete_episode")] == ["incomplete_episode"]


@pytest.mark.usefixtures("ctrl_c")
@pytest.mark.parametrize("where", ["step", "close"])
def test_ctrl_c_during_a_flush_is_raised_once_the_flush_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    # a Ctrl-C inside a flush dropped rows already counted into their episodes
    path = tmp_path / "interrupted.mcap"
    write_batch = EvidenceWriter.write_batch
    armed = [True]

    def interrupted(self: EvidenceWriter, *args: Any) -> int:
        if armed[0]:
            armed[0] = False
            signal.raise_signal(signal.SIGINT)  # (its handler runs at the next bytecode)
        return write_batch(self, *args)

    env = RecordEvidence(gym.make("CartPole-v1"), path, block_steps=16)
    env.reset(seed=0)
    taken = [0]

    def run(steps: int, action: int) -> None:
        for _ in range(steps):
            taken[0] += 1
            if env.step(action)[2]:
                env.reset()

    monkeypatch.setattr(EvidenceWriter, "write_batch", interrupted)
    if where == "close":
        run(1, 0)
        with pytest.raises(KeyboardInterrupt):
            env.close()
    else:
        with pytest.raises(KeyboardInterrupt):  # (from the step whose flush it came in)
            run(40, 0)
        run(40, 1)
        env.close()
    assert not armed[0]
    assert_valid(path)
    result = check([path])
    assert result.ok and result.steps == taken[0], [f.message for f in result.findings]


def test_env_raising_in_close_still_finishes_the_file(tmp_path: Path) -> None:
    class BadClose(ScriptedEnv):
        def close(self) -> None:
            raise OSError("display gone")

    path = tmp_path / "close.mcap"
    env = RecordEvidence(BadClose(), path)
    loop(env, episodes=1)
    with pytest.raises(OSError, match="display gone"):
        env.close()
    assert_valid(path)
    assert open_evidence(path).episodes().num_rows == 1


# ---------------------------------------------------------------------------------- rewards


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_reward_from_a_real_wrapper_is_kept_and_flagged(
    tmp_path: Path, bad: float
) -> None:
    path = tmp_path / "reward.mcap"
    inner = gym.wrappers.TransformReward(gym.make("CartPole-v1"), lambda r: bad if r else r)
    with RecordEvidence(inner, path) as env:
        env.action_space.seed(0)
        results = loop(env, episodes=2, steps=3)
    assert all(r[1] is bad for r in results)  # the env's value reached the loop untouched
    assert_valid(path)
    rewards = [s["reward"] for s in steps_of(path)]
    assert len(rewards) == 6
    assert all(math.isnan(r) for r in rewards) if math.isnan(bad) else rewards == [bad] * 6
    found = findings(path, "nonfinite_reward")
    assert [(f.severity, f.episode, f.step) for f in found] == [("error", 0, 0), ("error", 1, 0)]
    assert found[0].message == f"reward {bad} at step 0; 3 step(s) of the episode"


@pytest.mark.parametrize("bad", ["one", "1.5", None, [1.0, 2.0], np.array([1.5])])
def test_non_numeric_reward_is_recorded_as_nan_and_noted(tmp_path: Path, bad: Any) -> None:
    path = tmp_path / "reward.mcap"
    with scripted(path, lambda e, a: (ZEROS, bad if e.t == 2 else 1.0, False, False, {})) as env:
        results = loop(env, episodes=1)
    assert results[1][1] is bad
    assert_valid(path)
    steps = steps_of(path)
    assert [s["reward"] for s in steps][::2] == [1.0, 1.0]
    assert math.isnan(steps[1]["reward"])
    assert steps[1]["notes"] == f'["reward_not_numeric: reward {bad!r}"]'
    (noted,) = findings(path, "recorder_note:reward_not_numeric")
    assert noted == Finding(
        "warning",
        "recorder_note:reward_not_numeric",
        f"recorder noted reward_not_numeric at step 1 (1 time(s) in the episode): reward {bad!r}",
        str(path),
        0,
        1,
    )
    assert [(f.episode, f.step) for f in findings(path, "nonfinite_reward")] == [(0, 1)]


def test_a_tensor_reads_as_an_array_does(tmp_path: Path) -> None:
    """A one-element tensor is not a number (as a numpy array of shape (1,) is not); a 0-d
    one is (as a 0-d array is)."""
    torch = pytest.importorskip("torch")
    rewards = {0: torch.tensor([1.5]), 1: torch.tensor(2.5)}

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        terms = {"a": torch.tensor([1.0]) if env.t == 1 else 1.0}
        return ZEROS, rewards.get(env.t - 1, 1.0), False, False, {"reward_terms": terms}

    path = tmp_path / "tensor.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1)
    steps = steps_of(path)
    assert math.isnan(steps[0]["reward"]) and steps[1]["reward"] == 2.5
    assert steps[0]["notes"].startswith('["reward_not_numeric: reward tensor([1.5')
    assert math.isnan(dict(steps[0]["terms"])["a"])
    assert "term_not_numeric" in steps[0]["notes"]


# ---------------------------------------------------------------------------------- reward terms


@pytest.mark.parametrize("bad", ["x", "2.0", None, {"nested": 1}, np.array([2.0])])
def test_non_numeric_reward_term_is_recorded_as_nan_and_noted(tmp_path: Path, bad: Any) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 1.0, False, False, {"reward_terms": {"a": bad, "b": 1.0}}

    path = tmp_path / "term.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1, steps=2)
    assert_valid(path)
    terms = dict(steps_of(path)[0]["terms"])
    assert math.isnan(terms["a"]) and terms["b"] == 1.0
    (noted,) = findings(path, "recorder_note:term_not_numeric")
    assert noted.message == (
        f"recorder noted term_not_numeric at step 0 (2 time(s) in the episode): term 'a' is {bad!r}"
    )
    (nonfinite,) = findings(path, "nonfinite_term")
    assert nonfinite.message == "term 'a' is nan at step 0; 2 step(s) of the episode"
    assert findings(path, "terms_sum_mismatch") == []  # a NaN term is not also a mismatch


@pytest.mark.parametrize("bad_at", [0, 1])
def test_non_numeric_prefixed_term_leaves_the_other_steps_aligned(
    tmp_path: Path, bad_at: int
) -> None:
    # MuJoCo-style reward_* keys take the recorder's fastest path, which writes a step's term
    # values before it knows the whole step is fine: a bad value in either position is rolled
    # back and the step recorded (NaN + note) on the slow path; its neighbours are untouched.
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        values: list[Any] = [0.25 * env.t, -1.0]
        if env.t == 2:
            values[bad_at] = "oops"
        return ZEROS, 1.0, False, False, {"reward_a": values[0], "reward_b": values[1]}

    path = tmp_path / "prefixed.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1, steps=4)
    assert_valid(path)
    terms = [dict(s["terms"]) for s in steps_of(path)]
    assert [list(t) for t in terms] == [["reward_a", "reward_b"]] * 4
    assert [t["reward_a"] for t in terms][::2] == [0.25, 0.75]
    assert terms[3] == {"reward_a": 1.0, "reward_b": -1.0}
    assert math.isnan(terms[1]["reward_a" if bad_at == 0 else "reward_b"])
    name = "reward_a" if bad_at == 0 else "reward_b"
    (noted,) = findings(path, "recorder_note:term_not_numeric")
    assert noted.message == (
        f"recorder noted term_not_numeric at step 1 (1 time(s) in the episode): "
        f"term '{name}' is 'oops'"
    )
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert dict(episode["term_totals"])["reward_b" if bad_at == 0 else "reward_a"] == (
        -4.0 if bad_at == 0 else 2.5
    )


def test_prefixed_terms_then_an_invalid_observation_record_the_terms_once(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        obs = np.zeros(5, np.float32) if env.t == 2 else ZEROS  # does not fit the space
        return obs, 1.0, False, False, {"reward_a": float(env.t)}

    path = tmp_path / "obs.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1, steps=3)
    steps = steps_of(path)
    assert [dict(s["terms"]) for s in steps] == [{"reward_a": float(t)} for t in (1, 2, 3)]
    assert steps[1]["observation"] is None and "observation_invalid" in steps[1]["notes"]
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert dict(episode["term_totals"]) == {"reward_a": 6.0}


def test_terms_read_right_when_the_info_keys_change_from_step_to_step(tmp_path: Path) -> None:
    infos: list[dict[str, Any]] = [
        {"reward_a": 1.0, "x": 0},
        {"reward_a": 2.0, "reward_b": np.float32(0.5)},
        {"x": 1},  # no terms
        {},
        {"reward_b": np.float64(3.0), "reward_a": 4},  # other order
        {"reward_a": 5.0, "x": 0},  # the first keys again
    ]

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 1.0, False, False, infos[env.t - 1]

    path = tmp_path / "keys.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1, steps=len(infos))
    terms = [s["terms"] for s in steps_of(path)]
    assert terms == [
        [("reward_a", 1.0)],
        [("reward_a", 2.0), ("reward_b", 0.5)],
        None,
        None,
        [("reward_b", 3.0), ("reward_a", 4.0)],
        [("reward_a", 5.0)],
    ]
    assert open_evidence(path).episodes().to_pylist()[0]["notes"] == 0


def test_terms_from_a_list_of_info_keys_are_read_once_each_in_the_list_order(
    tmp_path: Path,
) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 1.0, False, False, {"ctrl": -0.5, "progress": 1.5, "other": 9.0}

    path = tmp_path / "listed.mcap"
    with scripted(path, step, reward_terms=["progress", "missing", "ctrl", "progress"]) as env:
        loop(env, episodes=1, steps=2)
    assert [s["terms"] for s in steps_of(path)] == [[("progress", 1.5), ("ctrl", -0.5)]] * 2


def test_nan_reward_term_is_kept_and_flagged(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        a = math.nan if env.t == 3 else 0.5
        return ZEROS, 1.0, False, False, {"reward_terms": {"a": a, "b": 0.5}}

    path = tmp_path / "term.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1)
    assert_valid(path)
    steps = steps_of(path)
    assert math.isnan(dict(steps[2]["terms"])["a"]) and steps[2]["notes"] is None
    message = "term 'a' is nan at step 2; 1 step(s) of the episode"
    expected = Finding("error", "nonfinite_term", message, str(path), 0, 2)
    assert findings(path, "nonfinite_term") == [expected]
    assert findings(path, "terms_sum_mismatch") == []


# ---------------------------------------------------------------------------------- observations


def test_observation_outside_its_space_is_kept_exactly_and_flagged(tmp_path: Path) -> None:
    outside = np.array([5.0, -7.5], np.float32)

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return (outside if env.t == 2 else ZEROS), 0.0, False, False, {}

    path = tmp_path / "obs.mcap"
    with scripted(path, step, lambda e: (outside, {})) as env:
        loop(env, episodes=1)
    assert_valid(path)
    assert steps_of(path)[1]["observation"] == [5.0, -7.5]
    found = findings(path, "observation_out_of_space")
    assert [(f.episode, f.step) for f in found] == [(0, None), (0, 1)]  # reset, then step 1
    assert found[1].message == (
        "observation outside its space at step 1: array([ 5. , -7.5], dtype=float32); "
        "1 row(s) of the episode"
    )


def test_observation_of_the_wrong_dtype_from_a_real_wrapper_is_cast_and_noted(
    tmp_path: Path,
) -> None:
    base = gym.make("CartPole-v1")
    inner = gym.wrappers.TransformObservation(
        base, lambda obs: obs.astype(np.float64), base.observation_space
    )
    path = tmp_path / "dtype.mcap"
    with RecordEvidence(inner, path) as env:
        env.action_space.seed(0)
        results = loop(env, episodes=1, steps=3)
    assert results[0][0].dtype == np.float64  # the loop got the env's own observation
    assert_valid(path)
    recorded = [np.array(s["observation"], np.float32) for s in steps_of(path)]
    for got, (obs, *_) in zip(recorded, results, strict=True):
        assert np.array_equal(got, obs.astype(np.float32))  # cast to the space's dtype
    at_reset, at_steps = findings(path, "recorder_note:observation_cast")
    assert (at_reset.step, at_steps.step) == (None, 0)
    assert at_steps.message == (
        "recorder noted observation_cast at step 0 (3 time(s) in the episode): "
        "dtype float64 cast to float32"
    )


def test_observation_of_the_wrong_shape_is_null_and_noted(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return (np.zeros(3, np.float32) if env.t == 1 else ZEROS), 0.0, False, False, {}

    path = tmp_path / "shape.mcap"
    with scripted(path, step) as env:
        loop(env, episodes=1)
    assert_valid(path)
    steps = steps_of(path)
    assert steps[0]["observation"] is None and steps[1]["observation"] == [0.0, 0.0]
    (noted,) = findings(path, "recorder_note:observation_invalid")
    assert (noted.episode, noted.step) == (0, 0)
    assert noted.message.endswith("Expect shape (2,), actually: shape (3,) (ndarray)")


# ---------------------------------------------------------------------------------- info


@pytest.mark.parametrize("keep", [(), ["a"], "all"])
@pytest.mark.parametrize("info", [None, [], ["a"], "text", (1, 2)])
def test_non_dict_info_is_noted_and_an_ending_with_it_does_not_raise(
    tmp_path: Path, info: Any, keep: Any
) -> None:
    path = tmp_path / "info.mcap"
    step = lambda e, a: (ZEROS, 1.0, e.t == 3, False, info)  # noqa: E731
    with scripted(path, step, info_keys=keep) as env:  # (noted once, kept info or not)
        results = loop(env, episodes=2)
    assert all(r[4] is info for r in results)
    assert_valid(path)
    assert [e["outcome"] for e in open_evidence(path).episodes().to_pylist()] == ["failure"] * 2
    notes = [s["notes"] for s in steps_of(path)]
    assert notes == [f'["info_not_dict: info is a {type(info).__name__}"]'] * 6
    found = findings(path, "recorder_note:info_not_dict")
    assert [(f.episode, f.step, f.severity) for f in found] == [
        (0, 0, "warning"),
        (1, 0, "warning"),
    ]


def test_info_keys_changing_between_steps_are_recorded_and_noted(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        info: dict[str, Any] = {"x": env.t}
        if env.t >= 3:
            info["contact"] = True
        if env.t == 4:
            del info["x"]
        return ZEROS, 1.0, False, False, info

    path = tmp_path / "keys.mcap"
    with scripted(path, step, info_keys="all") as env:
        loop(env, episodes=2)
    assert_valid(path)
    assert [s["info"] for s in steps_of(path)][:4] == [
        '{"x":1}',
        '{"x":2}',
        '{"x":3,"contact":true}',
        '{"contact":true}',
    ]
    assert findings(path, "info_keys_changed") == [
        Finding(
            "note",
            "info_keys_changed",
            "info keys changed between steps in 2 episode(s) (episodes 0, 1); first at step 2 "
            "of episode 0: added ['contact'], removed []",
            str(path),
            0,
            2,
        )
    ]
    assert check([path]).ok  # a note, not an error


def test_reward_term_names_changing_between_steps_are_recorded_and_noted(tmp_path: Path) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        terms = {"progress": 0.5, "ctrl": 0.5} if env.t < 4 else {"progress": 0.5, "bonus": 0.5}
        return ZEROS, 1.0, False, False, {"reward_terms": terms}

    path = tmp_path / "terms.mcap"
    # one step per block: the change is found across block boundaries too
    with scripted(path, step, block_steps=1) as env:
        loop(env, episodes=1, steps=5)
    assert_valid(path)
    assert [sorted(dict(s["terms"])) for s in steps_of(path)][2:4] == [
        ["ctrl", "progress"],
        ["bonus", "progress"],
    ]
    assert findings(path, "terms_keys_changed") == [
        Finding(
            "note",
            "terms_keys_changed",
            "reward-term keys changed between steps in 1 episode(s) (episodes 0); first at "
            "step 3 of episode 0: added ['bonus'], removed ['ctrl']",
            str(path),
            0,
            3,
        )
    ]
    assert findings(path, "terms_sum_mismatch") == []


def test_reset_info_without_the_step_keys_is_not_a_change(tmp_path: Path) -> None:
    """Gymnasium MuJoCo v5: the reset info lacks the step info's reward_* keys (Minari #191)."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 1.0, False, False, {"reward_run": 0.75, "reward_ctrl": 0.25, "x": 1}

    path = tmp_path / "mujoco_like.mcap"
    with scripted(path, step, lambda e: (ZEROS, {"x": 0}), info_keys="all") as env:
        loop(env, episodes=2)
    assert_valid(path)
    codes = {f.code for f in check([path]).findings}
    assert not codes & {"terms_keys_changed", "info_keys_changed", "terms_sum_mismatch"}


# ---------------------------------------------------------------------------------- related


def test_old_four_tuple_step_api_is_noted_not_raised(tmp_path: Path) -> None:
    path = tmp_path / "old_api.mcap"
    with scripted(path, lambda e, a: (ZEROS, 1.0, False, {})) as env:
        env.reset(seed=0)
        assert env.step(0) == (ZEROS, 1.0, False, {})  # handed back untouched
    assert_valid(path)
    (noted,) = findings(path, "recorder_note:step_result_invalid")
    assert noted.message.startswith(
        "recorder noted step_result_invalid at step 0 (1 time(s) in the episode): "
        "step() returned (array([0., 0.], dtype=float32), 1.0, False, {})"
    )


def test_flags_that_are_not_booleans_are_noted(tmp_path: Path) -> None:
    flags = np.array([True, False])
    path = tmp_path / "flags.mcap"
    with scripted(path, lambda e, a: (ZEROS, 1.0, flags, False, {})) as env:
        env.reset(seed=0)
        env.step(0)
    assert_valid(path)
    (noted,) = findings(path, "recorder_note:flags_not_bool")
    assert (noted.episode, noted.step) == (0, 0)
    assert steps_of(path)[0]["terminated"] is False


def test_action_outside_its_space_is_kept_and_flagged(tmp_path: Path) -> None:
    path = tmp_path / "action.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        env.step(1)
        with pytest.raises(AssertionError):  # CartPole's own check: its exception, re-raised
            env.step(7)
    assert_valid(path)
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert (episode["outcome"], episode["error_type"]) == ("error", "AssertionError")


# ------------------------------------------------------------- text UTF-8 cannot encode, odd infos

SURROGATE = "\udcff"  # what os.fsdecode makes of a byte that is not UTF-8


@pytest.mark.parametrize("where", ["failure", "truncation_reason", "term"])
def test_text_utf8_cannot_encode_is_stored_escaped_and_nothing_is_lost(
    tmp_path: Path, where: str
) -> None:
    bad = f"hit{SURROGATE}"

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        end = env.t == 3
        info: dict[str, Any] = {}
        if end and where == "failure":
            info = {"failure": bad}
        elif end and where == "truncation_reason":
            info = {"truncation_reason": bad}
        elif where == "term":
            info = {"reward_terms": {bad: 1.0}}
        return (
            ZEROS,
            1.0,
            end and where != "truncation_reason",
            end and where == "truncation_reason",
            info,
        )

    path = tmp_path / "text.mcap"
    with scripted(path, step, block_steps=2) as env:  # a flush every other step
        results = loop(env, episodes=3)
    assert len(results) == 9
    assert_valid(path)
    episodes = open_evidence(path).episodes().to_pylist()
    assert [e["length"] for e in episodes] == [3, 3, 3]
    escaped = "hit\\udcff"
    if where == "failure":
        assert [e["failure_label"] for e in episodes] == [escaped] * 3
    elif where == "truncation_reason":
        assert [e["truncation_reason"] for e in episodes] == [escaped] * 3
    else:
        assert [e["term_totals"] for e in episodes] == [[(escaped, 3.0)]] * 3
    assert check([path]).steps == 9


def test_an_env_error_whose_message_utf8_cannot_encode_reaches_the_loop_itself(
    tmp_path: Path,
) -> None:
    class Unprintable(Exception):
        def __str__(self) -> str:
            raise RuntimeError("no str")

    errors = [ValueError(f"cannot load level-{SURROGATE}.json"), Unprintable()]

    def reset(env: ScriptedEnv) -> tuple[Any, ...]:
        if env.np_random_seed in (0, 1):
            raise errors[env.np_random_seed]
        return ZEROS, {}

    path = tmp_path / "reset.mcap"
    with scripted(path, None, reset) as env:
        for seed, error in enumerate(errors):
            with pytest.raises(type(error)) as raised:
                env.reset(seed=seed)
            assert raised.value is error
    assert_valid(path)
    records = open_evidence(path).episodes().to_pylist()
    assert [
        (e["outcome"], e["error_type"].rpartition(".")[2], e["error_message"]) for e in records
    ] == [
        ("error", "ValueError", "cannot load level-\\udcff.json"),
        ("error", "Unprintable", "<str() raised RuntimeError>"),
    ]


@pytest.mark.parametrize(
    "success", [np.array([True, False]), "fn"], ids=["ambiguous_array", "raising_success_fn"]
)
def test_an_unreadable_success_value_ends_the_episode_by_its_flags_and_is_noted(
    tmp_path: Path, success: Any
) -> None:
    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        info = {} if isinstance(success, str) else {"success": success}
        return ZEROS, 1.0, env.t == 3, False, info

    def broken(info: Any) -> bool:
        raise KeyError("goal")

    kwargs = {"ending_rules": EndingRules(success_fn=broken)} if isinstance(success, str) else {}
    path = tmp_path / "success.mcap"
    with scripted(path, step, **kwargs) as env:
        assert len(loop(env, episodes=2)) == 6
    assert_valid(path)
    episodes = open_evidence(path).episodes().to_pylist()
    assert [(e["outcome"], e["failure_label"], e["length"]) for e in episodes] == [
        ("failure", "unlabeled", 3)
    ] * 2
    assert [e["notes"] for e in episodes] == [1, 1]
    noted = findings(path, "recorder_note:ending_unreadable")
    why = "The truth value of an array" if not kwargs else "KeyError: 'goal'"
    assert [(f.episode, f.step) for f in noted] == [(0, 2), (1, 2)]
    assert all(why in f.message for f in noted)


@pytest.mark.parametrize("shape", ["cycle", "deep", "bad_repr_key"])
def test_an_info_value_json_cannot_hold_is_noted_when_info_is_kept(
    tmp_path: Path, shape: str
) -> None:
    class BadRepr:
        def __repr__(self) -> str:
            raise RuntimeError("no repr")

        def __hash__(self) -> int:
            return 1

    def value() -> Any:
        if shape == "cycle":
            node: dict[str, Any] = {"name": "root"}
            node["self"] = node
            return node
        if shape == "deep":  # deeper than any Python's json encodes (3.13's C limit: 10 000)
            deep: list[Any] = []
            for _ in range(100_000):
                deep = [deep]
            return deep
        return {BadRepr(): 1}

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        info = {"t": env.t, "odd": value()} if env.t == 2 else {"t": env.t}
        return ZEROS, 1.0, env.t == 3, False, info

    path = tmp_path / "info.mcap"
    with scripted(path, step, info_keys="all", block_steps=2) as env:
        assert len(loop(env, episodes=3)) == 9
    assert_valid(path)
    assert [e["length"] for e in open_evidence(path).episodes().to_pylist()] == [3, 3, 3]
    assert len(findings(path, "recorder_note:info_unserializable")) == 3  # one per episode


def test_a_reset_that_returns_no_obs_info_pair_is_passed_through_and_noted(
    tmp_path: Path,
) -> None:
    extra = (ZEROS, {}, "extra")
    path = tmp_path / "reset.mcap"
    with scripted(path, None, lambda env: extra) as env:
        assert env.reset(seed=0) is extra
        env.step(0)
    assert_valid(path)
    (finding,) = findings(path, "recorder_note:reset_result_invalid")
    assert "reset() returned (array([0., 0.], dtype=float32), {}, 'extra')" in finding.message


def test_a_flush_that_fails_mid_loop_is_warned_once_and_never_reaches_the_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Fault injection: the disk fills up after the file was created."""
    from episode_audit.record.writer import EvidenceWriter

    def full(*args: Any, **kwargs: Any) -> int:
        raise OSError(28, "No space left on device")

    env = scripted(tmp_path / "full.mcap", None, block_steps=2)
    monkeypatch.setattr(EvidenceWriter, "write_batch", full)
    with pytest.warns(RuntimeWarning, match=r"full\.mcap failed \(OSError: .*No space left") as w:
        assert len(loop(env, episodes=3)) == 12
    assert len(w) == 1
    monkeypatch.undo()
    env.close()
    ev = open_evidence(tmp_path / "full.mcap")
    assert ev.finished
    # the file says so: the run-end record counts the failures, and check reports them
    assert ev.run_end is not None and int(ev.run_end["recorder_trouble"]) >= 1
    assert "No space left on device" in ev.run_end["recorder_trouble_first"]
    (trouble,) = [
        f for f in check([tmp_path / "full.mcap"]).findings if f.code == "recorder_trouble"
    ]
    assert trouble.severity == "error"
    assert re.match(
        r"the recorder failed inside itself \d+ time\(s\) while recording \(first: OSError: "
        r".*No space left on device\); the evidence may miss what it was recording then$",
        trouble.message,
    ), trouble.message


@pytest.mark.parametrize(
    "flag", ["False", 1, np.int64(1), [0]], ids=["text", "int", "np_int", "list"]
)
def test_a_true_flag_that_is_not_a_bool_ends_the_episode_and_is_noted(
    tmp_path: Path, flag: Any
) -> None:
    """Taken by its truth value (the text "False" is true), and the step says so."""
    path = tmp_path / "flags.mcap"
    with scripted(path, lambda e, a: (ZEROS, 1.0, flag if e.t == 2 else False, False, {})) as env:
        env.reset(seed=0)
        for _ in range(2):
            env.step(0)
    assert_valid(path)
    (noted,) = findings(path, "recorder_note:flags_not_bool")
    assert (noted.episode, noted.step) == (0, 1) and "taken by their truth value" in noted.message
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert (episode["outcome"], episode["terminated"], episode["length"]) == ("failure", True, 2)


def test_numpy_bool_flags_are_not_noted(tmp_path: Path) -> None:
    path = tmp_path / "flags.mcap"
    with scripted(path, lambda e, a: (ZEROS, 1.0, np.bool_(e.t == 2), np.False_, {})) as env:
        env.reset(seed=0)
        for _ in range(2):
            env.step(0)
    assert findings(path, "recorder_note:flags_not_bool") == []


# ------------------------------------------------------------------ endings read from info


def noted(path: Path, code: str) -> list[tuple[int, int, str]]:
    """``(episode, step, message)`` of each recorder note ``code`` in the steps' notes column."""
    found = []
    for row in steps_of(path):
        for item in json.loads(row["notes"] or "[]"):
            if item.startswith(code + ": "):
                found.append((row["episode"], row["step"], item.removeprefix(code + ": ")))
    return found


def record_ending(path: Path, info: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    """One episode of three steps ending by ``terminated`` with ``info``; its record."""
    with scripted(path, lambda e, a: (ZEROS, 1.0, e.t == 3, False, info), **kwargs) as env:
        assert len(loop(env, episodes=1)) == 3
    assert_valid(path)
    (episode,) = open_evidence(path).episodes().to_pylist()
    return dict(episode)


class Colour(enum.Enum):
    RED = 1


@pytest.mark.parametrize(
    ("value", "outcome", "shown"),
    [
        ("no", "success", r"'no' \(str\)"),
        ("False", "success", r"'False' \(str\)"),
        ([0], "success", r"\[0\] \(list\)"),
        ({"done": False}, "success", r"\{'done': False\} \(dict\)"),
        ("", "failure", r"'' \(str\)"),
        (math.nan, "success", r"nan \(float\)"),
    ],
    ids=["no", "False", "list", "dict", "empty_text", "nan"],
)
@pytest.mark.parametrize("key", ["success", "is_success"])
def test_a_success_value_that_is_not_a_bool_or_a_number_is_taken_by_its_truth_and_noted(
    tmp_path: Path, key: str, value: Any, outcome: str, shown: str
) -> None:
    """Classified as before (so old files replay the same), and the final step says why."""
    path = tmp_path / "success.mcap"
    episode = record_ending(path, {key: value})
    assert (episode["outcome"], episode["notes"]) == (outcome, 1)
    taken = "a success" if outcome == "success" else "not a success"
    ((ep, step, message),) = noted(path, "success_not_bool")
    assert (ep, step) == (0, 2)
    assert re.fullmatch(
        rf"info\['{key}'\] is {shown}: taken by its truth value as {taken}", message
    )
    (finding,) = findings(path, "recorder_note:success_not_bool")
    assert (finding.severity, finding.episode, finding.step) == ("warning", 0, 2)
    assert message in finding.message


@pytest.mark.parametrize(("value", "outcome"), [("yes", "success"), (None, "failure")])
def test_a_success_fn_that_returns_no_bool_or_number_is_taken_by_its_truth_and_noted(
    tmp_path: Path, value: Any, outcome: str
) -> None:
    path = tmp_path / "success_fn.mcap"
    episode = record_ending(path, {}, ending_rules=EndingRules(success_fn=lambda info: value))
    assert episode["outcome"] == outcome
    ((_, step, message),) = noted(path, "success_not_bool")
    assert step == 2
    assert re.fullmatch(r"success_fn returned \S+ \(\w+\): taken by its truth value as .+", message)
    assert findings(path, "recorder_note:success_not_bool") != []


@pytest.mark.parametrize(
    ("value", "outcome"),
    [
        (True, "success"),
        (np.True_, "success"),
        (np.False_, "failure"),
        (1.0, "success"),
        (0.0, "failure"),
        (np.float32(1.0), "success"),  # Gymnasium-Robotics' is_success
        (np.float64(0.0), "failure"),
        (1, "success"),
        (np.int64(0), "failure"),
        (np.array(1.0, np.float32), "success"),  # a 0-d array: one truth value
        (None, "failure"),  # no success value at all
    ],
)
def test_success_values_that_are_bools_or_numbers_are_not_noted(
    tmp_path: Path, value: Any, outcome: str
) -> None:
    path = tmp_path / "success.mcap"
    assert record_ending(path, {"is_success": value})["outcome"] == outcome
    assert noted(path, "success_not_bool") == []
    assert findings(path, "recorder_note:success_not_bool") == []


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        (3, r"3 \(int\)"),
        (Colour.RED, r"<Colour\.RED: 1> \(Colour\)"),
        (["door"], r"\['door'\] \(list\)"),
        (b"door", r"b'door' \(bytes\)"),
        (np.array([1, 2]), r"array\(\[1, 2\]\) \(ndarray\)"),  # no truth value: still unlabeled
    ],
    ids=["int", "enum", "list", "bytes", "array"],
)
def test_a_failure_label_that_is_not_text_is_unlabeled_and_noted(
    tmp_path: Path, value: Any, shown: str
) -> None:
    path = tmp_path / "label.mcap"
    episode = record_ending(path, {"failure": value})
    assert (episode["outcome"], episode["failure_label"], episode["notes"]) == (
        "failure",
        "unlabeled",
        1,
    )
    ((ep, step, message),) = noted(path, "failure_label_not_text")
    assert (ep, step) == (0, 2)
    assert re.fullmatch(
        rf"info\['failure'\] is {shown}: recorded as unlabeled; "
        r"give a string, or pass failure_fn",
        message,
    )
    (finding,) = findings(path, "recorder_note:failure_label_not_text")
    assert (finding.severity, finding.episode, finding.step) == ("warning", 0, 2)
    assert message in finding.message
    assert len(findings(path, "unlabeled_failure")) == 1


def test_a_failure_fn_that_returns_no_text_is_unlabeled_and_noted(tmp_path: Path) -> None:
    path = tmp_path / "label_fn.mcap"
    rules = EndingRules(failure_fn=lambda info: Colour.RED)
    assert record_ending(path, {}, ending_rules=rules)["failure_label"] == "unlabeled"
    ((_, step, message),) = noted(path, "failure_label_not_text")
    assert step == 2
    assert re.fullmatch(
        r"failure_fn returned <Colour\.RED: 1> \(Colour\): recorded as unlabeled; "
        r"return a string",
        message,
    )


@pytest.mark.parametrize(
    ("value", "label"),
    [
        (True, "unlabeled"),  # documented: a failure without a label
        (np.True_, "unlabeled"),
        ("", "unlabeled"),  # the text for "no label", like None
        (None, "unlabeled"),
        (0, "unlabeled"),
        ("door_slammed", "door_slammed"),
    ],
)
def test_failure_labels_that_are_text_or_say_no_label_are_not_noted(
    tmp_path: Path, value: Any, label: str
) -> None:
    path = tmp_path / "label.mcap"
    episode = record_ending(path, {"failure": value})
    assert (episode["outcome"], episode["failure_label"], episode["notes"]) == (
        "failure",
        label,
        0,
    )
    assert noted(path, "failure_label_not_text") == []


# ------------------------------------------------------------------ reward-term names


TERM_NAME_CASES: dict[str, tuple[dict[Any, float], list[tuple[str, float]], str | None]] = {
    # info["reward_terms"] -> the recorded terms of a step, and its terms_name_collision note
    "bytes": ({b"a": 0.5, "b": 0.25}, [("b'a'", 0.5), ("b", 0.25)], None),
    "int": ({0: 0.5, 1: 0.25}, [("0", 0.5), ("1", 0.25)], None),
    "collision": (
        {1: 0.5, "1": 0.25},
        [("1", 0.75)],
        r"keys 1, '1' share the name '1': recorded as one term, their sum",
    ),
    "bytes_collision": (
        {"b'a'": 0.5, "c": 0.0, b"a": 0.25},
        [("b'a'", 0.75), ("c", 0.0)],
        r"""keys "b'a'", b'a' share the name "b'a'": recorded as one term, their sum""",
    ),
}


@pytest.mark.parametrize("case", list(TERM_NAME_CASES))
def test_term_names_are_one_rule_on_both_recorder_paths_and_replay_identically(
    tmp_path: Path, case: str
) -> None:
    """The fast path (plain steps) and the slow path (``info_keys`` set) write the same names
    and values; names that collide are one term, their sum, noted; replay reads them so."""
    from episode_audit import replay

    terms, recorded, collision = TERM_NAME_CASES[case]

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 0.75, env.t == 3, False, {"reward_terms": dict(terms)}

    paths = {}
    for way, kwargs in (("fast", {}), ("slow", {"info_keys": ["nothing"]})):
        path = paths[way] = tmp_path / f"{way}.mcap"
        with scripted(path, step, **kwargs) as env:
            assert len(loop(env, episodes=2, steps=3)) == 6
        assert_valid(path)
        steps = steps_of(path)
        assert [row["terms"] for row in steps] == [recorded] * 6, way
        episodes = open_evidence(path).episodes().to_pylist()
        assert [e["term_totals"] for e in episodes] == [[(k, 3 * v) for k, v in recorded]] * 2
        notes = noted(path, "terms_name_collision")
        if collision is None:
            assert notes == [], way
        else:
            assert [(e, s) for e, s, _ in notes] == [(e, s) for e in (0, 1) for s in range(3)]
            assert all(re.fullmatch(collision, m) for _, _, m in notes), notes
            assert [e["notes"] for e in episodes] == [3, 3]
            found = findings(path, "recorder_note:terms_name_collision")
            assert [(f.severity, f.episode, f.step) for f in found] == [
                ("warning", 0, 0),
                ("warning", 1, 0),
            ]
        assert findings(path, "terms_sum_mismatch") == []
        result = replay([path], env_factory=lambda: ScriptedEnv(step_fn=step))
        assert [(e.status, e.steps) for e in result.episodes] == [("identical", 3)] * 2, way


# ---------------------------------------------------------- truncation reasons read from info


def record_truncation(path: Path, info: dict[str, Any], *, time_limit: bool) -> dict[str, Any]:
    """One episode of three steps cut off with ``info`` (by a ``TimeLimit`` or by the env)."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        return ZEROS, 1.0, False, not time_limit and env.t == 3, info

    inner: gym.Env[Any, Any] = ScriptedEnv(step_fn=step)
    if time_limit:
        inner = gym.wrappers.TimeLimit(inner, max_episode_steps=3)
    with RecordEvidence(inner, path) as env:
        env.action_space.seed(0)
        assert len(loop(env, episodes=1)) == 3
    assert_valid(path)
    (episode,) = open_evidence(path).episodes().to_pylist()
    return dict(episode)


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        (3, r"3 \(int\)"),
        (Colour.RED, r"<Colour\.RED: 1> \(Colour\)"),
        (b"wall", r"b'wall' \(bytes\)"),
        (["wall"], r"\['wall'\] \(list\)"),
        (np.int64(7), r"np\.int64\(7\) \(int64\)|7 \(int64\)"),  # numpy 2 / 1 repr
        (np.array([1, 2]), r"array\(\[1, 2\]\) \(ndarray\)"),  # no truth value: still noted
    ],
    ids=["int", "enum", "bytes", "list", "np_int", "array"],
)
@pytest.mark.parametrize("time_limit", [True, False], ids=["time_limit", "external"])
def test_a_truncation_reason_that_is_not_text_keeps_the_reason_and_is_noted(
    tmp_path: Path, value: Any, shown: str, time_limit: bool
) -> None:
    """As a failure label that is not text: the reason is the one without it, and the final
    step says what the env gave."""
    from episode_audit import replay

    path = tmp_path / "reason.mcap"
    episode = record_truncation(path, {"truncation_reason": value}, time_limit=time_limit)
    reason = "time_limit" if time_limit else "external"
    assert (episode["outcome"], episode["truncation_reason"], episode["notes"]) == (
        "truncated",
        reason,
        1,
    )
    ((ep, step, message),) = noted(path, "truncation_reason_not_text")
    assert (ep, step) == (0, 2)
    assert re.fullmatch(
        rf"info\['truncation_reason'\] is ({shown}): recorded as {reason}; give a string", message
    ), message
    (finding,) = findings(path, "recorder_note:truncation_reason_not_text")
    assert (finding.severity, finding.episode, finding.step) == ("warning", 0, 2)
    assert message in finding.message
    assert steps_of(path)[-1]["label"] == reason
    if not time_limit:  # (a TimeLimit the factory would have to rebuild)
        factory = lambda: ScriptedEnv(  # noqa: E731
            step_fn=lambda e, a: (ZEROS, 1.0, False, e.t == 3, {"truncation_reason": value})
        )
        assert [e.status for e in replay([path], env_factory=factory).episodes] == ["identical"]


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (None, "time_limit"),
        ("", "time_limit"),  # the text for "no reason", like None
        (False, "time_limit"),
        (0, "time_limit"),
        (True, "time_limit"),  # "cut off, no reason given": nothing is lost (see docs)
        (np.True_, "time_limit"),
        ("wall_hit", "wall_hit"),
    ],
)
def test_truncation_reasons_that_are_text_or_say_no_reason_are_not_noted(
    tmp_path: Path, value: Any, reason: str
) -> None:
    path = tmp_path / "reason.mcap"
    episode = record_truncation(path, {"truncation_reason": value}, time_limit=True)
    assert (episode["outcome"], episode["truncation_reason"], episode["notes"]) == (
        "truncated",
        reason,
        0,
    )
    assert noted(path, "truncation_reason_not_text") == []


def test_a_truncation_reason_beside_a_task_ending_is_noted_too(tmp_path: Path) -> None:
    """Both flags set: the task ending counts and the reason is kept beside it, so it is read."""
    path = tmp_path / "both.mcap"
    info = {"success": True, "truncation_reason": Colour.RED}
    with scripted(path, lambda e, a: (ZEROS, 1.0, e.t == 3, e.t == 3, info)) as env:
        assert len(loop(env, episodes=1)) == 3
    (episode,) = open_evidence(path).episodes().to_pylist()
    assert (episode["outcome"], episode["truncation_reason"], episode["notes"]) == (
        "success",
        "external",
        1,
    )
    ((_, step, message),) = noted(path, "truncation_reason_not_text")
    assert step == 2 and message.startswith("info['truncation_reason'] is <Colour.RED: 1>")


# ------------------------------------------------------------------ episode note counts


def rows_with_notes(path: Path) -> dict[int, int]:
    """Per episode: its reset row and step rows that carry recorder notes."""
    ev = open_evidence(path)
    count: dict[int, int] = {}
    for table in (ev.resets(), ev.steps()):
        for row in table.select(["episode", "notes"]).to_pylist():
            if row["notes"] is not None:
                count[row["episode"]] = count.get(row["episode"], 0) + 1
    return count


def assert_note_counts(path: Path) -> None:
    """Every episode record's ``notes`` is the number of its rows with notes."""
    records = {r["episode"]: r["notes"] for r in open_evidence(path).episodes().to_pylist()}
    rows = rows_with_notes(path)
    assert records == {e: rows.get(e, 0) for e in records}


class Opaque:
    """An info value JSON cannot hold (noted info_unserializable when the block is written)."""

    def __repr__(self) -> str:
        return "Opaque()"


@pytest.mark.parametrize("block_steps", [2, 100], ids=["small_blocks", "one_block"])
def test_notes_added_when_a_block_is_written_count_in_the_episode_record(
    tmp_path: Path, block_steps: int
) -> None:
    """info_unserializable is found when the block is written, before the episode's record
    (same flush): the reset row and every step row count, a row with two notes once."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, ...]:
        info: dict[Any, Any] = {"x": Opaque()}
        if env.t == 2:  # a second note on that row, made while stepping
            info["reward_terms"] = {"a": "1.5"}
        return ZEROS, 1.0, env.t == 4, False, info

    path = tmp_path / "info.mcap"
    reset = lambda env: (ZEROS, {"x": Opaque()})  # noqa: E731
    with scripted(path, step, reset, info_keys=["x"], block_steps=block_steps) as env:
        assert len(loop(env, episodes=2)) == 8
    assert_valid(path)
    assert [e["notes"] for e in open_evidence(path).episodes().to_pylist()] == [5, 5]
    assert_note_counts(path)
    assert [(e, s) for e, s, _ in noted(path, "info_unserializable")] == [
        (e, s) for e in (0, 1) for s in range(4)
    ]
    assert [(e, s) for e, s, _ in noted(path, "term_not_numeric")] == [(0, 1), (1, 1)]


def test_rows_stepped_after_the_end_count_only_when_written_with_the_end(tmp_path: Path) -> None:
    """The documented limit: an episode's record is written at the flush after its end and
    never again, so a row stepped after its end (noted step_after_end) and written by a later
    flush is not in its count."""
    path = tmp_path / "after.mcap"
    with scripted(path, lambda e, a: (ZEROS, 1.0, e.t >= 2, False, {})) as env:
        env.reset(seed=0)
        for _ in range(3):  # the third after the end: written with it
            env.step(0)
        env.reset(seed=1)
        for _ in range(2):
            env.step(0)
        env.flush()  # the second episode's record is written here
        env.step(0)  # after its end, in a later flush
    records = open_evidence(path).episodes().to_pylist()
    assert [(r["length"], r["notes"]) for r in records] == [(2, 1), (2, 0)]
    assert [(e, s) for e, s, _ in noted(path, "step_after_end")] == [(0, 2), (1, 2)]


# ------------------------------------------------------------------ PettingZoo infos on replay


GAME_STEPS = 4


class InfoAEC(AECEnv):  # type: ignore[misc]
    """Agents ``a`` and ``b`` take turns; every step pays both 1 and gives both
    ``info_fn(final)``; the fourth step terminates both (then their dead steps)."""

    metadata = {"name": "info_aec_v0"}

    def __init__(self, info_fn: Any) -> None:
        super().__init__()
        self.info_fn = info_fn
        self.possible_agents = ["a", "b"]

    def observation_space(self, agent: str) -> Any:
        return gym.spaces.Box(0.0, 100.0, (1,), np.float32)

    def action_space(self, agent: str) -> Any:
        return gym.spaces.Discrete(2)

    def observe(self, agent: str) -> Any:
        return np.array([self.t], dtype=np.float32)

    def reset(self, seed: int | None = None, options: Any = None) -> None:
        self.agents = list(self.possible_agents)
        self.t = 0
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, Any] = {a: {} for a in self.agents}
        self.agent_selection = "a"

    def step(self, action: Any) -> None:
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        self._cumulative_rewards[agent] = 0.0
        self.t += 1
        final = self.t >= GAME_STEPS
        self.rewards = dict.fromkeys(self.agents, 1.0)
        self.infos = {a: self.info_fn(final) for a in self.agents}
        if final:
            self.terminations = dict.fromkeys(self.agents, True)
        self.agent_selection = self.agents[(self.agents.index(agent) + 1) % len(self.agents)]
        self._accumulate_rewards()


class InfoParallel(ParallelEnv):  # type: ignore[misc]
    """The Parallel twin of :class:`InfoAEC`: four joint steps, both agents terminate."""

    metadata = {"name": "info_parallel_v0"}

    def __init__(self, info_fn: Any) -> None:
        self.info_fn = info_fn
        self.possible_agents = ["a", "b"]

    def observation_space(self, agent: str) -> Any:
        return gym.spaces.Box(0.0, 100.0, (1,), np.float32)

    def action_space(self, agent: str) -> Any:
        return gym.spaces.Discrete(2)

    def reset(self, seed: int | None = None, options: Any = None) -> Any:
        self.agents = list(self.possible_agents)
        self.t = 0
        return {a: np.zeros(1, np.float32) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> Any:
        self.t += 1
        final = self.t >= GAME_STEPS
        live = list(self.agents)
        if final:
            self.agents = []
        return (
            {a: np.array([self.t], np.float32) for a in live},
            dict.fromkeys(live, 1.0),
            dict.fromkeys(live, final),
            dict.fromkeys(live, False),
            {a: self.info_fn(final) for a in live},
        )


def play_game(env: Any, api: str, seed: int) -> None:
    env.reset(seed=seed)
    if api == "aec":
        for _agent in env.agent_iter():
            _, _, term, trunc, _ = env.last()
            env.step(None if term or trunc else 1)
    else:
        while env.agents:
            env.step(dict.fromkeys(env.agents, 1))


def record_game(path: Path, api: str, info_fn: Any) -> Any:
    """Two games of :class:`InfoAEC` or :class:`InfoParallel`; returns the env factory."""
    from episode_audit import RecordAECEvidence, RecordParallelEvidence

    make = (lambda: InfoAEC(info_fn)) if api == "aec" else (lambda: InfoParallel(info_fn))
    recorder = RecordAECEvidence if api == "aec" else RecordParallelEvidence
    with recorder(make(), path) as env:
        for seed in (0, 1):
            play_game(env, api, seed)
    assert_valid(path)
    return make


PZ_INFO_CASES: dict[str, tuple[Any, list[tuple[str, float]] | None, str, str | None]] = {
    # per-step info (final: the game's last step) -> each row's recorded terms, the ending,
    # and the recorder note every row (or the final row) has
    "collision": (
        lambda final: {"reward_terms": {1: 0.5, "1": 0.25}},
        [("1", 0.75)],
        "failure/unlabeled",
        "terms_name_collision",
    ),
    "surrogate": (
        lambda final: {"reward_terms": {"a\udcff": 0.5}},
        [("a\\udcff", 0.5)],
        "failure/unlabeled",
        None,
    ),
    "bytes": (
        lambda final: {"reward_terms": {b"a": 0.5}},
        [("b'a'", 0.5)],
        "failure/unlabeled",
        None,
    ),
    "text_value": (
        lambda final: {"reward_terms": {"x": "1.5"}},
        [("x", math.nan)],
        "failure/unlabeled",
        "term_not_numeric",
    ),
    "unreadable": (
        lambda final: {"reward_terms": 5},
        None,
        "failure/unlabeled",
        "terms_unreadable",
    ),
    "not_a_dict": (lambda final: [1, 2], None, "failure/unlabeled", "info_not_dict"),
    "array_success": (
        lambda final: {"reward_a": 1.0, **({"success": np.array([1, 0])} if final else {})},
        [("reward_a", 1.0)],
        "failure/unlabeled",
        "ending_unreadable",
    ),
    "success_text": (
        lambda final: {"success": "no"} if final else {},
        None,
        "success",
        "success_not_bool",
    ),
    "label_enum": (
        lambda final: {"failure": Colour.RED} if final else {},
        None,
        "failure/unlabeled",
        "failure_label_not_text",
    ),
}


@pytest.mark.parametrize("api", ["aec", "parallel"])
@pytest.mark.parametrize("case", list(PZ_INFO_CASES))
def test_pettingzoo_infos_are_read_on_replay_as_the_recorder_read_them(
    tmp_path: Path, case: str, api: str
) -> None:
    """Term names by the one rule (collisions summed, text escaped), terms that cannot be read
    are none, a final info the rules cannot read ends by the flags: every agent replays
    identical, and replay never raises over an info."""
    from episode_audit import replay

    info_fn, terms, ending, code = PZ_INFO_CASES[case]
    path = tmp_path / f"{api}.mcap"
    make = record_game(path, api, info_fn)
    records = open_evidence(path).episodes().to_pylist()
    assert len(records) == 4
    assert {"/".join(p for p in (r["outcome"], r["failure_label"]) if p) for r in records} == {
        ending
    }
    for row in steps_of(path):
        if terms is None:
            assert row["terms"] is None
        else:
            assert [k for k, _ in row["terms"]] == [k for k, _ in terms]
            assert np.allclose([v for _, v in row["terms"]], [v for _, v in terms], equal_nan=True)
    if code is not None:
        assert noted(path, code) != []
    assert_note_counts(path)
    result = replay([path], env_factory=make)
    rows = GAME_STEPS // 2 if api == "aec" else GAME_STEPS  # AEC: the agents take turns
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", rows)] * 4, (
        result.to_dict()
    )


def test_pettingzoo_replay_still_compares_the_named_terms(tmp_path: Path) -> None:
    """The names are the recorder's: a replayed env whose colliding terms sum otherwise
    diverges at its first step, showing the recorded sum."""
    from episode_audit import replay

    path = tmp_path / "parallel.mcap"
    record_game(path, "parallel", lambda final: {"reward_terms": {1: 0.5, "1": 0.25}})
    other = lambda: InfoParallel(lambda final: {"reward_terms": {1: 0.5, "1": 0.5}})  # noqa: E731
    first, *_ = replay([path], env_factory=other).episodes
    assert first.status == "not_replayable" and first.divergence is not None
    assert first.divergence.describe() == "step 0: terms expected {'1': 0.75}, got {'1': 1.0}"


def test_an_aec_row_noted_by_the_turns_and_by_the_step_keeps_both_notes_counted_once(
    tmp_path: Path,
) -> None:
    """``b`` is paid by ``a``'s first step, before its own first turn (reward_before_first_turn,
    noted by the turn accounting), and its first row's term is text (term_not_numeric, noted
    by the recorder's slow path): one row, both notes, one row in the count."""
    path = tmp_path / "aec.mcap"
    record_game(path, "aec", lambda final: {"reward_terms": {"x": "1.5"}})
    first_b = [r for r in steps_of(path) if r["episode"] == 1 and r["step"] == 0]
    (row,) = first_b
    codes = [n.partition(":")[0] for n in json.loads(row["notes"])]
    assert codes == ["reward_before_first_turn", "term_not_numeric"]
    assert_note_counts(path)


class ArrayFlagParallel(InfoParallel):
    """:class:`InfoParallel` whose second step's truncation flags are arrays (no truth value)."""

    def step(self, actions: dict[str, Any]) -> Any:
        obs, rewards, terms, truncs, infos = super().step(actions)
        if self.t == 2:
            truncs = {a: np.array([True, False]) for a in truncs}
        return obs, rewards, terms, truncs, infos


def test_pettingzoo_flags_without_a_truth_value_replay_as_the_recorder_took_them(
    tmp_path: Path,
) -> None:
    """The recorder takes such flags as False (noted flags_not_bool); so does replay."""
    from episode_audit import RecordParallelEvidence, replay

    path = tmp_path / "flags.mcap"
    with RecordParallelEvidence(ArrayFlagParallel(lambda final: {}), path) as env:
        play_game(env, "parallel", 0)
    steps = open_evidence(path).steps().to_pylist()
    noted = [row["step"] for row in steps if "flags_not_bool" in (row["notes"] or "")]
    assert noted == [1, 1]
    result = replay([path], env_factory=lambda: ArrayFlagParallel(lambda final: {}))
    assert [e.status for e in result.episodes] == ["identical", "identical"], result.episodes


_OVERFLOWING = """
import sys
import gymnasium as gym, numpy as np
from episode_audit import RecordEvidence, replay


class Big(gym.Env):
    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.array([1.0, 2.0]), {}

    def step(self, action):
        return np.array([1e39, -1e39]), 1.0, True, False, {}


with RecordEvidence(Big(), sys.argv[1]) as env:
    env.reset(seed=0)
    env.step(0)
print("identical", replay([sys.argv[1]], env_factory=lambda: Big()).count("identical"))
"""


def test_a_value_too_large_for_its_float_column_is_stored_as_inf_without_a_numpy_warning(
    tmp_path: Path,
) -> None:
    """The cast is noted in the file; numpy's overflow warning is no line of the loop's output."""
    import subprocess
    import sys

    path = tmp_path / "big.mcap"
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", _OVERFLOWING, str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "overflow" not in done.stderr and "Warning" not in done.stderr, done.stderr
    assert "identical 1" in done.stdout
    assert steps_of(path)[0]["observation"] == [math.inf, -math.inf]
    assert findings(path, "recorder_note:observation_cast")
