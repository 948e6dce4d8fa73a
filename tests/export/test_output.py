"""The viewer exports' output file: refused at once when it cannot be written, its folder made,
never seen half-written (an unnamed temporary file where the OS has them)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from episode_audit import ConfigurationError, open_evidence
from episode_audit.cli import app
from episode_audit.export import export
from episode_audit.export._output import staged
from tests.support.killing import how_long, killed_midway
from tests.support.viewer_files import camera_file, random_cartpole_file

ROOT = Path(__file__).resolve().parents[2]
CLEAN = ROOT / "fixtures" / "clean.mcap"
VIEWERS = [
    pytest.param("foxglove", "x.foxglove.mcap", id="foxglove"),
    pytest.param("rerun", "x.rrd", id="rerun"),
]
UNWRITABLE = [
    pytest.param("/proc/self", id="proc"),  # no file can be made there, even by root
    pytest.param("/sys", id="sys"),  # permission denied, even to root
]


def _viewer(to: str) -> None:
    pytest.importorskip("foxglove" if to == "foxglove" else "rerun")


@pytest.mark.skipif(not Path("/sys/kernel").is_dir(), reason="needs Linux's /proc and /sys")
@pytest.mark.parametrize("folder", UNWRITABLE)
@pytest.mark.parametrize(("to", "name"), VIEWERS)
def test_an_output_that_cannot_be_written_is_one_error_line_exit_2(
    folder: str, to: str, name: str
) -> None:
    """rerun-sdk's ``RuntimeError: Failed to create file`` was a traceback (exit 1); Foxglove
    said ``Permission denied (os error 13)`` without the path."""
    _viewer(to)
    out = f"{folder}/{name}"
    expected = rf"^{re.escape(out)}: cannot create a file in {folder}: .+; give a path in a folder"
    with pytest.raises(ConfigurationError, match=expected):
        export([CLEAN], out, to=to)  # type: ignore[call-overload]
    result = CliRunner().invoke(app, ["export", str(CLEAN), "--to", to, "-o", out])
    assert result.exit_code == 2, result.output
    (line,) = result.output.strip().splitlines()
    assert re.match(rf"episode-audit: error: {expected[1:]}", line), line


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_a_viewer_library_that_cannot_create_the_file_is_a_configuration_error(
    tmp_path: Path,
) -> None:
    """Once the folder is checked the SDKs should not fail to create the file; if one does, the
    error names the output, not the SDK's temporary path."""
    pytest.importorskip("rerun")
    pytest.importorskip("foxglove")
    import foxglove
    import rerun as rr

    from episode_audit.export import foxglove as fg_export
    from episode_audit.export import rerun as rr_export
    from episode_audit.export._output import ViewerExport

    out = tmp_path / "x.rrd"
    result = ViewerExport(out, CLEAN, "rerun")
    with pytest.raises(ConfigurationError, match=rf"^{re.escape(str(out))}: rerun-sdk cannot"):
        rr_export._write(rr, Path("/proc/self/no/x.rrd"), open_evidence(CLEAN), result, None)
    rr_export._free_dropped_recordings()
    out = tmp_path / "x.mcap"
    with pytest.raises(
        ConfigurationError, match=rf"^{re.escape(str(out))}: foxglove-sdk cannot create it: "
    ):
        fg_export._open(foxglove, Path("/proc/self/no/x.mcap"), out, foxglove.Context(), None)


@pytest.mark.parametrize(("to", "name"), VIEWERS)
def test_a_missing_folder_is_created_as_parquet_and_recover_do(
    tmp_path: Path, to: str, name: str
) -> None:
    _viewer(to)
    out = tmp_path / "viewers" / "deeper" / name
    result = export([CLEAN], out, to=to)  # type: ignore[call-overload]
    assert result.path == out and out.is_file()
    assert sorted(p.name for p in out.parent.iterdir()) == [name]


@pytest.mark.parametrize(("to", "name"), VIEWERS)
def test_a_folder_that_is_a_file_is_said_so(tmp_path: Path, to: str, name: str) -> None:
    _viewer(to)
    blocker = tmp_path / "run.mcap"
    blocker.write_bytes(b"a file")
    for out in (blocker / name, blocker / "sub" / name):
        with pytest.raises(
            ConfigurationError,
            match=rf"^{re.escape(str(out))}: {re.escape(str(blocker))} is a file, not a folder",
        ):
            export([CLEAN], out, to=to)  # type: ignore[call-overload]
    assert blocker.read_bytes() == b"a file"


