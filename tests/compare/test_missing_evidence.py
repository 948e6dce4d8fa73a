"""compare() where the candidate lacks evidence the baseline has: episodes its env raised in
(``error``), and whole groups; neither may pass as ``held``."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest

from episode_audit import CompareGates, RecordEvidence, compare
from episode_audit.compare.core import _decide
from episode_audit.compare.groups import compare_group
from episode_audit.compare.sides import Side
from episode_audit.errors import ConfigurationError
from episode_audit.rollout import record_episodes
from tests.support.crashing import Crashing, crashing_cartpole


@pytest.fixture(scope="module")
def crashing(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("crashing")
    return {
        "clean": crashing_cartpole(out / "clean.mcap", 40),
        "clean_again": crashing_cartpole(out / "clean_again.mcap", 40),
        "half": crashing_cartpole(out / "half.mcap", 40, lambda seed: seed % 2 == 0),
    }


def test_a_candidate_whose_env_raises_in_half_its_episodes_regresses_on_error_rate(
    crashing: dict[str, Path],
) -> None:
    result = compare([crashing["clean"]], [crashing["half"]])
    (group,) = result.groups
    errors = group.metric("error_rate")
    assert (errors.baseline, errors.candidate) == (0.0, 0.5)
    assert (errors.baseline_n, errors.candidate_n, errors.paired) == (40, 40, True)
    assert errors.verdict == "regressed" and errors.better == "lower"
    assert group.metric("failure_rate").candidate_n == 20  # (the other rates: ended episodes)
    assert result.verdict == "regressed" and not result.passed
    assert any("20 of 40 candidate episodes" in note for note in result.notes), result.notes
    assert "all/error_rate" in {c.name for c in result.cases() if not c.passed}


def test_the_error_gate_bounds_the_error_rate_of_every_started_episode(
    crashing: dict[str, Path],
) -> None:
    gates = CompareGates(max_error_increase=0.05)
    failed = compare([crashing["clean"]], [crashing["half"]], gates=gates)
    (gate,) = failed.groups[0].gates
    assert gate.gate == "max_error_increase" and not gate.passed
    assert gate.message.startswith("error_rate: the 95 % interval allows an increase of up to")
    held = compare([crashing["clean"]], [crashing["clean_again"]], gates=CompareGates(0.5))
    assert "error_rate" not in {m.name for m in held.groups[0].metrics}  # (0 against 0: none)
    loose = CompareGates(max_error_increase=0.5)
    passed = compare([crashing["clean"]], [crashing["clean_again"]], gates=loose)
    assert passed.passed and passed.groups[0].gates[0].gate == "max_error_increase"
    with pytest.raises(Exception, match=r"max_error_increase: expected a rate between 0 and 1"):
        CompareGates(max_error_increase=2)


def test_an_error_rate_of_none_on_both_sides_costs_the_family_nothing() -> None:
    """0 errors against 0 cannot reject: with the gate on it is shown, not counted by Holm."""
    seeds = list(range(60))
    base = Side.of(["success"] * 50 + ["truncated"] * 10, seed=seeds)
    cand = Side.of(["success"] * 44 + ["truncated"] * 16, seed=seeds)
    plain = compare_group("all", base, cand, CompareGates(), [])
    gated = compare_group("all", base, cand, CompareGates(max_error_increase=0.1), [])
    _decide([plain])
    _decide([gated])
    errors = gated.metric("error_rate")
    assert not errors.can_reject and errors.verdict is not None
    others = [m for m in gated.metrics if m is not errors]
    assert [(m.name, m.p_adjusted) for m in plain.metrics] == [
        (m.name, m.p_adjusted) for m in others
    ]


def _tagged(out: Path, name: str, config: str, steps: int) -> Path:
    path = out / f"{name}.mcap"
    record_episodes(
        "CartPole-v1", path, episodes=12, max_episode_steps=steps, tags={"config": config}
    )
    return path


@pytest.fixture(scope="module")
def configs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("configs")
    return {
        "b_short": _tagged(out, "b_short", "short", 20),
        "b_long": _tagged(out, "b_long", "long", 40),
        "c_short": _tagged(out, "c_short", "short", 20),
        "c_new": _tagged(out, "c_new", "new", 20),
    }


def test_a_gate_on_a_group_the_candidate_lacks_fails_as_cannot_be_verified(
    configs: dict[str, Path],
) -> None:
    baseline = [configs["b_short"], configs["b_long"]]
    gates = CompareGates(max_failure_increase=1.0, fail_on_new_incentive_warning=True)
    result = compare(baseline, [configs["c_short"]], by="tag:config", gates=gates, rate_margin=0.5)
    assert result.only_baseline == ["long"] and not result.passed
    assert [g.key for g in result.groups] == ["short"] and result.groups[0].gates[0].passed
    missing = {(g.gate, g.group, g.passed) for g in result.only_baseline_gates}
    assert missing == {
        ("max_failure_increase", "long", False),
        ("new_incentive_warnings", "long", False),
    }
    message = result.only_baseline_gates[0].message
    assert message.startswith("max_failure_increase: cannot be verified, the candidate has no")
    assert "group long" in message
    failed = {c.name for c in result.cases() if not c.passed}
    assert failed == {"long/gate:max_failure_increase", "long/gate:new_incentive_warnings"}
    data = result.to_dict()
    assert [g["group"] for g in data["only_baseline_gates"]] == ["long", "long"]
    assert result.verdict == "inconclusive"  # (short held; long was not compared)
    ungated = compare(baseline, [configs["c_short"]], by="tag:config", rate_margin=0.5)
    assert ungated.passed and ungated.verdict == "inconclusive"
    assert any(n.startswith("group long: only the baseline") for n in ungated.notes)


def test_a_group_only_the_candidate_has_is_a_note_not_a_failure(
    configs: dict[str, Path],
) -> None:
    gates = CompareGates(max_failure_increase=1.0)
    candidate = [configs["c_short"], configs["c_new"]]
    result = compare([configs["b_short"]], candidate, by="tag:config", gates=gates, rate_margin=0.5)
    assert result.only_candidate == ["new"] and result.only_baseline_gates == []
    assert result.passed and result.verdict == "held"
    assert any(n.startswith("group new: only the candidate") for n in result.notes), result.notes


def test_a_candidate_whose_every_episode_raised_regresses_on_error_rate(tmp_path: Path) -> None:
    """Its error rate is over every episode begun, so it is measured; the metrics over ended
    episodes have no value of the candidate and say why; a gate on them cannot be verified."""
    crashed = crashing_cartpole(tmp_path / "crashed.mcap", 30, lambda seed: True)
    base = crashing_cartpole(tmp_path / "clean.mcap", 30)
    gates = CompareGates(max_error_increase=0.05, max_failure_increase=0.05)
    result = compare([base], [crashed], gates=gates)
    (group,) = result.groups
    errors = group.metric("error_rate")
    assert (errors.baseline, errors.candidate, errors.verdict) == (0.0, 1.0, "regressed")
    assert result.verdict == "regressed" and not result.passed
    why = "the candidate has no ended episode (its 30 episodes: error 30)"
    for name in ("failure_rate", "truncation_rate", "return"):
        metric = group.metric(name)
        assert metric.candidate is None and metric.candidate_n == 0, name
        assert metric.not_comparable == why and metric.test == "none", name
    assert group.metric("return").verdict == "inconclusive"
    assert {g.gate: (g.passed, g.message) for g in group.gates} == {
        "max_failure_increase": (False, f"failure_rate: cannot be verified, {why} (group all)"),
        "max_error_increase": (
            False,
            "error_rate: the 95 % interval allows an increase of up to 1, beyond 0.05 (group all)",
        ),
    }
    assert any(n.startswith(f"group all: {why}: the rates (but error_rate)") for n in result.notes)


def test_sides_whose_every_episode_raised_are_compared_on_error_rate_alone(
    tmp_path: Path,
) -> None:
    """Both sides all errors: no regression to find (the rates are the same), the metrics over
    ended episodes are not computed on either side, and a gate on them cannot be verified."""
    base = crashing_cartpole(tmp_path / "base.mcap", 30, lambda seed: True)
    crashed = crashing_cartpole(tmp_path / "crashed.mcap", 30, lambda seed: True)
    result = compare([base], [crashed], gates=CompareGates(max_failure_increase=0.05))
    (group,) = result.groups
    errors = group.metric("error_rate")
    assert (errors.baseline, errors.candidate, errors.verdict) == (1.0, 1.0, "underpowered")
    why = (
        "neither side has an ended episode (the baseline's 30 episodes: error 30; the "
        "candidate's 30 episodes: error 30)"
    )
    for name in ("failure_rate", "truncation_rate", "return"):
        metric = group.metric(name)
        assert metric.baseline is None and metric.candidate is None, name
        assert metric.not_comparable == why, name
    (gate,) = group.gates
    assert (
        not gate.passed and gate.message == f"failure_rate: cannot be verified, {why} (group all)"
    )
    assert result.verdict == "underpowered" and not result.passed
    ungated = compare([base], [crashed])
    assert ungated.passed and ungated.verdict == "underpowered"


def test_a_group_whose_candidate_episodes_all_raised_is_compared(tmp_path: Path) -> None:
    def record(name: str, config: str, crash: bool) -> Path:
        env = Crashing(gym.make("CartPole-v1", max_episode_steps=20), lambda seed: crash)
        with RecordEvidence(env, tmp_path / name, tags={"config": config}) as recorded:
            for seed in range(10):
                recorded.reset(seed=seed)
                try:
                    while not any(recorded.step(0)[2:4]):
                        pass
                except RuntimeError:
                    pass
        return tmp_path / name

    baseline = [record("b_short.mcap", "short", False), record("b_long.mcap", "long", False)]
    candidate = [record("c_short.mcap", "short", False), record("c_long.mcap", "long", True)]
    result = compare(baseline, candidate, by="tag:config")
    assert result.only_baseline == [] and [g.key for g in result.groups] == ["long", "short"]
    long = result.groups[0]
    assert long.verdict == "regressed" and long.metric("error_rate").candidate == 1.0
    assert long.metric("failure_rate").not_comparable is not None
    assert result.verdict == "regressed" and not result.passed


def test_a_side_of_one_unended_episode_says_it_in_the_singular(tmp_path: Path) -> None:
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "one.mcap") as env:
        env.reset(seed=0)
        env.step(0)
    base = record_episodes("CartPole-v1", tmp_path / "base.mcap", episodes=2).path
    with pytest.raises(
        ConfigurationError,
        match=r"^the baseline has no episode that ended or raised \(success, failure, truncated "
        r"or error\) to compare "
        r"\(its 1 episode: incomplete 1\): record some",
    ):
        compare([tmp_path / "one.mcap"], [base])
