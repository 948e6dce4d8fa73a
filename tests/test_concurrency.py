"""Several recording processes at once, and audits of a file that is still being written."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import IO

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, check, open_evidence, report
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError

REPO = Path(__file__).resolve().parents[1]
runner = CliRunner()

RECORDER = """
import sys
import gymnasium as gym
from episode_audit import RecordEvidence

path, episodes, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
with RecordEvidence(gym.make("CartPole-v1"), path, tags={"worker": str(seed)}) as env:
    env.action_space.seed(seed)
    for e in range(episodes):
        env.reset(seed=seed * 1000 + e)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
"""

# Records in phases; after each it flushes, says how far it got, and waits for a line on stdin.
STEPPED = """
import json, sys
import gymnasium as gym
from episode_audit import RecordEvidence

env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], flush_every_s=3600)
env.action_space.seed(0)
episodes = steps = 0
def phase(whole, extra):
    global episodes, steps
    for _ in range(whole):
        env.reset(seed=episodes)
        episodes += 1
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
            done = terminated or truncated
    if extra:
        env.reset(seed=episodes)
        episodes += 1
        for _ in range(extra):
            env.step(0)
            steps += 1
    env.flush()
    print(json.dumps({"episodes": episodes, "steps": steps}), flush=True)
    sys.stdin.readline()
phase(3, 0)
phase(2, 4)   # the last episode is still running
env.close()
print(json.dumps({"closed": True}), flush=True)
"""

# Records as fast as it can, flushing often, until told to stop.
STREAMING = """
import sys, time
import gymnasium as gym
from episode_audit import RecordEvidence

