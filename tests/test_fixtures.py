"""The golden evidence fixtures keep the properties fixtures/README.md documents.

Regenerate them with ``python fixtures/make_fixtures.py``; a regenerated file that lost its
property fails here.
"""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow.compute as pc
import pytest

from episode_audit import Evidence, open_evidence

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
NAMES = ["clean.mcap", "terms_mismatch.mcap", "unlabeled_failure.mcap", "torn.mcap"]

MISMATCH = (1, 3)
"""(episode, step) of terms_mismatch.mcap whose reward is its terms' sum + 0.5."""
MISMATCH_RESIDUAL = 0.5
TORN_STEPS = 300


def evidence(name: str) -> Evidence:
    return open_evidence(FIXTURES / name)


@pytest.mark.parametrize("name", NAMES)
def test_fixture_is_small_and_documented(name: str) -> None:
    path = FIXTURES / name
    assert path.stat().st_size < 200_000
    readme = (FIXTURES / "README.md").read_text()
    assert f"`{name}`" in readme
    assert "test_fixtures.py" in readme


def test_readme_lists_every_fixture() -> None:
    assert sorted(p.name for p in FIXTURES.glob("*.mcap")) == sorted(NAMES)


def test_clean_has_successes_and_a_time_limit() -> None:
    ev = evidence("clean.mcap")
    assert ev.finished and ev.torn is None
    assert ev.run.env_id == "episode_audit/DrawerOpen-v0"
    assert ev.run.tags == {"policy": "scripted"}
    episodes = ev.episodes().to_pylist()
    assert [e["seed"] for e in episodes] == [0, 1, 2, 3, 4, 5]
    assert [e["outcome"] for e in episodes] == ["success"] * 4 + ["truncated", "success"]
    truncated = episodes[4]
    assert truncated["truncation_reason"] == "time_limit"
    assert truncated["truncated"] and not truncated["terminated"]
    assert truncated["length"] == 120
    assert all(e["failure_label"] is None for e in episodes)
    assert all(e["ended"] for e in episodes)
    assert ev.steps(columns=["episode"]).num_rows == sum(e["length"] for e in episodes)


def test_terms_mismatch_has_one_known_bad_step() -> None:
    ev = evidence("terms_mismatch.mcap")
    assert ev.finished
    assert ev.run.env_id is None
    episodes = ev.episodes().to_pylist()
    assert [e["outcome"] for e in episodes] == ["success"] * 3
    steps = ev.steps(columns=["episode", "step", "reward", "terms"]).to_pylist()
    assert len(steps) == 18
    residuals = {}
    for row in steps:
        terms = dict(row["terms"])
        assert set(terms) == {"progress", "step_cost"}
        residual = row["reward"] - math.fsum(terms.values())
        if residual != 0.0:
            residuals[(row["episode"], row["step"])] = residual
    assert residuals == {MISMATCH: MISMATCH_RESIDUAL}
    bad = next(r for r in steps if (r["episode"], r["step"]) == MISMATCH)
    assert bad["reward"] == 0.625
    assert dict(bad["terms"]) == {"progress": 0.25, "step_cost": -0.125}


def test_unlabeled_failure_ends_every_episode_in_an_unlabeled_failure() -> None:
    ev = evidence("unlabeled_failure.mcap")
    assert ev.finished
    assert ev.run.env_id == "CartPole-v1"
    episodes = ev.episodes().to_pylist()
    assert [e["seed"] for e in episodes] == [0, 1, 2]
    for episode in episodes:
        assert episode["outcome"] == "failure"
        assert episode["failure_label"] == "unlabeled"
        assert episode["terminated"] and not episode["truncated"]


def test_torn_is_unfinished_with_complete_episodes() -> None:
    ev = evidence("torn.mcap")
    assert not ev.finished
    assert ev.run_end is None
    assert ev.torn is not None
    assert ev.run.env_id == "CartPole-v1"
    assert ev.run.recorder["block_steps"] == 64
    episodes = ev.episodes()
    ended = episodes.filter(pc.equal(episodes["ended"], True)).to_pylist()
    assert len(ended) >= 1
    assert all(e["outcome"] == "failure" for e in ended)
    assert all(e["failure_label"] == "unlabeled" for e in ended)
    last = episodes.to_pylist()[-1]
    assert not last["ended"] and last["outcome"] == "incomplete"
    assert len(ended) == episodes.num_rows - 1
    assert ev.steps(columns=["episode"]).num_rows == TORN_STEPS
    assert sum(episodes["length"].to_pylist()) == TORN_STEPS
