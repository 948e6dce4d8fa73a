from __future__ import annotations

import re
import shutil
from pathlib import Path

import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import ConfigurationError, NotEvidenceError, open_evidence
from episode_audit.cli import app
from episode_audit.export import export
from tests.support.disk import fill_disk
from tests.support.mypy_run import mypy_output
from tests.support.viewer_files import random_cartpole_file

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
    with pytest.raises(
        ConfigurationError, match=r"episodes\.parquet: exists; pass overwrite=True to replace"
    ):
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
        f"wrote {result.episodes} episodes to {out / 'episodes.parquet'}\nand {result.steps} "
        f"steps to 2 *.steps.parquet file(s) in {out}"
    )


def _tagged_run(path: Path, tags: dict[str, str], seeds: range, limit: int) -> Path:
    import gymnasium as gym

    from episode_audit import RecordEvidence

    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=limit), path, tags=tags) as env:
        for seed in seeds:
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(seed % 2)
                done = term or trunc
    return path


def test_report_by_tag_is_reproduced_from_the_parquet_export(tmp_path: Path) -> None:
    """episodes and steps carry env_id and tag:NAME, so `report --by tag:policy` can be redone."""
    import pyarrow as pa

    from episode_audit import report

    runs = [
        _tagged_run(tmp_path / "a.mcap", {"policy": "left", "seed": "1"}, range(0, 4), 200),
        _tagged_run(tmp_path / "b.mcap", {"policy": "right"}, range(4, 7), 9),
        _tagged_run(tmp_path / "c.mcap", {"policy": "left"}, range(7, 9), 9),
    ]
    result = export(runs, tmp_path / "out")
    episodes = pq.read_table(result.episodes_file)
    assert set(episodes.column("env_id").to_pylist()) == {"CartPole-v1"}
    assert episodes.column("tag:seed").to_pylist().count("1") == 4  # null for b and c
    counts = episodes.group_by(["tag:policy", "outcome"]).aggregate([("episode", "count")])
    got = {(row["tag:policy"], row["outcome"]): row["episode_count"] for row in counts.to_pylist()}
    expected = {}
    for group in report(runs, by="tag:policy").groups:
        if group.success:
            expected[(group.key, "success")] = group.success
        if sum(group.failures.values()):
            expected[(group.key, "failure")] = sum(group.failures.values())
        if sum(group.truncations.values()):
            expected[(group.key, "truncated")] = sum(group.truncations.values())
    assert got == expected
    assert {outcome for _, outcome in got} == {"failure", "truncated"}, got
    steps = ds.dataset(result.steps_files, format="parquet").to_table()  # one schema for all
    by_policy = steps.group_by("tag:policy").aggregate([("reward", "sum")])
    returns = episodes.group_by("tag:policy").aggregate([("return", "sum")])
    assert dict(zip(*by_policy.to_pydict().values(), strict=True)) == pytest.approx(
        dict(zip(*returns.to_pydict().values(), strict=True))
    )
    assert steps.schema.field("env_id").type == pa.string()


def test_a_parquet_export_given_as_evidence_says_what_it_is(tmp_path: Path) -> None:
    out = tmp_path / "out"
    export([FIXTURES / "clean.mcap"], out)
    for written in (out / "episodes.parquet", out / "clean.steps.parquet"):
        with pytest.raises(
            NotEvidenceError,
            match=rf"^{re.escape(str(written))}: a Parquet file \(what export --to parquet "
            r"writes\), not evidence: pass the evidence files \(\*\.mcap\) instead$",
        ):
            open_evidence(written)


def test_a_failed_export_leaves_no_folder_it_made(tmp_path: Path) -> None:
    """As the command line, which opens its inputs first, leaves none."""
    bad = tmp_path / "notes.txt"
    bad.write_text("not an mcap\n")
    out = tmp_path / "new" / "out"
    with pytest.raises(NotEvidenceError, match=rf"^{re.escape(str(bad))}: "):
        export([bad], out)
    assert not (tmp_path / "new").exists()
    existing = tmp_path / "existing"
    existing.mkdir()
    with pytest.raises(NotEvidenceError, match=rf"^{re.escape(str(bad))}: "):
        export([bad], existing / "out")
    assert list(existing.iterdir()) == []  # (a folder it did not make stays)
    # an input exported before the failure stays, with its folder (the docstring says so)
    with pytest.raises(NotEvidenceError, match=rf"^{re.escape(str(bad))}: "):
        export([FIXTURES / "clean.mcap", bad], tmp_path / "partial")
    assert [p.name for p in (tmp_path / "partial").iterdir()] == ["clean.steps.parquet"]