env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], block_steps=64, flush_every_s=0.01)
env.action_space.seed(0)
print("started", flush=True)
deadline = time.monotonic() + float(sys.argv[2])
episode = 0
while time.monotonic() < deadline:
    env.reset(seed=episode)
    episode += 1
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
env.close()
"""


def python(script: str, *args: str, stdin: int | None = None) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen(
        [sys.executable, "-c", script, *args],
        stdin=stdin,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=REPO,
    )


def stop(child: subprocess.Popen[str]) -> None:
    """Kill the child if it still runs, and close its pipes."""
    if child.poll() is None:
        child.kill()
    child.communicate(timeout=60)


def cli(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def test_several_processes_record_separate_files_at_once(tmp_path: Path) -> None:
    episodes = 15
    paths = [tmp_path / f"worker-{i}.mcap" for i in range(4)]
    children = [python(RECORDER, str(p), str(episodes), str(i)) for i, p in enumerate(paths)]
    for child in children:
        _, err = child.communicate(timeout=120)
        assert child.returncode == 0, err
    result = check(paths)
    assert result.ok and result.episodes == 4 * episodes
    for i, path in enumerate(paths):
        ev = open_evidence(path)
        assert ev.finished and ev.run.tags == {"worker": str(i)}
        table = ev.episodes()
        assert table.column("seed").to_pylist() == [i * 1000 + e for e in range(episodes)]
        assert sum(table.column("length").to_pylist()) == int(ev.run_end["steps"])  # type: ignore[index]
        assert ev.steps().num_rows == int(ev.run_end["steps"])  # type: ignore[index]


def _progress(stdout: IO[str]) -> dict[str, int]:
    line = stdout.readline()
    assert line, "the recording process ended early"
    data: dict[str, int] = json.loads(line)
    return data


def test_check_and_report_see_what_a_live_recorder_flushed(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    child = python(STEPPED, str(path), stdin=subprocess.PIPE)
    assert child.stdin is not None and child.stdout is not None
    try:
        for running in (0, 1):
            flushed = _progress(child.stdout)
            ev = open_evidence(path)
            assert not ev.finished
            assert ev.steps().num_rows == flushed["steps"]
            episodes = ev.episodes().to_pylist()
            assert len(episodes) == flushed["episodes"]
            assert [e["outcome"] for e in episodes][-1] == ("incomplete" if running else "failure")

            result = check([path])
            assert (result.episodes, result.steps) == (flushed["episodes"], flushed["steps"])
            (unfinished,) = [f for f in result.findings if f.code == "file_unfinished"]
            assert unfinished.severity == "warning"
            live = f"still being written by pid {child.pid}"
            assert unfinished.message.startswith(f"the file is {live}: what it had flushed was")
            assert result.ok  # warnings: exit 0, or 1 with --strict (docs/cli.md)
            assert cli("check", str(path))[0] == 0
            code, out, _ = cli("check", str(path), "--strict", "--format", "json")
            assert code == 1 and "file_unfinished" in {
                f["code"] for f in json.loads(out)["findings"]
            }

            rep = report([path])
            assert [name for name, _ in rep.unfinished] == [str(path)]
            (group,) = rep.groups
            assert group.episodes == flushed["episodes"] and group.incomplete == running
            code, out, _ = cli("report", str(path))
            assert code == 0 and "Unfinished files (still being written, or torn)" in out
            assert rep.unfinished[0][1].startswith(f"{live}: what it had flushed by byte ")
            code, out, _ = cli("show", str(path))
            assert code == 0 and f"UNFINISHED ({live}" in out
            code, out, _ = cli("replay", str(path), "--format", "json")
            replayed = json.loads(out)
            assert code == 0 and replayed["summary"]["identical"] == flushed["episodes"]
            assert [r["file"] for r in replayed["live"]] == [str(path)]
            reasons = [e["reason"] for e in replayed["episodes"]]
            assert reasons[-1] == (
                f"still being recorded (the file is {live}): its flushed steps replayed"
                if running
                else None
            )
            code, _, err = cli("recover", str(path), "--out", str(tmp_path / "out.mcap"))
            assert code == 2 and f"is {live}, not torn; wait for it to close" in err
            child.stdin.write("go on\n")
            child.stdin.flush()
        assert json.loads(child.stdout.readline()) == {"closed": True}
        assert child.wait(timeout=60) == 0
    finally:
        stop(child)
    result = check([path])
    assert "file_unfinished" not in {f.code for f in result.findings}
    assert report([path]).unfinished == []


@pytest.mark.parametrize("seconds", [2.0])
def test_reading_while_a_recorder_writes_never_fails(tmp_path: Path, seconds: float) -> None:
    """Open, check and report over and over while another process appends chunks."""
    path = tmp_path / "streaming.mcap"
    child = python(STREAMING, str(path), str(seconds))
    assert child.stdout is not None
    try:
        assert child.stdout.readline().strip() == "started"
        seen = [0]
        reads = 0
        while child.poll() is None:
            result = check([path])
            rep = report([path])
            assert sum(g.episodes for g in rep.groups) >= result.episodes  # read later
            assert result.steps >= seen[-1]  # what was flushed stays readable
            seen.append(result.steps)
            reads += 1
        assert child.wait(timeout=60) == 0
    finally:
        stop(child)
    assert reads >= 3 and seen[-1] > 0
    final = check([path])
    assert final.ok and final.steps >= seen[-1]
    assert open_evidence(path).finished


def test_a_second_recorder_on_the_same_path_is_refused_and_the_first_file_is_intact(
    tmp_path: Path,
) -> None:
    path = tmp_path / "shared.mcap"
    first = RecordEvidence(gym.make("CartPole-v1"), path)
    first.reset(seed=0)
    first.step(0)
    first.flush()
    size = path.stat().st_size
    held = f"another live recorder is writing this file \\(this process \\(pid {os.getpid()}\\)"
    for overwrite in (False, True):  # overwrite=True never clobbers a file that is held
        with pytest.raises(ConfigurationError, match=f"^{re.escape(str(path))}: {held}"):
            RecordEvidence(gym.make("CartPole-v1"), path, overwrite=overwrite)
    # the CLI (another recorder) is refused too, with one line on stderr
    code, _, err = cli("record", "CartPole-v1", "--out", str(path), "--overwrite")
    assert code == 2 and "another live recorder" in err and len(err.strip().splitlines()) == 1
    assert path.stat().st_size == size
    for _ in range(3):
        first.step(0)
    first.close()
    ev = open_evidence(path)
    assert ev.finished and ev.steps().num_rows == 4
    assert check([path]).ok


# Tries to record to a path (with overwrite or not) and prints the error it gets.
SECOND = """
import sys
import gymnasium as gym
from episode_audit import RecordEvidence
from episode_audit.errors import ConfigurationError

try:
    RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], overwrite=sys.argv[2] == "1")
except ConfigurationError as exc:
    print(exc, flush=True)
"""


def test_a_second_process_is_refused_while_the_first_records(tmp_path: Path) -> None:
    path = tmp_path / "shared.mcap"
    child = python(STEPPED, str(path), stdin=subprocess.PIPE)
    assert child.stdin is not None and child.stdout is not None
    try:
        flushed = _progress(child.stdout)
        size = path.stat().st_size
        for overwrite in ("0", "1"):
            other = python(SECOND, str(path), overwrite)
            out, err = other.communicate(timeout=60)
            assert other.returncode == 0, err
            assert out == (
                f"{path}: another live recorder is writing this file (pid {child.pid} holds its "
                "lock); a file has one writer — give each recorder its own path, e.g. the "
                "template 'runs/train-{index}.mcap'\n"
            )
            assert path.stat().st_size == size  # not a byte written, nothing truncated
        child.stdin.write("go on\n")
        child.stdin.flush()
        flushed = _progress(child.stdout)
        child.stdin.write("go on\n")
        child.stdin.flush()
        assert _progress(child.stdout) == {"closed": True}
        assert child.wait(timeout=60) == 0
    finally:
        stop(child)
    ev = open_evidence(path)
    assert ev.finished and ev.run.tags == {}  # the first recorder's file, complete
    assert ev.steps().num_rows == int(ev.run_end["steps"]) == flushed["steps"]  # type: ignore[index]
    assert ev.episodes().num_rows == flushed["episodes"]
    assert check([path]).ok
