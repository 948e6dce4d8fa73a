"""The same run twice on one side (a torn file and its recovered copy, a copy) is refused."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import (
    ConfigurationError,
    RecordEvidence,
    compare,
    open_evidence,
    recover,
    report,
)
from episode_audit.cli import app
from episode_audit.rollout import record_episodes

SAME_RUN = (
    r"hold the same run \(the same run metadata: a copy, or a recovered copy beside its torn "
    r"original\), whose episodes would count twice; pass one of them"
)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("same_run")
    base = out / "base" / "run.mcap"
    base.parent.mkdir()
    record_episodes("CartPole-v1", base, episodes=8)
    cand = out / "cand"
    cand.mkdir()
    env = RecordEvidence(gym.make("CartPole-v1"), cand / "whole.mcap", block_steps=16)
    env.action_space.seed(0)
    for seed in range(8):
        env.reset(seed=seed)
        while not any(env.step(env.action_space.sample())[2:4]):
            pass
    env.flush()  # (as a killed process leaves it: flushed, no summary)
    (cand / "run.mcap").write_bytes((cand / "whole.mcap").read_bytes()[:-10])
    env.close()
    (cand / "whole.mcap").unlink()
    recover(cand / "run.mcap", cand / "run.recovered.mcap")
    return {"base": base, "torn": cand / "run.mcap", "recovered": cand / "run.recovered.mcap"}


def test_a_torn_file_and_its_recovered_copy_on_one_side_are_refused(
    files: dict[str, Path],
) -> None:
    # each counted its episodes: the candidate's 8 counted 16 times over, and the verdict moved
    both = [files["torn"], files["recovered"]]
    with pytest.raises(ConfigurationError, match=f"^the candidate's .*run.mcap and .*{SAME_RUN}"):
        compare([files["base"]], both)
    with pytest.raises(ConfigurationError, match=f"^the baseline's .*run.mcap and .*{SAME_RUN}"):
        compare(both, [files["base"]])
    with pytest.raises(ConfigurationError, match=f"run.recovered.mcap {SAME_RUN}"):
        report(both, by="all")
    assert compare([files["base"]], [files["recovered"]]).groups[0].candidate_episodes == 8


def test_the_command_line_refuses_them_in_one_line(files: dict[str, Path], tmp_path: Path) -> None:
    copy = tmp_path / "copy.mcap"
    shutil.copyfile(files["base"], copy)
    runner = CliRunner()
    for args in (
        ["compare", str(files["base"]), "--candidate", str(files["torn"].parent)],
        ["report", str(files["base"]), str(copy)],
    ):
        result = runner.invoke(app, [*args, "-j", "1"])
        assert result.exit_code == 2 and "Traceback" not in result.stderr
        assert "hold the same run" in result.stderr and "pass one of them" in result.stderr


def test_runs_begun_in_one_microsecond_with_one_configuration_are_two_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (workers a scheduler starts at once: the same run metadata, to the microsecond)
    from datetime import datetime, timezone

    import episode_audit.record.settings as settings

    class OneInstant(datetime):
        @classmethod
        def now(cls, tz: Any = None) -> OneInstant:
            return cls(2026, 11, 29, 12, 0, 0, 123456, tzinfo=timezone.utc)

    monkeypatch.setattr(settings, "datetime", OneInstant)
    paths = [tmp_path / "worker-0.mcap", tmp_path / "worker-1.mcap"]
    for path in paths:
        record_episodes("CartPole-v1", path, episodes=3)
    assert open_evidence(paths[0]).run.to_metadata() == open_evidence(paths[1]).run.to_metadata()
    assert report(paths, by="all").groups[0].episodes == 6
