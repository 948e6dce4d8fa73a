"""A command whose stdout is a pipe its reader closed (``| head -1``) keeps its verdict.

Each command runs in a real process whose stdout is a pipe closed before the command writes
(as ``head -1`` closes it after one line, ``true`` at once): nothing is said of it, the work
goes on (the job summary is still written) and the exit code is the verdict's, which a CI job
with ``set -o pipefail`` reads.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures"


def _closed_stdout(args: list[str], summary: Path) -> tuple[int, str]:
    """``episode-audit ARGS`` with its stdout's reader gone before it writes: code, stderr."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "GITHUB_STEP_SUMMARY": str(summary)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "episode_audit", *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # (the command imports the package first: about a second)
    with proc.stderr:
        err = proc.stderr.read()
    return proc.wait(timeout=300), err


@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["check", "clean.mcap"], 0),
        (["check", "terms_mismatch.mcap"], 1),
        (["check", "terms_mismatch.mcap", "-f", "junit"], 1),
        (["report", "clean.mcap"], 0),
        (["report", "clean.mcap", "--min-success-rate", "0.99", "-f", "json"], 1),
        (["replay", "unlabeled_failure.mcap", "-f", "markdown"], 0),
        (["show", "clean.mcap"], 0),
    ],
)
def test_a_closed_stdout_exits_with_the_verdict(args: list[str], code: int, tmp_path: Path) -> None:
    args = [str(FIXTURES / a) if a.endswith(".mcap") else a for a in args]
    summary = tmp_path / "summary.md"
    assert _closed_stdout(args, summary) == (code, "")
    if args[0] != "show":  # (the work after the output was done: the job summary written)
        assert summary.stat().st_size > 0


def test_a_closed_stdout_with_an_unreadable_input_exits_2(tmp_path: Path) -> None:
    shutil.copy(FIXTURES / "clean.mcap", tmp_path / "clean.mcap")
    (tmp_path / "bogus.mcap").write_bytes(b"not evidence")
    code, err = _closed_stdout(["check", str(tmp_path)], tmp_path / "summary.md")
    assert code == 2
    assert [line.partition(":")[0] for line in err.splitlines()] == ["episode-audit"], err
    assert "bogus.mcap" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "args",
    [["--help"], ["--version"], ["check", "--help"], ["compare", "--help"], ["record", "--help"]],
    ids=" ".join,
)
def test_help_into_a_closed_pipe_exits_0(args: list[str], tmp_path: Path) -> None:
    """``episode-audit --help | true`` exited 1 (Click's own handling of a broken pipe)."""
    assert _closed_stdout(args, tmp_path / "summary.md") == (0, "")
