"""The pytest plugin, run as pytest runs it: pytester projects that use its fixtures.

Each kind of broken contract is a failing test whose message names the step and the term (or
the numbers), with the replay command of the evidence file kept.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

SUPPORT = Path(__file__).resolve().parents[1] / "support"
WALK = (SUPPORT / "walk.py").read_text()
GAME = (SUPPORT / "walk_game.py").read_text().replace("tests.support.walk", "walk")
PLUGIN = "episode_audit_pytest"

HEADER = """
import gymnasium as gym
import pytest
from episode_audit.testing import ContractCase, contract_cases
from walk import Walk
"""


def run(pytester: pytest.Pytester, body: str) -> pytest.RunResult:
    pytester.makepyfile(walk=WALK)
    pytester.makepyfile(test_env=HEADER + body)
    pytester.syspathinsert()
    return pytester.runpytest("-p", PLUGIN, "-p", "no:cacheprovider", "-q")


def failure_text(result: pytest.RunResult) -> str:
    result.assert_outcomes(failed=1)
    return "\n".join(result.outlines)


def test_a_passing_contract_over_several_env_ids_and_endings(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
CASES = contract_cases(
    ["CartPole-v1", "Acrobot-v1"], env_kwargs={"max_episode_steps": 8}, actions="random",
    expect="truncated:time_limit",
)

@pytest.mark.parametrize("case", CASES, ids=str)
def test_time_limits(env_contract, case):
    assert env_contract(case).steps == 8

@pytest.mark.parametrize(("actions", "expect", "term"), [
    ([1] * 10, "success", "success_bonus"),
    ([0] * 10, "failure:fell", "fall_penalty"),
])
def test_walk(env_contract, actions, expect, term):
    result = env_contract(ContractCase(Walk, seed=3, actions=actions, expect=expect,
                                       terms_present=[term], require_terms=True))
    assert result.replayed.status == "identical"

def test_own_rollout(record_evidence):
    env = record_evidence(gym.make("CartPole-v1", max_episode_steps=4))
    env.reset(seed=1)
    for _ in range(4):
        env.step(0)
    ev = record_evidence.evidence()
    assert ev.episodes().column("outcome").to_pylist() == ["truncated"]
    assert record_evidence.path.parent.name.startswith("test_own_rollout")
""",
    )
    result.assert_outcomes(passed=5)


def test_a_wrong_ending_names_the_step_and_the_replay_command(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, seed=0, actions=[0] * 10, expect="success"))
""",
    )
    text = failure_text(result)
    assert "Walk-seed0-success: 1 broken clause" in text
    assert "ending: expected success, got failure (fell) at step" in text
    assert "evidence kept: " in text and "Walk-seed0-success.mcap" in text
    assert "replay it: episode-audit replay " in text
    assert "--env-factory walk:Walk" in text
    assert "Traceback" not in text


def test_terms_that_do_not_sum_name_the_step_and_the_terms(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, {"bad_sum_at": 2}, seed=0, actions=[1] * 10,
                              expect="success"))
""",
    )
    text = failure_text(result)
    assert "check: terms_sum_mismatch at step 2:" in text
    assert "terms at step 2: progress=0.25, time=-0.125 (sum 0.125), reward 0.625" in text


def test_a_time_limit_reported_as_termination(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, {"own_time_limit": 6}, seed=0, actions=[1, 0] * 5,
                              expect="truncated"))
""",
    )
    text = failure_text(result)
    assert "ending: expected truncated, got failure (unlabeled) at step 5:" in text
    assert "the env reports a truncation as termination" in text


def test_a_task_ending_reported_as_truncation(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, {"success_truncates": True}, seed=0, actions=[1] * 10,
                              expect="success"))
""",
    )
    text = failure_text(result)
    assert "ending: expected success, got truncated (external) at step" in text
    assert "the env reports a task ending as truncation" in text


def test_a_nondeterministic_reset_fails_the_replay(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, {"noisy_reset": True}, seed=0, actions=[1] * 10))
""",
    )
    text = failure_text(result)
    assert "replay: not reproducible in a fresh env with seed 0: reset: reset_observation " in text


def test_an_incentive_warning_over_random_episodes(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
def test_walk(env_contract):
    env_contract(ContractCase(Walk, {"falling_pays": True}, seed=0, actions=[1] * 10,
                              expect="success", random_episodes=20))
""",
    )
    text = failure_text(result)
    assert "incentives over 20 random episodes (seeds 0..19): failure_outearns_success:" in text
    assert "random episodes: episode-audit report " in text


def test_unused_the_plugin_changes_nothing(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_plain="def test_one():\n    assert True\n")
    result = pytester.runpytest_subprocess(
        "-p", PLUGIN, "-p", "no:cacheprovider", "-q", "--fixtures"
    )
    assert "env_contract" in result.stdout.str()
    ours = "sorted(m for m in sys.modules if m.startswith('episode_audit'))"
    loaded = pytester.run(sys.executable, "-c", f"import sys, {PLUGIN}; print({ours})")
    assert loaded.outlines[-1] == f"[{PLUGIN!r}]"


def test_the_examples_of_docs_testing_md_pass(pytester: pytest.Pytester) -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "testing.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, flags=re.S)
    assert len(blocks) == 4  # a case; CartPole's time limit; a user env with terms; PettingZoo
    pytester.makepyfile(**{f"test_doc_{i}": block for i, block in enumerate(blocks)})
    pytester.syspathinsert()
    result = pytester.runpytest("-p", PLUGIN, "-p", "no:cacheprovider", "-q")
    result.assert_outcomes(passed=11)


def test_a_games_broken_contract_names_the_agent(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(walk_game=GAME)
    result = run(
        pytester,
        """
from episode_audit.testing import GameCase
from walk_game import WalkGame

def test_game(env_contract):
    env_contract(GameCase(WalkGame, seed=0, actions=[{"left": 1, "right": 0}] * 6,
                          expect={"left": "success", "right": "success"}))
""",
    )
    text = failure_text(result)
    assert "WalkGame-seed0: 1 broken clause" in text
    assert "ending of agent 'right': expected success, got failure (fell) at step 2" in text