def test_a_full_disk_is_one_error_naming_the_file_and_leaves_nothing(
    small_disk: Path, tmp_path: Path
) -> None:
    source = random_cartpole_file(tmp_path / "run.mcap", 400)
    filler = fill_disk(small_disk)
    for out in (small_disk / "exp", small_disk / "new" / "exp"):
        with pytest.raises(
            ConfigurationError,
            match=rf"^{re.escape(str(out / 'run.steps.parquet'))}: cannot write it: No space "
            "left on device; free some space there or choose another output path$",
        ):
            export([source], out)
        assert sorted(small_disk.iterdir()) == [filler]  # no half-written file, no folder
    filler.unlink()
    # the episodes file refused (the steps files took the last of the disk): none of it left
    exported = export([source], tmp_path / "exp")
    steps_size = exported.steps_files[0].stat().st_size
    with open(filler, "wb") as f:
        f.write(b"\0" * (2 * 2**20 - steps_size - 4096))
    with pytest.raises(ConfigurationError, match=r"episodes\.parquet: cannot write it: No space"):
        export([source], small_disk / "exp")
    assert not (small_disk / "exp" / "episodes.parquet").exists()


@pytest.mark.parametrize("out", ["exp-12:30-out", "file:out", "mock:x", "hdfs:x", "a:b/c:d"])
def test_a_local_out_with_a_colon_is_written_there(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, out: str
) -> None:
    """Only ``SCHEME://`` is a URL: any other ``:`` in a path is a character of a name."""
    source = shutil.copy(FIXTURES / "clean.mcap", tmp_path / "run.mcap")
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["export", str(source), "--out", out])
    assert (result.exit_code, result.stderr) == (0, "")
    assert sorted(p.name for p in (tmp_path / out).iterdir()) == [
        "episodes.parquet",
        "run.steps.parquet",
    ]
    assert pq.read_table(tmp_path / out / "run.steps.parquet").num_rows > 0


def test_a_file_url_out_is_its_local_path(tmp_path: Path) -> None:
    source = shutil.copy(FIXTURES / "clean.mcap", tmp_path / "run.mcap")
    result = export([source], f"file://{tmp_path}/out")
    assert result.episodes_file == tmp_path / "out" / "episodes.parquet"
    assert result.episodes_file.is_file()


@pytest.mark.parametrize("to", ["parquet", "foxglove", "rerun"])
def test_a_url_missing_a_slash_is_one_line_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, to: str
) -> None:
    source = shutil.copy(FIXTURES / "clean.mcap", tmp_path / "run.mcap")
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(
        app, ["export", str(source), "--to", to, "--out", "s3:/bucket-a/x.out"]
    )
    assert (result.exit_code, result.stderr) == (
        2,
        "episode-audit: error: --out s3:/bucket-a/x.out: a URL takes two slashes: "
        "s3://bucket-a/x.out; a local path: ./s3:/bucket-a/x.out\n",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]
    with pytest.raises(ConfigurationError, match=r"^--out s3:/b: a URL takes two slashes"):
        export([source], "s3:/b", to=to)


def test_mypy_takes_a_target_held_in_a_str(tmp_path: Path) -> None:
    found = mypy_output(
        tmp_path,
        """
        from episode_audit import export

        def run(target: str) -> None:
            reveal_type(export(["a.mcap"], "out", to=target))
            reveal_type(export(["a.mcap"], "out"))
            reveal_type(export(["a.mcap"], "out.rrd", to="rerun"))
        """,
    )
    revealed = re.findall(r'Revealed type is "(.*)"', found)
    assert revealed == [
        "episode_audit.export.parquet.ExportResult | episode_audit.export._output.ViewerExport",
        "episode_audit.export.parquet.ExportResult",
        "episode_audit.export._output.ViewerExport",
    ], found
    assert "Success: no issues found" in found, found
