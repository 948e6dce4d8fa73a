"""``check_contract`` on real envs (Gymnasium classic, MuJoCo v5, a user env) and its errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import EpisodeAuditError, RecordEvidence, open_evidence
from episode_audit.errors import ConfigurationError, ContractViolation
from episode_audit.testing import (
    ContractCase,
    GameCase,
    RolloutRecorder,
    check_contract,
    check_game_contract,
    contract_cases,
    evidence_actions,
    expected_ending,
)
from tests.support.walk import Walk

CLASSIC = ["CartPole-v1", "Acrobot-v1", "MountainCar-v0", "Pendulum-v1"]


@pytest.mark.parametrize(
    "case",
    contract_cases(CLASSIC, env_kwargs={"max_episode_steps": 12}, actions="random", seed=5),
    ids=str,
)
def test_classic_envs_keep_the_contract_under_random_actions(
    case: ContractCase, tmp_path: Path
) -> None:
    result = check_contract(case, tmp_path)
    assert result.replayed is not None and result.replayed.status == "identical"
    assert result.outcome in ("truncated", "failure")


def test_cartpole_time_limit_from_a_recorded_file(tmp_path: Path) -> None:
    recorded = tmp_path / "kept.mcap"
    env = gym.make("CartPole-v1", max_episode_steps=10)
    with RecordEvidence(env, recorded) as rec:
        rec.reset(seed=4)
        for i in range(10):
            rec.step(i % 2)
    assert evidence_actions(recorded) == [i % 2 for i in range(10)]
    case = ContractCase(
        "CartPole-v1",
        {"max_episode_steps": 10},
        seed=4,
        actions=recorded,
        expect="truncated:time_limit",
    )
    result = check_contract(case, tmp_path / "out")
    assert (result.outcome, result.detail, result.steps) == ("truncated", "time_limit", 10)


def test_cartpole_falling_is_a_failure_not_a_truncation(tmp_path: Path) -> None:
    case = ContractCase("CartPole-v1", seed=0, actions=[0] * 100, expect="truncated:time_limit")
    with pytest.raises(ContractViolation, match=r"got failure \(unlabeled\) at step 10: ") as info:
        check_contract(case, tmp_path)
    result = info.value.result
    assert isinstance(info.value, AssertionError) and isinstance(info.value, EpisodeAuditError)
    assert result.path.exists() and result.outcome == "failure"
    assert f"replay it: episode-audit replay {result.path}" in str(info.value)


@pytest.mark.mujoco
def test_mujoco_v5_time_limit_and_unhealthy_ending_with_their_terms(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    still = ContractCase(
        "Hopper-v5",
        {"max_episode_steps": 10},
        actions=[np.zeros(3, np.float32)] * 10,
        expect="truncated:time_limit",
        terms_present=["reward_forward", "reward_survive"],
        terms_absent=["reward_ctrl"],  # no control, no control cost
        require_terms=True,
    )
    assert check_contract(still, tmp_path).steps == 10
    falls = ContractCase(
        "Hopper-v5",
        seed=1,
        actions="random",
        expect="failure",
        terms_present=["reward_forward", "reward_ctrl"],
        terms_absent=["reward_survive"],  # an unhealthy step earns no survival reward
    )
    result = check_contract(falls, tmp_path)
    assert (result.outcome, result.last_terms["reward_survive"]) == ("failure", 0.0)
    wrong = ContractCase(
        "Hopper-v5", seed=1, actions="random", expect="failure", terms_absent=["reward_ctrl"]
    )
    with pytest.raises(
        ContractViolation,
        match=r"expected term 'reward_ctrl' absent \(or zero\), got reward_ctrl=-",
    ):
        check_contract(wrong, tmp_path)


def test_a_user_env_with_terms_declared_constants_and_a_policy(tmp_path: Path) -> None:
    case = ContractCase(
        Walk,
        seed=2,
        make_policy=lambda env: lambda obs: 1,
        expect="success",
        terms_present=["success_bonus"],
        terms_absent=["fall_penalty"],
    )
    assert check_contract(case, tmp_path).outcome == "success"
    shifted = ContractCase(
        lambda **kw: gym.wrappers.TransformReward(Walk(**kw), lambda r: r + 0.5),
        seed=2,
        actions=[1] * 10,
        expect="success",
        recorder_options={"constant_terms": {"alive": 0.5}},
    )
    assert check_contract(shifted, tmp_path).ok


def test_running_out_of_actions_or_steps_says_so(tmp_path: Path) -> None:
    short = ContractCase(Walk, actions=[1, 0], expect="success")
    with pytest.raises(
        ContractViolation, match=r"expected success, got none: the actions ran out after 2 step"
    ):
        check_contract(short, tmp_path)
    endless = ContractCase(Walk, actions=lambda obs: int(obs[0] < 0), max_steps=7)
    with pytest.raises(ContractViolation, match=r"got none: max_steps was reached after 7 step"):
        check_contract(endless, tmp_path)


def test_the_evidence_a_violation_kept_is_not_written_over(tmp_path: Path) -> None:
    # two cases of one name (the actions are not in it): the second wrote over the file the
    # first one's violation said it kept
    endless = ContractCase("CartPole-v1", seed=0, actions=[0, 1] * 5, expect="failure")
    with pytest.raises(ContractViolation) as raised:
        check_contract(endless, tmp_path)
    kept = raised.value.result.path
    assert f"evidence kept: {kept}" in str(raised.value)
    falling = ContractCase("CartPole-v1", seed=0, actions=[0] * 50, expect="failure")
    passed = check_contract(falling, tmp_path)
    assert passed.path == kept.with_name(f"{kept.stem}-2.mcap")
    (episode,) = open_evidence(kept).episodes().to_pylist()
    assert (episode["outcome"], episode["length"]) == ("incomplete", 10)
    assert check_contract(falling, tmp_path).path == passed.path  # (a pass: written over)
    with pytest.raises(ConfigurationError, match=r"expected a folder to keep the evidence files"):
        check_contract(falling, kept)


class Raising(Walk):
    def step(self, action: Any) -> Any:
        if self.t == 2:
            raise RuntimeError("the simulator exploded")
        return super().step(action)


class RaisingReset(Walk):
    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        raise ValueError("no scene file")


def test_an_env_that_raises_is_a_broken_contract_with_its_error(tmp_path: Path) -> None:
    case = ContractCase(Raising, actions=[1] * 10, expect="success")
    with pytest.raises(
        ContractViolation, match=r"the env raised at step 2: RuntimeError: the simulator exploded"
    ):
        check_contract(case, tmp_path)
    case = ContractCase(RaisingReset, actions=[1] * 10, expect="success")
    with pytest.raises(ContractViolation, match=r"the env raised in reset: ValueError: no scene"):
        check_contract(case, tmp_path)


def test_an_array_of_actions_steps_row_by_row(tmp_path: Path) -> None:
    case = ContractCase(
        "Pendulum-v1", {"max_episode_steps": 6}, actions=np.zeros((6, 1), np.float32)
    )
    assert check_contract(case, tmp_path).detail == "time_limit"


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({}, "expected exactly one of actions= and make_policy=, got neither"),
        (
            {"actions": [0], "make_policy": lambda env: env.action_space.sample},
            "expected exactly one of actions= and make_policy=, got both",
        ),
        ({"actions": "run.mcap"}, "as a Path, got the string 'run.mcap'"),
        ({"actions": [0], "expect": "done"}, "expect: expected 'success', "),
        ({"actions": [0], "max_steps": 0}, r": max_steps: expected an int >= 1, got 0 \(int\)$"),
        ({"actions": [0], "seed": "0"}, r"^CartPole-v1-seed0: seed: expected an int in 0 \.\. "),
        ({"actions": [0], "seed": -1}, r": seed: expected an int in 0 \.\. 9223372036854775807, "),
        ({"actions": [0], "seed": 2**63}, r": seed: expected an int in 0 \.\. 922"),
        (
            {"actions": [0], "seed": True},
            r": seed: expected an int in 0 \.\. .*, got True \(bool\)$",
        ),
        ({"actions": [0], "seed": 1.0}, r": seed: expected an int in .*, got 1\.0 \(float\)$"),
        (
            {"actions": [0], "random_episodes": "3"},
            r": random_episodes: expected an int >= 0, got '3'",
        ),
        (
            {"actions": [0], "random_episodes": -1},
            r": random_episodes: expected an int >= 0, got -1",
        ),
        (
            {"actions": [0], "max_steps": None},
            r": max_steps: expected an int >= 1, got None \(None",
        ),
        (
            {"actions": [0], "atol": "0.1"},
            r": atol: expected a finite number >= 0, got '0\.1' \(str\)$",
        ),
        ({"actions": [0], "rtol": float("nan")}, r": rtol: expected a finite number >= 0, got nan"),
        (
            {"actions": [0], "rtol": False},
            r": rtol: expected a finite number >= 0, got False \(bool",
        ),
        ({"actions": [0], "replay": "no"}, r": replay: expected True or False, got 'no' \(str\)$"),
        (
            {"actions": [0], "require_terms": 1},
            r": require_terms: expected True or False, got 1 \(int",
        ),
        ({"actions": 5}, r": actions: expected a list, a policy, 'random' or .*, got 5 \(int\)$"),
        ({"actions": [0], "make_policy": 3}, r": make_policy: expected a callable .*, got 3 \(int"),
        (
            {"actions": [0], "expect": 1},
            r": expect: expected 'success', .* or None, got 1 \(int\)$",
        ),
        ({"actions": [0], "env_kwargs": [1]}, r": env_kwargs: expected a dict of keyword argu"),
        ({"actions": [0], "env_kwargs": {1: 2}}, r": env_kwargs: expected a dict .*, got \{1: 2\}"),
        ({"actions": [0], "recorder_options": None}, r": recorder_options: expected a dict .*None"),
        ({"actions": [0], "id": 7}, r"^ContractCase: id: expected a str or None, got 7 \(int\)$"),
        (
            {"actions": [0], "terms_present": "reward_ctrl"},
            r"^CartPole-v1-seed0: terms_present: expected a list of names, got the string "
            r"'reward_ctrl'; pass \['reward_ctrl'\]$",
        ),
        (
            {"actions": [0], "terms_absent": [None]},
            r"^CartPole-v1-seed0: terms_absent\[0\]: expected a name \(a str\), got None",
        ),
    ],
)
def test_a_case_that_cannot_run_is_a_configuration_error(
    fields: dict[str, Any], match: str
) -> None:
    with pytest.raises(ConfigurationError, match=match):
        ContractCase("CartPole-v1", **fields)


def test_a_case_whose_env_is_neither_an_id_nor_a_factory_is_a_configuration_error() -> None:
    with pytest.raises(ConfigurationError, match=r"^ContractCase: env: expected a registered env"):
        ContractCase(3, actions=[0])  # type: ignore[arg-type]


def test_a_case_s_numpy_integers_are_kept_as_ints(tmp_path: Path) -> None:
    case = ContractCase("CartPole-v1", seed=np.int64(3), actions=[0] * 50, max_steps=np.int32(60))
    assert type(case.seed) is int and case.seed == 3
    assert type(case.max_steps) is int and case.max_steps == 60
    check_contract(case, tmp_path)  # (a bad seed would be the env's error, not the case's)


def test_an_env_that_cannot_be_made_is_a_configuration_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="the env factory returned str"):
        check_contract(ContractCase(lambda: "CartPole-v1", actions=[0]), tmp_path)
    with pytest.raises(ConfigurationError, match=r"cannot make the env: .*NoSuchEnv"):
        check_contract(ContractCase("NoSuchEnv-v0", actions=[0]), tmp_path)


def test_expected_endings_parse_and_match() -> None:
    assert expected_ending("failure").matches("failure", "anything")
    assert not expected_ending("failure:fell").matches("failure", "unlabeled")
    assert expected_ending("truncated:time_limit").matches("truncated", "time_limit")
    assert not expected_ending("success").matches("truncated", "time_limit")
    for bad in ("success:yes", "failure:", "truncated:", "done"):
        with pytest.raises(ConfigurationError, match="expect: expected"):
            expected_ending(bad)


def test_evidence_actions_of_a_missing_episode(tmp_path: Path) -> None:
    path = tmp_path / "one.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as rec:
        rec.reset(seed=0)
        rec.step(1)
    with pytest.raises(ConfigurationError, match="no steps of episode 3 to take actions from"):
        evidence_actions(path, episode=3)


def test_the_rollout_recorder_refuses_a_name_twice_and_nothing_recorded(tmp_path: Path) -> None:
    record = RolloutRecorder(tmp_path)
    with pytest.raises(ConfigurationError, match="no env recorded yet"):
        record.evidence()
    env = record(gym.make("CartPole-v1"), name="a")
    with pytest.raises(ConfigurationError, match=r"a\.mcap is already recorded by this test"):
        record(gym.make("CartPole-v1"), name="a")
    env.reset(seed=0)
    env.step(0)
    record(gym.make("CartPole-v1"), name="b")
    assert record.evidence("a").episodes().num_rows == 1
    with pytest.raises(ConfigurationError, match="no env recorded as 'c'"):
        record.evidence("c")
    record.close()
    record.close()
    assert open_evidence(tmp_path / "b.mcap").finished


# ------------------------------------------------------------------ PettingZoo games


def test_a_game_checks_each_agents_ending(tmp_path: Path) -> None:
    from tests.support.walk_game import WalkGame

    apart = [{"left": 1, "right": 0}] * 6
    ends = GameCase(
        WalkGame, seed=0, actions=apart, expect={"left": "success", "right": "failure:fell"}
    )
    result = check_game_contract(ends, tmp_path)
    assert (result.outcome, result.replayed and result.replayed.status) == ("mixed", "identical")
    back_and_forth = [{"left": 1, "right": 0}, {"left": 0, "right": 1}] * 2
    cut = {"left": "truncated:time_limit", "right": "truncated:time_limit"}
    assert (
        check_game_contract(
            GameCase(WalkGame, {"max_cycles": 4}, seed=0, actions=back_and_forth, expect=cut),
            tmp_path,
        ).outcome
        == "truncated"
    )
    assert check_game_contract(GameCase(WalkGame, seed=3), tmp_path).steps > 0  # random
    with pytest.raises(
        ContractViolation,
        match=r"the game did not end: the actions ran out after 2 step\(s\), agents left, right",
    ):
        check_game_contract(GameCase(WalkGame, actions=back_and_forth[:2]), tmp_path)
    wrong = GameCase(
        WalkGame, {"max_cycles": 4, "cutoff_terminates": True}, actions=back_and_forth, expect=cut
    )
    with pytest.raises(
        ContractViolation,
        match=r"ending of agent 'left': expected truncated:time_limit, got failure \(unlabeled\) "
        r"at step 3: terminated=True, truncated=False, so the task ended it; .*"
        r"the env reports a truncation as termination",
    ):
        check_game_contract(wrong, tmp_path)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"env": 3}, r"^GameCase: env: expected a factory returning a pettingzoo ParallelEnv, "),
        ({"id": 7}, r"^GameCase: id: expected a str or None, got 7 \(int\)$"),
        ({"seed": "0"}, r"^WalkGame-seed0: seed: expected an int in 0 \.\. .*, got '0' \(str\)$"),
        ({"seed": -1}, r": seed: expected an int in 0 \.\. 9223372036854775807, got -1 \(int\)$"),
        ({"max_steps": 0}, r": max_steps: expected an int >= 1, got 0 \(int\)$"),
        ({"max_steps": "5"}, r": max_steps: expected an int >= 1, got '5' \(str\)$"),
        ({"atol": -1.0}, r": atol: expected a finite number >= 0, got -1\.0 \(float\)$"),
        ({"replay": "yes"}, r": replay: expected True or False, got 'yes' \(str\)$"),
        ({"require_terms": 1}, r": require_terms: expected True or False, got 1 \(int\)$"),
        ({"env_kwargs": [1]}, r": env_kwargs: expected a dict of keyword arguments"),
        ({"recorder_options": None}, r": recorder_options: expected a dict .*None \(NoneType\)$"),
        (
            {"actions": 5},
            r": actions: expected joint actions, a policy or 'random', got 5 \(int\)$",
        ),
        ({"actions": [{"left": 1}, 0]}, r": actions: expected a dict .*, got 0 \(int\) at step 1$"),
        ({"expect": ["success"]}, r": expect: expected a dict of each agent's ending"),
        (
            {"expect": {"left": 3}},
            r": expect: expected agent names .*, got 'left' \(str\): 3 \(int",
        ),
    ],
)
def test_a_game_case_with_a_bad_field_is_a_configuration_error(
    fields: dict[str, Any], match: str
) -> None:
    from tests.support.walk_game import WalkGame

    with pytest.raises(ConfigurationError, match=match):
        GameCase(**{"env": WalkGame, **fields})


def test_a_game_case_s_numpy_integers_are_kept_as_ints() -> None:
    from tests.support.walk_game import WalkGame

    case = GameCase(WalkGame, seed=np.int64(3), max_steps=np.int32(60))
    assert (type(case.seed), type(case.max_steps)) == (int, int)


def test_a_game_case_that_cannot_run_is_a_configuration_error(tmp_path: Path) -> None:
    from tests.support.walk_game import WalkGame

    (tmp_path / "file").write_text("")
    with pytest.raises(
        ConfigurationError,
        match=r"file: expected a folder to keep the evidence files in, got a file; give a folder",
    ):
        check_game_contract(GameCase(WalkGame, seed=3), tmp_path / "file")
    with pytest.raises(
        ConfigurationError, match=r"file/runs: cannot make the folder for the evidence files"
    ):
        check_game_contract(GameCase(WalkGame, seed=3), tmp_path / "file" / "runs")

    with pytest.raises(ConfigurationError, match="agent 'left': expect: expected 'success'"):
        GameCase(WalkGame, expect={"left": "won"})
    with pytest.raises(ConfigurationError, match="expected joint actions, a policy or 'random'"):
        GameCase(WalkGame, actions="scripted")
    with pytest.raises(
        ConfigurationError, match="the env factory returned Walk, not a ParallelEnv"
    ):
        check_game_contract(GameCase(Walk), tmp_path)
