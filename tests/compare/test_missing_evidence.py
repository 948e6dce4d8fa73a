"""compare() where the candidate lacks evidence the baseline has: episodes its env raised in
(``error``) may not pass as ``held``."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import CompareGates, compare
from episode_audit.compare.core import _decide
from episode_audit.compare.groups import compare_group
from episode_audit.compare.sides import Side
from tests.support.crashing import crashing_cartpole


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
