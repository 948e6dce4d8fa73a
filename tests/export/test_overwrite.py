"""What ``--overwrite`` may replace: an earlier export or another file, never evidence, never a
file a live recorder is writing (``_output.refuse_evidence``), for every target."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import ConfigurationError, RecordEvidence, open_evidence
from episode_audit.cli import app
from episode_audit.export import export

ROOT = Path(__file__).resolve().parents[2]
CLEAN = ROOT / "fixtures" / "clean.mcap"
# (target, the output name, where the export writes in it: the output itself, or a file of the
# Parquet folder, an earlier export's steps file that an export with --overwrite removes)
TARGETS = [
    pytest.param("foxglove", "x.foxglove.mcap", "", id="foxglove"),
    pytest.param("rerun", "x.rrd", "", id="rerun"),
    pytest.param("parquet", "pq", "episodes.parquet", id="parquet-episodes"),
    pytest.param("parquet", "pq", "clean.steps.parquet", id="parquet-steps"),
    pytest.param("parquet", "pq", "old.steps.parquet", id="parquet-stale-steps"),
]


def _viewer(to: str) -> None:
    if to != "parquet":
        pytest.importorskip("foxglove" if to == "foxglove" else "rerun")


def _record(path: Path, steps: int = 5) -> RecordEvidence:
    env = RecordEvidence(gym.make("CartPole-v1"), path, flush_every_s=3600)
    env.reset(seed=0)
    for _ in range(steps):
        env.step(0)
    env.flush()
    return env


def _cli(to: str, out: Path) -> tuple[int, list[str]]:
    args = ["export", str(CLEAN), "--to", to, "-o", str(out), "--overwrite"]
    result = CliRunner().invoke(app, args)
    return result.exit_code, result.output.strip().splitlines()


@pytest.mark.parametrize(("to", "name", "inner"), TARGETS)
def test_a_live_recorder_s_file_is_never_replaced(
    tmp_path: Path, to: str, name: str, inner: str
) -> None:
    """export --overwrite replaced the file a recorder was writing (recover refused it): the
    recorder's evidence was deleted under it."""
    _viewer(to)
    out = tmp_path / name
    victim = out / inner if inner else out
    victim.parent.mkdir(exist_ok=True)
    env = _record(victim)
    try:
        expected = (
            rf"{re.escape(str(victim))}: is still being written by this process .*; an export "
            "never replaces a live recorder's file — choose another output path"
        )
        with pytest.raises(ConfigurationError, match=expected):
            export([CLEAN], out, to=to, overwrite=True)
        code, lines = _cli(to, out)
        assert code == 2
        assert len(lines) == 1 and lines[0].startswith(f"episode-audit: error: {victim}: is still")
        env.step(0)
    finally:
        env.close()
    assert open_evidence(victim).steps().num_rows == 6  # the recorder's file, whole


@pytest.mark.parametrize(("to", "name", "inner"), TARGETS)
@pytest.mark.parametrize("torn", [False, True], ids=["finished", "torn"])
def test_an_evidence_file_is_never_replaced(
    tmp_path: Path, to: str, name: str, inner: str, torn: bool
) -> None:
    """cp reacher.mcap victim.mcap; export cart.mcap --to foxglove -o victim.mcap --overwrite
    replaced the evidence with a viewer file."""
    _viewer(to)
    out = tmp_path / name
    victim = out / inner if inner else out
    victim.parent.mkdir(exist_ok=True)
    shutil.copyfile(CLEAN, victim)
    if torn:
        with open(victim, "r+b") as f:
            f.truncate(victim.stat().st_size // 2)
    before = victim.read_bytes()
    expected = (
        f"{victim}: is an evidence file; an export never replaces evidence — choose another "
        "output path"
    )
    stale = inner.startswith("old")  # (only an export with --overwrite removes it)
    for overwrite in (True,) if stale else (False, True):
        with pytest.raises(ConfigurationError, match=re.escape(expected)):
            export([CLEAN], out, to=to, overwrite=overwrite)
    code, lines = _cli(to, out)
    assert (code, lines) == (2, [f"episode-audit: error: {expected}"])
    assert victim.read_bytes() == before


@pytest.mark.parametrize(("to", "name", "inner"), TARGETS)
def test_an_earlier_export_or_another_file_is_still_replaced(
    tmp_path: Path, to: str, name: str, inner: str
) -> None:
    _viewer(to)
    out = tmp_path / name
    export([CLEAN], out, to=to)  # type: ignore[call-overload]
    export([CLEAN], out, to=to, overwrite=True)  # type: ignore[call-overload]
    other = out / inner if inner else out
    other.write_text("notes\n")
    export([CLEAN], out, to=to, overwrite=True)  # type: ignore[call-overload]
    assert not other.exists() or other.read_bytes() != b"notes\n"
