from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from episode_audit import NotEvidenceError, open_evidence
from episode_audit.export import export
from tests.support.viewer_files import (
    aec_file,
    camera_file,
    leaves,
    recorded_resets,
    vector_file,
)

pytest.importorskip("rerun")

ROOT = Path(__file__).resolve().parents[1]
CHUNK = re.compile(r"^Chunk\(\S+\) with (\d+) rows \([^)]*\) - (\S+) - data columns: \[(.*)\]$")


def _rrd(*args: str) -> str:
    """Run rerun-sdk's own ``rerun rrd`` command (the viewer's reader) and return its output."""
    env = {**os.environ, "RERUN_ANALYTICS": "false"}
    done = subprocess.run(
        [sys.executable, "-c", "from rerun_cli.__main__ import main; main()", "rrd", *args],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    return done.stdout + done.stderr


def _rows(path: Path) -> tuple[Counter[str], dict[str, str]]:
    """Rows per entity path, and each path's data columns, as ``rerun rrd print`` lists them."""
    rows: Counter[str] = Counter()
    columns: dict[str, str] = {}
    for line in _rrd("print", str(path)).splitlines():
        match = CHUNK.match(line.strip())
        if match:
            rows[match[2]] += int(match[1])
            columns[match[2]] = match[3]
    return rows, columns


def _chunk_rows(path: Path) -> dict[str, list[dict[str, Any]]]:
    """Every row of the recording by entity path, read back with ``rerun.chunk.RrdReader``."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        rows[chunk.entity_path].extend(chunk.to_record_batch().to_pylist())
    return rows


@pytest.mark.parametrize("name", ["camera", "vector", "aec"])
def test_each_episode_starts_with_its_reset_observation(tmp_path: Path, name: str) -> None:
    """On the ``step`` timeline an episode's reset is at -1, before its step 0, with the
    observation ``Evidence.resets()`` holds, at the reset's time; no reward, flags or action.
    An episode reset and never stepped (vector) has its reset alone."""
    make = {"camera": camera_file, "vector": vector_file, "aec": aec_file}[name]
    source = make(tmp_path / f"{name}.mcap")
    out = tmp_path / f"{name}.rrd"
    export([source], out, to="rerun")
    rows = _chunk_rows(out)
    resets = recorded_resets(source)
    assert len(resets) == open_evidence(source).episodes().num_rows
    for entity in rows:
        if entity.endswith(("/reward", "/terminated", "/truncated", "/action")):
            assert all(r["step"] >= 0 for r in rows[entity]), entity
    plotted = 0
    for reset in resets:
        prefix, episode = reset["prefix"], reset["episode"]
        for path, recorded in leaves(reset["observation"]).items():
            entity = "/".join((f"{prefix}/steps/observation", *path))
            if entity not in rows:  # (the camera: an image, not numbers)
                continue
            mine = sorted(
                (r["time"].value, r["step"], r["Scalars:scalars"])
                for r in rows[entity]
                if r["episode"] == episode
            )
            (time, step, values), *steps = mine
            assert (time, step) == (reset["time_ns"], -1)
            np.testing.assert_array_equal(values, np.ravel(recorded))
            assert not steps or (steps[0][0] > time and steps[0][1] == 0)
            plotted += 1
    assert plotted >= len(resets)
    if name == "camera":
        frames = sorted(
            (r["time"].value, r["step"], r["EncodedImage:blob"])
            for r in rows["/camera/observation.camera"]
        )
        for reset in resets:
            (blob,) = [b for t, step, b in frames if (t, step) == (reset["time_ns"], -1)]
            pixels = np.asarray(Image.open(io.BytesIO(bytes(blob[0]))))  # (one blob a row)
            np.testing.assert_array_equal(pixels, reset["observation"]["camera"])


@pytest.mark.parametrize("name", ["camera", "vector", "aec"])
def test_rerun_reads_the_recording(tmp_path: Path, name: str) -> None:
    make = {"camera": camera_file, "vector": vector_file, "aec": aec_file}[name]
    source = make(tmp_path / f"{name}.mcap")
    out = tmp_path / f"{name}.rrd"
    result = export([source], out, to="rerun")
    assert "verified without error" in _rrd("verify", str(out))
    rows, columns = _rows(out)
    ev = open_evidence(source)
    episodes = ev.episodes().to_pylist()
    steps = ev.steps(columns=["episode"]).column("episode").to_pylist()
    assert rows["/log"] == len(episodes) and "TextLog:text" in columns["/log"]
    per_stream: Counter[str] = Counter()
    prefix = {
        e["episode"]: (f"/{e['agent']}" if e["agent"] else f"/env_{e['env_index']}")
        if name != "camera"
        else ""
        for e in episodes
    }
    for episode in steps:
        per_stream[prefix[episode]] += 1
    for stream, count in per_stream.items():
        for what in ("reward", "terminated", "truncated", "action"):
            assert rows[f"{stream}/steps/{what}"] == count, (stream, what)
            assert "Scalars:scalars" in columns[f"{stream}/steps/{what}"]
    assert sum(per_stream.values()) == result.steps == len(steps)
    assert set(rows) - {"/__properties"} == set(result.paths)
    assert result.resets == len(ev.resets())
    if name == "camera":  # (10 steps, and the observations of 2 resets)
        assert rows["/steps/terms/progress"] == rows["/steps/terms/effort"] == 10
        assert rows["/steps/observation/state"] == rows["/steps/observation/mode"] == 12
        assert rows["/camera/observation.camera"] == result.frames == 12
        assert "EncodedImage:blob" in columns["/camera/observation.camera"]


def test_a_disabled_sdk_is_an_error_not_a_missing_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from episode_audit import ConfigurationError

    monkeypatch.setenv("RERUN", "off")
    out = tmp_path / "none.rrd"
    with pytest.raises(ConfigurationError, match=r"rerun-sdk wrote nothing; is logging turned"):
        export([ROOT / "fixtures" / "clean.mcap"], out, to="rerun")
    assert list(tmp_path.iterdir()) == []


def test_a_missing_viewer_library_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    from episode_audit import ConfigurationError

    monkeypatch.setitem(sys.modules, "rerun", None)  # as if rerun-sdk were not installed
    with pytest.raises(
        ConfigurationError,
        match=r"--to rerun: needs the 'rerun-sdk' package; install it with pip install "
        r"'episode-audit\[rerun\]'",
    ):
        export([ROOT / "fixtures" / "clean.mcap"], Path("unused.rrd"), to="rerun")


def test_cli_export_to_rerun_notes_what_is_not_plotted(tmp_path: Path) -> None:
    import gymnasium as gym
    import numpy as np
    from typer.testing import CliRunner

    from episode_audit import RecordEvidence
    from episode_audit.cli import app
    from tests.support.envs import ScriptedEnv

    wide = gym.spaces.Box(-1, 1, (80,), np.float32)
    env = ScriptedEnv(
        step_fn=lambda e, a: (np.zeros(80, np.float32), 1.0, e.t == 3, False, {}),
        reset_fn=lambda e: (np.zeros(80, np.float32), {}),
        observation_space=wide,
    )
    source = tmp_path / "wide.mcap"
    with RecordEvidence(env, source) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            rec.step(0)
    out = tmp_path / "wide.rrd"
    result = CliRunner().invoke(app, ["export", str(source), "--to", "rerun", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "not plotted (more than 64 numbers, digests or text): observation" in result.output
    assert "wrote 1 episode, 3 steps" in result.output  # (it said "1 episodes")
    rows, _ = _rows(out)
    assert rows["/steps/reward"] == 3 and "/steps/observation" not in rows


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc")
def test_exporting_many_files_in_one_process_keeps_no_threads(tmp_path: Path) -> None:
    # rerun-sdk ends a dropped stream's two threads only when asked: 2 000 files, 4 000 threads
    source = vector_file(tmp_path / "vector.mcap")
    export([source], tmp_path / "first.rrd", to="rerun")  # (the SDK's own threads start)
    threads = len(os.listdir("/proc/self/task"))
    for k in range(5):
        export([source], tmp_path / f"{k}.rrd", to="rerun")
    assert len(os.listdir("/proc/self/task")) <= threads


def test_a_rerun_export_named_mcap_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    """An .rrd named .mcap would read as an evidence file to check, replay and report."""
    from typer.testing import CliRunner

    from episode_audit.cli import app

    out = tmp_path / "run.mcap"
    source = str(ROOT / "fixtures" / "clean.mcap")
    result = CliRunner().invoke(app, ["export", source, "--to", "rerun", "-o", str(out)])
    assert result.exit_code == 2 and not out.exists()
    assert result.output.strip() == (
        f"episode-audit: error: --out {out}: --to rerun writes an .rrd recording, not MCAP; "
        "name it run.rrd (an .mcap name reads as an evidence file to check, replay and report)"
    )


def test_a_rerun_export_given_as_evidence_says_what_it_is(tmp_path: Path) -> None:
    out = tmp_path / "run.rrd"
    export([ROOT / "fixtures" / "clean.mcap"], out, to="rerun")
    with pytest.raises(
        NotEvidenceError,
        match=rf"^{re.escape(str(out))}: a Rerun recording \(what export --to rerun writes\), "
        r"not evidence: pass the evidence files \(\*\.mcap\) instead$",
    ):
        open_evidence(out)


def test_a_full_disk_is_one_error_naming_the_output(small_disk: Path, tmp_path: Path) -> None:
    """Full before the export (the SDK cannot create its file) or midway (its writer fails)."""
    from episode_audit import ConfigurationError
    from tests.support.disk import export_stderr, fill_disk
    from tests.support.viewer_files import random_cartpole_file

    source = random_cartpole_file(tmp_path / "run.mcap", 400)  # (an .rrd of about 60 KB)
    filler = fill_disk(small_disk)
    full = filler.stat().st_size
    error = "cannot write it: No space left on device; free some space there or choose another "
    for free in (0, 16 * 1024):
        os.truncate(filler, full - free)
        for out in (small_disk / "run.rrd", small_disk / "new" / "run.rrd"):
            with pytest.raises(ConfigurationError, match=rf"^{re.escape(f'{out}: {error}')}"):
                export([source], out, to="rerun")
            assert sorted(small_disk.iterdir()) == [filler]  # no output, no folder it made
    # one line: neither a traceback nor rerun-sdk's own log lines
    assert export_stderr(source, "rerun", out) == (
        2,
        f"episode-audit: error: {out}: {error}output path\n",
    )
    assert sorted(small_disk.iterdir()) == [filler]


_FILLING_DISK = """
import sys
from pathlib import Path
from episode_audit import ConfigurationError
from episode_audit.export import export
source, out = sys.argv[1], Path(sys.argv[2])
for k in range(int(sys.argv[3])):
    try:
        export([source], out, to="rerun")
    except ConfigurationError as exc:
        assert "No space left on device" in str(exc), exc
    else:
        raise SystemExit(f"export {k} succeeded")
print("done")
"""


def test_a_disk_filling_midway_never_leaves_the_export_waiting(
    small_disk: Path, tmp_path: Path
) -> None:
    """rerun-sdk's file writer, failing midway, could leave its flush waiting forever (~1 in 10).

    In a process of its own, so that a wait is a failed test, not a stopped suite.
    """
    from tests.support.disk import fill_disk
    from tests.support.viewer_files import random_cartpole_file

    source = random_cartpole_file(tmp_path / "run.mcap", 400)  # (an .rrd of about 60 KB)
    filler = fill_disk(small_disk)
    os.truncate(filler, filler.stat().st_size - 16 * 1024)
    out = small_disk / "new" / "run.rrd"
    command = [sys.executable, "-c", _FILLING_DISK, str(source), str(out), "100"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert (done.returncode, done.stdout) == (0, "done\n"), done.stderr[-2000:]
    assert sorted(small_disk.iterdir()) == [filler]