def test_the_cli_docs_viewer_example_runs_as_written(tmp_path: Path) -> None:
    """docs/cli.md's ``--to foxglove`` line writes into ``viewers/``, which need not exist."""
    pytest.importorskip("foxglove")
    text = (ROOT / "docs" / "cli.md").read_text()
    block = text.split("### `--to foxglove` and `--to rerun`", 1)[1].split("```bash", 1)[1]
    line = next(x for x in block.splitlines() if "--to foxglove" in x)
    args = shlex.split(line.split("#", 1)[0])
    assert args[:2] == ["episode-audit", "export"], args
    (tmp_path / "run.mcap").write_bytes(CLEAN.read_bytes())
    cwd = Path.cwd()
    os.chdir(tmp_path)
    try:
        result = CliRunner().invoke(app, args[1:])
    finally:
        os.chdir(cwd)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "viewers" / "run.foxglove.mcap").is_file()


@pytest.mark.skipif(not hasattr(os, "O_TMPFILE"), reason="no unnamed files (O_TMPFILE) here")
@pytest.mark.parametrize("overwrite", [False, True])
def test_nothing_shows_in_the_folder_until_the_export_is_complete(
    tmp_path: Path, overwrite: bool
) -> None:
    """The export was written to ``.NAME.<pid>.partial``, which a killed export left for good."""
    out = tmp_path / "view.mcap"
    if overwrite:
        out.write_bytes(b"old")
    before = sorted(p.name for p in tmp_path.iterdir())
    with staged(CLEAN, out, overwrite=overwrite) as temporary:
        temporary.write_bytes(b"new")
        assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.mcap"]
    assert out.read_bytes() == b"new"

    def fail_midway() -> None:
        with staged(CLEAN, tmp_path / "failed.mcap", overwrite=False) as temporary:
            temporary.write_bytes(b"half")
            raise RuntimeError("failed midway")

    with pytest.raises(RuntimeError, match="failed midway"):
        fail_midway()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.mcap"]


_EXPORT_CHILD = """
import sys, time
from episode_audit.export import export
print("go", flush=True)
start = time.perf_counter()
export([sys.argv[1]], sys.argv[2], to="foxglove")
print(time.perf_counter() - start, flush=True)
"""


@pytest.mark.skipif(not hasattr(os, "O_TMPFILE"), reason="no unnamed files (O_TMPFILE) here")
def test_a_killed_export_leaves_nothing_behind(tmp_path: Path) -> None:
    pytest.importorskip("foxglove")
    from mcap.reader import make_reader

    source = random_cartpole_file(tmp_path / "run.mcap", 20_000)
    out = tmp_path / "out"
    out.mkdir()
    took = how_long(_EXPORT_CHILD, str(source), str(out / "whole.foxglove.mcap"))
    runs = [(str(source), str(out / f"killed-{n}.foxglove.mcap")) for n in range(4)]
    assert killed_midway(_EXPORT_CHILD, runs, took / 2) >= 2  # most kills landed mid-export
    left = sorted(p.name for p in out.iterdir())
    assert all(name.endswith(".foxglove.mcap") for name in left), left
    for name in left:  # an output there is whole
        with open(out / name, "rb") as f:
            assert make_reader(f).get_summary() is not None


@pytest.mark.parametrize(("to", "name"), VIEWERS)
def test_the_success_line_says_how_to_look_at_the_file(tmp_path: Path, to: str, name: str) -> None:
    """It names no docs/ file (no installed package holds one) and says how to open it."""
    _viewer(to)
    out = tmp_path / "a b" / name
    result = CliRunner().invoke(app, ["export", str(CLEAN), "--to", to, "-o", str(out)])
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    text = "\n".join(lines).replace(str(CLEAN), "").replace(str(out), "")
    assert "docs/" not in text  # (the paths may)
    quoted = shlex.quote(str(out))
    if to == "foxglove":
        assert lines[-2:] == [
            "open it in Foxglove; a layout for it:",
            f"  python -m episode_audit.export.layout {quoted} > layout.json",
        ]
        command = lines[-1].strip().split(" > ")[0]
        args = shlex.split(command)
        done = subprocess.run(
            [sys.executable, *args[1:]], capture_output=True, text=True, cwd=ROOT, check=True
        )
        assert '"configById"' in done.stdout
    else:
        assert lines[-1] == f"open it with: rerun {quoted}"


