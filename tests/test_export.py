from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from episode_audit import ConfigurationError
from episode_audit.export import export

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def test_overwrite_replaces_the_whole_export(tmp_path: Path) -> None:
    """Re-exporting fewer files with overwrite leaves no earlier steps file for a glob to read."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    shutil.copy(FIXTURES / "clean.mcap", a)
    shutil.copy(FIXTURES / "unlabeled_failure.mcap", b)
    out = tmp_path / "out"
    first = export([a, b], out)
    assert sorted(p.name for p in out.glob("*.steps.parquet")) == [
        "a.steps.parquet",
        "b.steps.parquet",
    ]
    with pytest.raises(ConfigurationError, match=r"episodes\.parquet: exists; pass --overwrite"):
        export([a], out)
    again = export([a], out, overwrite=True)
    assert again.removed == [out / "b.steps.parquet"]
    assert [p.name for p in out.glob("*.steps.parquet")] == ["a.steps.parquet"]
    steps = ds.dataset(sorted(out.glob("*.steps.parquet"))).to_table()
    assert set(steps.column("file").to_pylist()) == {str(a)}
    assert steps.num_rows == again.steps < first.steps
    assert set(pq.read_table(again.episodes_file).column("file").to_pylist()) == {str(a)}
    other = out / "notes.parquet"  # not an export's steps file: kept
    other.write_bytes(b"")
    assert export([a], out, overwrite=True).removed == []
    assert other.exists()


def test_the_result_names_unfinished_inputs_and_sums_up(tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = export([FIXTURES / "torn.mcap", FIXTURES / "clean.mcap"], out)
    (unfinished,) = result.unfinished
    assert unfinished[0] == FIXTURES / "torn.mcap"
    assert result.notes == [
        f"{FIXTURES / 'torn.mcap'} is unfinished ({unfinished[1]}): exported what it holds, "
        "its cut-off episode as incomplete"
    ]
    assert result.summary() == (
        f"wrote {result.episodes} episodes to {out / 'episodes.parquet'} and {result.steps} "
        f"steps to 2 *.steps.parquet file(s) in {out}"
    )
