"""Replay of ``error`` episodes whose loop caught the env's error and stepped on.

The env (tests/support/flaky.py) raises in episode 1's third step; the loop catches it and
keeps stepping the same env: three rows after the episode's end, then the next reset.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

from episode_audit import open_evidence
from episode_audit.replay import replay
from tests.support.flaky import FLAKY, FLAKY_FRESH, record_flaky

RAISED = (
    "not repeated by replay: episode 1's 3rd step, which raised RuntimeError and whose "
    "action is not recorded, and 3 steps after its end"
)


def test_the_recording_is_what_the_tests_say(tmp_path: Path) -> None:
    path = record_flaky(tmp_path / "f.mcap", FLAKY_FRESH)
    ev = open_evidence(path)
    records = ev.episodes().select(["outcome", "length", "error_type", "error_during"])
    assert records.to_pylist()[1] == {
        "outcome": "error",
        "length": 2,
        "error_type": "RuntimeError",
        "error_during": "step",
    }
    steps = ev.steps()
    rows = [s for e, s in zip(steps["episode"].to_pylist(), steps["step"].to_pylist()) if e == 1]
    assert rows == [0, 1, 2, 3, 4]  # 2 steps, then 3 rows after its end numbering on


def test_an_error_episode_compares_its_steps_up_to_the_raise_not_the_rows_after_it(
    tmp_path: Path,
) -> None:
    # Each episode depends on its seed alone: every compared step is identical. The rows the
    # loop stepped after the error are not the episode (nor is the step that raised, whose
    # action is not recorded): the episode says so, and is identical.
    path = record_flaky(tmp_path / "f.mcap", FLAKY_FRESH)
    result = replay([path])
    got = [(e.episode, e.status, e.steps, e.divergence) for e in result.episodes]
    assert got == [
        (0, "identical", 6, None),
        (1, "identical", 2, None),
        (2, "identical", 6, None),
        (3, "identical", 2, None),
    ]
    assert result.episodes[1].reason == RAISED
    assert result.episodes[0].reason is None
    assert [e.status for e in replay([path], episodes=[1, 3]).episodes] == ["identical"] * 2


def test_a_difference_before_the_raise_still_diverges(tmp_path: Path) -> None:
    # Replayed in an env that does not raise and counts no steps: step 0 of episode 0
    # already differs (nothing unrepeated before it): diverged.
    path = record_flaky(tmp_path / "f.mcap", FLAKY)
    result = replay([path], env_factory=lambda: gym.make(FLAKY_FRESH))
    first = result.episodes[0]
    assert (first.status, first.divergence and first.divergence.describe()) == (
        "diverged",
        "step 0: observation expected [1.0, 1.0, 0.6369616873214543], got [1.0, 0.0, "
        "0.6369616873214543] (max abs diff 1)",
    )
    assert result.episodes[1].status == "diverged"
