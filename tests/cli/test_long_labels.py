"""A group label too long for its column (report's first column, at 80 columns) is broken where
it reads on: after a ``/`` or ``.``, else after a ``-`` or ``_``, never inside a word."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence
from episode_audit.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    ("folder", "lines"),
    [
        ("cartpole-evaluation-runs-november29", ["cartpole-evaluation-runs-", "november29/a.mcap"]),
        ("cartpole_evaluation_runs_2026_11_29", ["cartpole_evaluation_runs_2026_", "11_29/a.mcap"]),
    ],
)
def test_a_long_folder_name_in_a_group_label_keeps_its_words(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, folder: str, lines: list[str]
) -> None:
    """A 35-character folder without a ``/`` or ``.`` in it: the label was cut where the
    column ended (``cartpole-evaluation-runs-novembe`` / ``r29/a.mcap``)."""
    runs = tmp_path / folder
    runs.mkdir()
    for name in ("a.mcap", "b.mcap"):  # (two runs: a copy would be the same run twice)
        with RecordEvidence(gym.make("CartPole-v1"), runs / name) as env:
            for seed in range(2):
                env.reset(seed=seed)
                while not any(env.step(seed % 2)[2:4]):
                    pass
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["report", folder], env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.stderr
    out = result.stdout.splitlines()
    assert max(map(len, out)) <= 80
    firsts = [line.split("  ")[0].strip() for line in out]
    for name in ("a.mcap", "b.mcap"):
        at = firsts.index(lines[0])
        assert firsts[at : at + 2] == [lines[0], lines[1].replace("a.mcap", name)], out
        firsts = firsts[at + 2 :]
