"""What an export's result line counts: episodes as ``show`` and ``report`` count them (the
unstarted apart), and what its note says of an unfinished input's cut-off episodes."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, open_evidence
from episode_audit.cli import app
from episode_audit.export import export
from episode_audit.format.records import unstarted

TARGETS = [
    pytest.param("parquet", "pq", id="parquet"),
    pytest.param("foxglove", "x.foxglove.mcap", id="foxglove"),
    pytest.param("rerun", "x.rrd", id="rerun"),
]


def _viewer(to: str) -> None:
    if to != "parquet":
        pytest.importorskip("foxglove" if to == "foxglove" else "rerun")


@pytest.fixture(scope="module")
def two_unstarted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One episode of 3 steps, then two resets never stepped (``show``: episodes 1, unstarted 2)."""
    path = tmp_path_factory.mktemp("counts") / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)
        env.reset(seed=1)  # the first episode left mid-way: incomplete, 3 steps
        env.reset(seed=2)  # reset, never stepped
    return path


@pytest.mark.parametrize(("to", "name"), TARGETS)
def test_the_unstarted_are_counted_apart_as_show_counts_them(
    two_unstarted: Path, tmp_path: Path, to: str, name: str
) -> None:
    """``show`` said "episodes 1, unstarted 2" and export "wrote 3 episodes"."""
    _viewer(to)
    episodes = open_evidence(two_unstarted).episodes()
    assert (episodes.num_rows, int(unstarted(episodes).sum())) == (3, 2)
    shown = CliRunner().invoke(app, ["show", str(two_unstarted)]).output
    assert re.search(r"^ episodes +1 ", shown, re.M) and re.search(r"^ unstarted +2 ", shown, re.M)
    out = tmp_path / name
    result = export([two_unstarted], out, to=to)  # type: ignore[call-overload]
    assert (result.episodes, result.unstarted) == (3, 2)
    assert result.summary().startswith("wrote 1 episode (+2 unstarted)")
    done = CliRunner().invoke(
        app, ["export", str(two_unstarted), "--to", to, "-o", str(out), "--overwrite"]
    )
    assert done.exit_code == 0, done.output
    assert "wrote 1 episode (+2 unstarted)" in done.output


def test_an_unfinished_input_without_episodes_names_no_cut_off_episode(tmp_path: Path) -> None:
    """A torn file with no episode was noted "exported what it holds, its cut-off episode as
    incomplete" with 0 episodes written."""
    path = tmp_path / "live.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, flush_every_s=3600)
    try:
        env.flush()  # the run metadata, no episode yet
        result = export([path], tmp_path / "pq")
        (note,) = result.notes
        assert result.episodes == 0
        assert note.startswith(f"{path} is unfinished (still being written")
        assert note.endswith("): exported what it holds"), note
        env.reset(seed=0)
        env.step(0)
        env.flush()
        result = export([path], tmp_path / "pq", overwrite=True)
        assert result.notes[0].endswith("exported what it holds, its cut-off episode as incomplete")
    finally:
        env.close()
