"""compare where a side holds several env ids: episodes pair only within an env id."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import compare
from episode_audit.rollout import record_episodes
from episode_audit.tasks import DOOR_OPEN_ID

pytestmark = pytest.mark.mujoco


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("tasks")
    made = {
        "cart": out / "cart.mcap",
        "door": out / "door.mcap",
    }
    record_episodes("CartPole-v1", made["cart"], episodes=8)  # seeds 0..7 on both tasks
    record_episodes(DOOR_OPEN_ID, made["door"], policy="scripted", episodes=8)
    for name in ("cart", "door"):
        made[f"{name}_again"] = out / f"{name}_again.mcap"
        made[f"{name}_again"].write_bytes(made[name].read_bytes())
    return made


def test_the_same_episodes_of_two_tasks_pair_within_each_task(files: dict[str, Path]) -> None:
    # the candidate holds the baseline's very episodes, its files listed the other way round:
    # seed 0 of CartPole paired with seed 0 of DoorOpen, so the same episodes read as changed
    # returns, and the results depended on the files' order
    baseline = [files["cart"], files["door"]]
    one = compare(baseline, [files["door_again"], files["cart_again"]])
    other = compare(baseline, [files["cart_again"], files["door_again"]])
    for result in (one, other):
        (group,) = result.groups
        ret = group.metric("return")
        assert group.pairs == 16 and ret.paired and ret.difference == 0
        assert ret.interval.low == ret.interval.high == 0 and ret.verdict == "held"
    assert one.to_dict()["groups"] == other.to_dict()["groups"]
    note = (
        "group all: episodes of several env ids in one group (the baseline's (CartPole-v1, "
        f"{DOOR_OPEN_ID}) and the candidate's (CartPole-v1, {DOOR_OPEN_ID})): its rates and "
        "returns pool the tasks, and episodes pair only within an env id; compare each task "
        "on its own with --by env (by='env')"
    )
    assert one.notes.count(note) == 1 and note in one.to_dict()["notes"]


def test_by_env_says_nothing_of_mixed_tasks(files: dict[str, Path]) -> None:
    result = compare(
        [files["cart"], files["door"]], [files["door_again"], files["cart_again"]], by="env"
    )
    assert [g.pairs for g in result.groups] == [8, 8] and not result.notes


@pytest.mark.filterwarnings("ignore:.*CartPole-v0 is out of date:DeprecationWarning")
def test_two_versions_compared_with_different_tasks_still_pair_on_seeds(tmp_path: Path) -> None:
    """One task a side (v0 against v1, ``different_tasks``): the same seeds pair across them."""
    v1, v0 = tmp_path / "v1.mcap", tmp_path / "v0.mcap"
    record_episodes("CartPole-v1", v1, episodes=8)
    record_episodes("CartPole-v0", v0, episodes=8)
    (group,) = compare([v1], [v0], different_tasks=True).groups
    assert group.pairs == 8 and group.metric("return").paired
