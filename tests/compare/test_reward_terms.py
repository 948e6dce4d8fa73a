"""compare where the sides' reward terms differ: the reward changed, returns are not compared."""

from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import CompareGates, compare
from episode_audit.rollout import record_episodes
from episode_audit.tasks import DOOR_OPEN_ID

pytestmark = pytest.mark.mujoco


@pytest.fixture(scope="module")
def door(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("door")
    made = {}
    for name, kwargs in (("base", {}), ("proxy", {"proxy_reward": True})):
        made[name] = out / f"{name}.mcap"
        record_episodes(DOOR_OPEN_ID, made[name], policy="scripted", episodes=8, env_kwargs=kwargs)
    return made


def test_returns_of_other_reward_terms_are_not_compared(door: dict[str, Path]) -> None:
    # the same scripted policy and seeds; proxy_reward swaps shaping and failure_penalty for
    # progress_velocity: the return was `regressed` (p = 7e-5), exit 1
    result = compare([door["proxy"]], [door["base"]], gates=CompareGates(max_return_drop=1.0))
    (group,) = result.groups
    ret = group.metric("return")
    assert ret.verdict == "inconclusive" and ret.test == "none" and not ret.can_reject
    assert ret.not_comparable == (
        "the sides' rewards have different terms (baseline only: progress_velocity; candidate "
        "only: failure_penalty, shaping), so their returns sum different rewards and those "
        "terms are not compared; record both sides with the same reward (env kwargs, reward "
        "function) to compare returns"
    )
    assert result.verdict != "regressed"
    assert group.metric("success_rate").verdict == "underpowered"  # (outcomes still are)
    shared = [m.name for m in group.metrics if m.name.startswith("term:")]
    assert shared == ["term:ctrl_cost", "term:success_bonus"]
    assert (
        "group all: return: not compared (inconclusive), nor a max_return_drop gate: "
        + (ret.not_comparable)
        in result.notes
    )
    (gate,) = group.gates
    assert not gate.passed and gate.message.startswith("return: cannot be verified, the sides'")


def test_the_same_terms_on_both_sides_are_compared(door: dict[str, Path]) -> None:
    result = compare([door["base"]], [_again(door["base"])])
    assert result.groups[0].metric("return").not_comparable is None


def _again(path: Path) -> Path:
    copy = path.with_name("base_again.mcap")
    if not copy.exists():
        copy.write_bytes(path.read_bytes())
    return copy


def test_a_term_reported_in_some_episodes_only_does_not_stop_returns_being_compared(
    tmp_path: Path,
) -> None:
    """Walk reports ``success_bonus`` at a success only: the side that never succeeds lacks
    it, and its reward is still the same one."""
    import gymnasium as gym
    import numpy as np

    from episode_audit import RecordEvidence, open_evidence
    from tests.support.walk import Walk

    def record(path: Path, right: float) -> Path:
        rng = np.random.default_rng(0)
        with RecordEvidence(gym.wrappers.TimeLimit(Walk(), 12), path) as env:
            for seed in range(12):
                env.reset(seed=seed)
                while not any(env.step(int(rng.random() < right))[2:4]):
                    pass
        return path

    base, cand = record(tmp_path / "b.mcap", 0.7), record(tmp_path / "c.mcap", 0.2)
    outcomes = [
        {e["outcome"] for e in open_evidence(p).episodes().to_pylist()} for p in (base, cand)
    ]
    assert "success" in outcomes[0] and len(outcomes[0]) > 1 and "success" not in outcomes[1]
    group = compare([base], [cand]).groups[0]
    assert group.metric("return").not_comparable is None
    assert "term:success_bonus" not in [m.name for m in group.metrics]
    # every episode of one side falls (fall_penalty in each), every one of the other succeeds
    # (success_bonus in each): outcomes, not rewards, differ; the return gate holds
    falls, succeeds = record(tmp_path / "f.mcap", 0.0), record(tmp_path / "s.mcap", 1.0)
    result = compare([falls], [succeeds], gates=CompareGates(max_return_drop=1.0))
    assert result.groups[0].metric("return").not_comparable is None
    assert result.groups[0].metric("return").verdict == "improved" and result.passed
