"""Replay of ``error`` episodes whose loop caught the env's error and stepped on.

The env (tests/support/flaky.py) raises in episode 1's third step; the loop catches it and
keeps stepping the same env: three rows after the episode's end, then the next reset. The file
keeps the action of the step that raised: replay steps it again and expects the same error.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, open_evidence
from episode_audit.cli import app
from episode_audit.replay import replay
from episode_audit.replay import run as replay_run
from tests.support.flaky import FLAKY, FLAKY_FRESH, Flaky, record_flaky

RAISED = "not repeated by replay: episode 1's 3 steps after its end"
AFTER_RAISED = (
    r"differed at the reset \(reset_observation\) after calls to this env that replay does "
    r"not repeat \(episode 1's 3 steps after its end\): the state it began from cannot be "
    r"reproduced"
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
    # Each episode depends on its seed alone: every compared step is identical, and the step
    # that raised raises again. The rows the loop stepped after the error are not the
    # episode: the episode says so, and is identical.
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
    # Replayed in an env that counts no steps (its spec as recorded, ``persist`` changed
    # after it was made): step 0 of episode 0 already differs (nothing unrepeated before
    # it): diverged.
    path = record_flaky(tmp_path / "f.mcap", FLAKY)
    result = replay([path], env_factory=_uncounting)
    first = result.episodes[0]
    assert (first.status, first.divergence and first.divergence.describe()) == (
        "diverged",
        "step 0: observation expected [1.0, 1.0, 0.6369616873214543], got [1.0, 0.0, "
        "0.6369616873214543] (max abs diff 1)",
    )
    assert result.episodes[1].status == "diverged"


def _uncounting() -> gym.Env[Any, Any]:
    """``EpisodeAuditFlaky-v0`` made to count no steps after it was built (its spec unchanged)."""
    env = gym.make(FLAKY)
    env.unwrapped.persist = False  # type: ignore[attr-defined]
    return env


def test_episodes_after_steps_replay_does_not_repeat_are_not_replayable_never_diverged(
    tmp_path: Path,
) -> None:
    # The env counts every step it took, the one that raised and those after the end
    # included: the episodes after episode 1 began from a count replay cannot reproduce.
    path = record_flaky(tmp_path / "f.mcap", FLAKY)
    result = replay([path])
    assert [(e.episode, e.status) for e in result.episodes] == [
        (0, "identical"),
        (1, "identical"),
        (2, "not_replayable"),
        (3, "not_replayable"),
    ]
    assert result.episodes[1].reason == RAISED
    for later in result.episodes[2:]:
        assert later.reason is not None
        assert later.divergence is not None and later.divergence.step is None
        assert re.fullmatch(AFTER_RAISED, later.reason), later.reason
    assert result.episodes[2].restored == "seed 2; this env after 2 earlier episodes"
    assert result.ok and result.verified == 2


def test_selections_and_batches_give_the_verdicts_of_the_whole_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Replayed alone or in batches (a fresh env each), an episode that differs is replayed
    # again after the file's earlier episodes, whatever verdict it got: the same verdicts,
    # differences and restored state as a replay of the whole file.
    path = record_flaky(tmp_path / "f.mcap", FLAKY, episodes=6)
    whole = {e.episode: e for e in replay([path]).episodes}
    assert [whole[e].status for e in range(6)] == ["identical"] * 2 + ["not_replayable"] * 4
    for chosen in ([2], [3], [3, 4], [1, 4, 5], [5]):
        alone = replay([path], episodes=chosen).episodes
        assert alone == [whole[e] for e in chosen], chosen
    monkeypatch.setattr(replay_run, "MIN_BATCH_BYTES", path.stat().st_size // 3)
    assert len(replay_run._batches([path], None, None, 2)[0]) == 3
    batched = replay([path], jobs=2, imports=["tests.support.flaky"]).episodes
    assert batched == [whole[e] for e in range(6)]


def test_steps_after_an_ending_by_flags_are_not_repeated_either(tmp_path: Path) -> None:
    # No error: the loop steps twice past episode 0's termination, then resets.
    path = tmp_path / "past.mcap"
    with RecordEvidence(gym.make(FLAKY), path) as env:
        for seed in (0, 2):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, done, _, _ = env.step(0)
            if seed == 0:
                env.step(1)
                env.step(1)
    result = replay([path])
    assert [(e.episode, e.status, e.steps) for e in result.episodes] == [
        (0, "identical", 6),
        (1, "not_replayable", 0),
    ]
    assert result.episodes[0].reason == "not repeated by replay: episode 0's 2 steps after its end"
    assert re.search(
        r"after calls to this env that replay does not repeat \(episode 0's 2 steps after its "
        r"end\): the state it began from cannot be reproduced$",
        str(result.episodes[1].reason),
    )


class ResetRefused(Flaky):
    """Refuses its first reset with seed 1; counts its resets (that one too) in observations."""

    def __init__(self) -> None:
        super().__init__(persist=False)
        self.resets = 0
        self.refused = False

    def _obs(self) -> Any:
        return np.array([self.t, self.resets, self.draw], np.float64)

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        self.resets += 1
        if seed == 1 and not self.refused:
            self.refused = True
            raise ValueError("reset refused")
        return super().reset(seed=seed, options=options)


gym.register("EpisodeAuditResetRefused-v0", entry_point=ResetRefused)


def test_episodes_after_a_reset_that_raised_are_not_replayable_when_they_differ(
    tmp_path: Path,
) -> None:
    path = tmp_path / "refused.mcap"
    with RecordEvidence(gym.make("EpisodeAuditResetRefused-v0"), path) as env:
        for seed in (0, 1, 2):
            try:
                env.reset(seed=seed)
            except ValueError:
                continue  # the loop resets again, with the next seed
            done = False
            while not done:
                _, _, done, _, _ = env.step(0)
    result = replay([path])
    assert [(e.episode, e.status) for e in result.episodes] == [
        (0, "identical"),
        (1, "not_replayable"),
        (2, "not_replayable"),
    ]
    assert result.episodes[2].reason == (
        "differed at the reset (reset_observation) after calls to this env that replay does "
        "not repeat (episode 1's reset, which raised ValueError): the state it began from "
        "cannot be reproduced"
    )


def test_the_command_says_not_replayable_and_why_and_exits_0(tmp_path: Path) -> None:
    path = record_flaky(tmp_path / "f.mcap", FLAKY)
    runner = CliRunner()
    args = ["replay", str(path), "--import", "tests.support.flaky"]
    out = runner.invoke(app, args, env={"COLUMNS": "80"})
    assert out.exit_code == 0, out.output
    assert "2 identical, 0 diverged, 2 not replayable: 2 episode(s) verified" in out.output
    assert "cannot be reproduced" in " ".join(out.output.split())
    assert max(len(line) for line in out.output.splitlines()) <= 80
    data = json.loads(runner.invoke(app, [*args, "--format", "json"]).output)
    assert [e["status"] for e in data["episodes"]] == [
        "identical",
        "identical",
        "not_replayable",
        "not_replayable",
    ]
    assert data["episodes"][1]["reason"] == RAISED


def test_the_file_keeps_the_action_of_the_step_that_raised(tmp_path: Path) -> None:
    path = record_flaky(tmp_path / "f.mcap", FLAKY_FRESH)
    assert open_evidence(path).error_actions().to_pylist() == [
        {"episode": 1, "action": 1},
        {"episode": 3, "action": 1},
    ]


class RaisesOther(Flaky):
    """Flaky, but its step that raises raises ``KeyError`` (``kind``: ``None`` raises none)."""

    def __init__(self, kind: type[Exception] | None) -> None:
        super().__init__(persist=False)
        self.kind = kind

    def step(self, action: Any) -> Any:
        try:
            return super().step(action)
        except RuntimeError:
            if self.kind is None:
                return self._obs(), 0.0, False, False, {}
            raise self.kind("another error") from None


@pytest.mark.parametrize(
    ("kind", "got"),
    [(None, "did not raise"), (KeyError, "raised KeyError: 'another error'")],
)
def test_a_step_that_raised_and_does_not_raise_the_same_again_is_not_replayable(
    tmp_path: Path, kind: type[Exception] | None, got: str
) -> None:
    # The same steps before it, the same action: an error the replayed env does not raise
    # (or raises another) may have come from outside the env. Never diverged.
    path = record_flaky(tmp_path / "f.mcap", FLAKY_FRESH)
    result = replay([path], env_factory=lambda: RaisesOther(kind))
    assert [(e.episode, e.status) for e in result.episodes] == [
        (0, "identical"),
        (1, "not_replayable"),
        (2, "identical"),
        (3, "not_replayable"),
    ]
    assert result.episodes[1].reason == (
        f"its 3rd step raised RuntimeError when recorded, and {got} in replay with the "
        "recorded action (an error may come from outside the env: memory, files, network)"
    )
    assert result.episodes[2].reason is None


class Picky(Flaky):
    """Raises on any action that is not 0 or 1 (before counting the step)."""

    def step(self, action: Any) -> Any:
        if action not in (0, 1):
            raise ValueError(f"not an action: {action!r}")
        return super().step(action)


def test_an_action_the_file_cannot_hold_is_not_repeated_and_said_so(tmp_path: Path) -> None:
    path = tmp_path / "picky.mcap"
    with RecordEvidence(Picky(persist=False), path) as env:
        for seed in (0, 2):
            env.reset(seed=seed)
            if seed == 0:
                with pytest.raises(ValueError, match="not an action"):
                    env.step("left")  # (no Discrete value: a null action_error)
    ev = open_evidence(path)
    assert ev.error_actions().to_pylist() == [{"episode": 0, "action": None}]
    result = replay([path], env_factory=lambda: Picky(persist=False))
    assert [(e.episode, e.status) for e in result.episodes] == [(0, "identical")]
    assert result.unstarted == 1  # (episode 1: reset, never stepped)
    assert result.episodes[0].reason == (
        "not repeated by replay: episode 0's 1st step, which raised ValueError"
    )
