"""compare over files recorded over reward wrappers: returns in other units are not compared."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import CompareGates, compare
from tests.support.rewards import record_cartpole

NOT_COMPARED = (
    "record both sides over the same reward wrappers, or beneath them (the env's own rewards)"
)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("wrapped")
    made = {w: record_cartpole(out / f"{w}.mcap", w) for w in ("plain", "normalized", "scaled")}
    made["plain_again"] = record_cartpole(out / "plain_again.mcap")
    made["normalized_again"] = record_cartpole(out / "normalized_again.mcap", "normalized")
    for wrap in ("halved", "clipped", "clipped_half"):
        made[wrap] = record_cartpole(out / f"{wrap}.mcap", wrap)
    made["clipped_again"] = record_cartpole(out / "clipped_again.mcap", "clipped")
    return made


def test_a_drop_that_is_only_a_wrapper_taken_away_is_not_a_regression(
    files: dict[str, Path],
) -> None:
    # the same episodes (seeds, actions): returns x10 in the baseline, the env's in the
    # candidate; it was `regressed` (p = 0.0037), and exit 1
    result = compare([files["scaled"]], [files["plain"]])
    (group,) = result.groups
    ret = group.metric("return")
    assert ret.baseline == pytest.approx(10 * ret.candidate) and ret.pairs == 8
    assert ret.verdict == "inconclusive" and not ret.can_reject and ret.test == "none"
    # each side's mean in its own units; no difference, interval nor p-value (JSON nulls)
    data = ret.to_dict()
    assert data["difference"] is data["p_value"] is data["p_adjusted"] is data["mde"] is None
    assert data["interval"] == {"low": None, "high": None} and data["n_needed"] is None
    assert ret.not_comparable == (
        "the baseline's returns are TransformReward's and the candidate's the env's; "
        + NOT_COMPARED
    )
    assert result.verdict != "regressed" and result.passed
    assert group.notes == [
        "return: not compared (inconclusive), nor a max_return_drop gate: " + ret.not_comparable
    ]
    assert result.reward_notes == ["Baseline 1/1 files' returns are not the env's: TransformReward"]
    mismatches = {m.field: str(m) for m in result.mismatches}
    assert mismatches["reward_wrappers"] == (
        "reward_wrappers differs: baseline TransformReward; candidate (none)"
    )
    # (the function TransformReward was given has a placeholder in the baseline's env spec:
    # its time limit and kwargs are there, and the same as the candidate's)
    assert set(mismatches) == {"reward_wrappers"}
    case = {c.name: c for c in result.cases()}["all/return"]
    assert (case.status, case.passed) == ("inconclusive", True)
    assert case.message.startswith("return: inconclusive, not compared: the baseline's returns")


def test_a_return_gate_cannot_be_verified_and_outcome_gates_still_are(
    files: dict[str, Path],
) -> None:
    gates = CompareGates(max_return_drop=1000.0, max_failure_increase=0.5)
    result = compare([files["plain"]], [files["normalized"]], gates=gates)
    (group,) = result.groups
    by_gate = {g.gate: g for g in group.gates}
    assert by_gate["max_failure_increase"].passed  # outcomes are no rewards
    assert not by_gate["max_return_drop"].passed and not result.passed
    assert by_gate["max_return_drop"].message == (
        "return: cannot be verified, the baseline's returns are the env's and the candidate's "
        f"NormalizeReward(epsilon=1e-08, gamma=0.99)'s; {NOT_COMPARED} (group all)"
    )


def test_the_same_wrapper_on_both_sides_is_compared_and_said(files: dict[str, Path]) -> None:
    result = compare([files["normalized"]], [files["normalized_again"]])
    ret = result.groups[0].metric("return")
    assert ret.not_comparable is None and ret.can_reject is False  # (the same episodes)
    assert not result.mismatches
    assert result.reward_notes == [
        "Baseline 1/1 files' returns are not the env's: NormalizeReward",
        "Candidate 1/1 files' returns are not the env's: NormalizeReward",
    ]
    data = result.to_dict()
    assert data["reward_wrappers"]["candidate"] == [{"wrappers": ["NormalizeReward"], "files": 1}]
    assert data["groups"][0]["metrics"][-1]["not_comparable"] is None


def test_sides_that_mix_wrapped_and_plain_files_are_not_compared(files: dict[str, Path]) -> None:
    result = compare(
        [files["plain"], files["normalized"]], [files["plain_again"], files["normalized_again"]]
    )
    ret = result.groups[0].metric("return")
    assert ret.verdict == "inconclusive"
    assert ret.not_comparable is not None and ret.not_comparable.startswith(
        "the baseline's returns are a mix of the env's and NormalizeReward(epsilon=1e-08, "
        "gamma=0.99)'s and the candidate's a mix of the env's and NormalizeReward(epsilon=1e-08, "
        "gamma=0.99)'s;"
    )


def test_groups_whose_sides_share_their_wrappers_are_compared(files: dict[str, Path]) -> None:
    # by tag-less env id both are CartPole: one group; plain against plain is compared
    result = compare([files["plain"]], [files["plain_again"]], by="env")
    assert result.groups[0].metric("return").not_comparable is None
    assert result.reward_notes == [] and result.to_dict()["reward_wrappers"] == {
        "baseline": [],
        "candidate": [],
    }


def test_the_same_wrapper_set_up_otherwise_is_other_units_not_a_regression(
    files: dict[str, Path],
) -> None:
    # the same episodes under ClipReward to 1 and to 0.5 (recorded in the env spec): the
    # returns halve; the wrappers were compared by name only, and it was `regressed` (exit 1)
    result = compare([files["clipped"]], [files["clipped_half"]])
    ret = result.groups[0].metric("return")
    assert ret.candidate == pytest.approx(0.5 * ret.baseline) and ret.pairs == 8
    assert ret.verdict == "inconclusive" and ret.test == "none" and result.passed
    assert ret.not_comparable == (
        "the baseline's returns are ClipReward(max_reward=1.0, min_reward=-1.0)'s and the "
        "candidate's ClipReward(max_reward=0.5, min_reward=-1.0)'s; " + NOT_COMPARED
    )
    assert [str(m) for m in result.mismatches] == [
        "reward_wrappers differs: baseline ClipReward(max_reward=1.0, min_reward=-1.0); "
        "candidate ClipReward(max_reward=0.5, min_reward=-1.0)"
    ]
    same = compare([files["clipped"]], [files["clipped_again"]])
    assert not same.mismatches and same.groups[0].metric("return").not_comparable is None


def test_settings_no_file_holds_say_nothing_new(files: dict[str, Path]) -> None:
    # x10 and x0.5 by lambdas: the files hold a placeholder for each function, alike, so
    # nothing tells them apart (as before: by the wrapper's name)
    result = compare([files["scaled"]], [files["halved"]])
    ret = result.groups[0].metric("return")
    assert ret.not_comparable is None and not result.mismatches
