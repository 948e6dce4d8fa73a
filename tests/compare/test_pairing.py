"""compare pairs episodes only where the pairs leave out no task: no episode is dropped silently."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import CompareGates, compare
from episode_audit.rollout import record_episodes

CART = "tests.support.cartpole:"


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("pairing")
    made = {name: out / f"{name}.mcap" for name in ("car", "cart", "left", "cart_more")}
    record_episodes("MountainCar-v0", made["car"], episodes=8, max_episode_steps=20)
    record_episodes("CartPole-v1", made["cart"], policy=CART + "balance", episodes=8,
                    max_episode_steps=50)  # fmt: skip
    # the candidate's CartPole: a policy that drops the pole, on other seeds (100..)
    record_episodes("CartPole-v1", made["left"], policy=CART + "always_left", episodes=8,
                    seed=100, max_episode_steps=50)  # fmt: skip
    record_episodes("CartPole-v1", made["cart_more"], policy=CART + "balance", episodes=12,
                    max_episode_steps=50)  # fmt: skip
    made["car_again"] = out / "car_again.mcap"
    made["car_again"].write_bytes(made["car"].read_bytes())
    return made


def test_a_task_without_pairs_is_compared_unpaired_not_dropped(files: dict[str, Path]) -> None:
    # by all over two tasks: MountainCar's 8 episodes pair (the same file), CartPole's none
    # (other seeds). The pairs were half the episodes, so only MountainCar's were compared
    # (paired, no difference) and the candidate's CartPole, balancing no more, passed the gate
    gates = CompareGates(max_return_drop=2.0)
    result = compare(
        [files["car"], files["cart"]], [files["car_again"], files["left"]], gates=gates
    )
    (group,) = result.groups
    ret = group.metric("return")
    assert group.pairs == 8 and not ret.paired and ret.test == "Welch t"
    assert (ret.baseline_n, ret.candidate_n) == (16, 16) and ret.difference < -10
    assert all(not m.paired and m.baseline_n == 16 for m in group.metrics)
    (gate,) = group.gates
    assert not gate.passed and not result.passed
    assert not any("no pair" in note for note in result.notes)


def test_pairs_that_leave_episodes_out_say_how_many(files: dict[str, Path]) -> None:
    result = compare([files["cart"]], [files["cart_more"]])
    (group,) = result.groups
    assert group.pairs == 8 and group.metric("return").paired
    assert group.metric("return").candidate_n == 8
    assert result.notes == [
        "group all: the rates and the return compared paired on 8 pairs: 0 baseline and 4 "
        "candidate episodes have no pair (no episode of the other side began as they did) and "
        "are left out of it"
    ]


def test_a_gate_on_a_label_no_failure_has_is_checked_on_0_against_0(
    files: dict[str, Path],
) -> None:
    # docs/compare.md said such a gate passes; 0 against 0 over 8 pairs allows an increase
    # beyond 0.1, and a gate of 0.1 fails (as it would on a label that exists)
    tight = CompareGates(max_failure_increase_by_label={"fel": 0.1})
    (gate,) = compare([files["cart"]], [files["cart_more"]], gates=tight).groups[0].gates
    assert not gate.passed and gate.message.startswith(
        "failure_rate:fel: the 95 % interval allows an increase of up to 0.3"
    )
    assert gate.message.endswith("beyond 0.1 (group all)")
    loose = CompareGates(max_failure_increase_by_label={"fel": 0.5})
    result = compare([files["cart"]], [files["cart_more"]], gates=loose)
    assert result.passed and result.unmatched_labels == ["fel"]
