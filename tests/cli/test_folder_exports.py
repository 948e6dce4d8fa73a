"""Folders given to a command: the viewer exports in them are left out, and a line says so."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence
from episode_audit.cli import app
from episode_audit.export import export

runner = CliRunner()


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``runs/`` holds a CartPole recording and its Foxglove export beside it."""
    runs = tmp_path_factory.mktemp("folder") / "runs"
    runs.mkdir()
    with RecordEvidence(gym.make("CartPole-v1"), runs / "run.mcap") as env:
        for seed in range(2):
            env.reset(seed=seed)
            while not any(env.step(seed % 2)[2:4]):
                pass
    export([runs / "run.mcap"], runs / "run.foxglove.mcap", to="foxglove")
    return runs


@pytest.mark.parametrize("command", ["check", "report", "replay"])
def test_a_viewer_export_in_a_folder_is_left_out_in_one_line(runs: Path, command: str) -> None:
    """The export was read as an unreadable input: exit 2 ("a viewer file, not evidence")."""
    result = runner.invoke(app, [command, str(runs), "--format", "json"])
    assert result.exit_code == 0, result.stderr
    assert result.stderr == (
        "episode-audit: note: left out 1 viewer export(s) found in the directories given "
        f"({runs / 'run.foxglove.mcap'})\n"
    )
    data = json.loads(result.stdout)
    assert data["unreadable"] == []
    if command == "check":
        assert data["files"] == [str(runs / "run.mcap")]
    # named, the export is still refused
    named = runner.invoke(app, [command, str(runs / "run.foxglove.mcap")])
    assert named.exit_code == 2
    assert "Foxglove export of" in named.stderr and "(a viewer file), not evidence" in named.stderr


def test_show_given_the_folder_names_an_evidence_file_not_the_export(runs: Path) -> None:
    """The example it gave was the first *.mcap: the export (``run.foxglove.mcap``)."""
    result = runner.invoke(app, ["show", str(runs)])
    assert result.exit_code == 2
    assert result.stderr.endswith(f"name one of its .mcap files (e.g. {runs / 'run.mcap'})\n")