def test_rerun_rows_have_the_episodes_timelines_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``/log`` rows had a fourth timeline, ``log_time``: the export's own wall clock."""
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    monkeypatch.setenv("RERUN_LOG_TICK", "1")  # (rerun-sdk's other timeline, asked for)
    out = tmp_path / "x.rrd"
    export([CLEAN], out, to="rerun")
    timelines: dict[str, set[str]] = {}
    for chunk in RrdReader(out).stream():
        if not chunk.is_static:
            timelines.setdefault(chunk.entity_path, set()).update(chunk.timeline_names)
    assert "/log" in timelines and "/steps/reward" in timelines
    assert all(names == {"step", "episode", "time"} for names in timelines.values()), timelines


@pytest.mark.parametrize(("to", "name"), VIEWERS)
def test_camera_frames_without_pillow_are_one_error_line_naming_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, to: str, name: str
) -> None:
    """The frames' PNG encoder was imported midway: ``ModuleNotFoundError: No module named
    'PIL'`` as a traceback (exit 1)."""
    _viewer(to)
    source = camera_file(tmp_path / "camera.mcap")
    monkeypatch.setitem(sys.modules, "PIL", None)  # as if Pillow were not installed
    out = tmp_path / name
    expected = (
        rf"--to {to}: needs the 'pillow' package \(to write camera frames\); install it with "
        rf"pip install 'episode-audit\[{to}\]'"
    )
    with pytest.raises(ConfigurationError, match=rf"^{expected}$"):
        export([source], out, to=to)  # type: ignore[call-overload]
    result = CliRunner().invoke(app, ["export", str(source), "--to", to, "-o", str(out)])
    assert result.exit_code == 2, result.output
    (line,) = result.output.strip().splitlines()
    assert re.fullmatch(rf"episode-audit: error: {expected}", line), line
    assert list(tmp_path.iterdir()) == [source]
    assert export([CLEAN], out, to=to).frames == 0  # type: ignore[call-overload]


@pytest.mark.parametrize(("to", "name"), [*VIEWERS, pytest.param("parquet", "p q", id="parquet")])
def test_a_path_with_spaces_stays_whole_in_the_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, to: str, name: str
) -> None:
    """The result broke ``ev/ünïcødé run ✓.foxglove.mcap`` at its space (COLUMNS=80)."""
    if to != "parquet":
        _viewer(to)
    monkeypatch.chdir(tmp_path)
    source = Path("edge/ünïcødé run ✓.mcap")
    source.parent.mkdir()
    random_cartpole_file(source, 5)
    out = f"ev/ünïcødé run ✓ of a longer name {name}"
    args = ["export", str(source), "--to", to, "-o", out]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    unwrapped = result.output.replace("\n  ", " ")  # (a path broken at a space made whole)
    assert out in result.output
    for path in (str(source), out):
        assert result.output.count(path) == unwrapped.count(path), result.output
    lines = result.output.splitlines()
    assert all(len(line) <= 80 for line in lines if not line.startswith("  python")), lines


@pytest.mark.parametrize(("to", "name"), [*VIEWERS, pytest.param("parquet", "pq", id="parquet")])
def test_the_result_fits_80_columns(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, to: str, name: str
) -> None:
    """At COLUMNS=80 the Foxglove result line was ~180 characters: the counts, the output and
    the layout command in one line."""
    if to != "parquet":
        _viewer(to)
    monkeypatch.chdir(tmp_path)
    source = Path("run.mcap")
    camera_file(source)
    (Path("out") / "old.steps.parquet").parent.mkdir()
    (Path("out") / "old.steps.parquet").write_bytes(b"")  # (removed: one more line)
    out = f"out/{name}"
    args = ["export", str(source), "--to", to, "-o", out, "--overwrite"]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) >= 2 and max(len(line) for line in lines) <= 80, lines
