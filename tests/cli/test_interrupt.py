"""A Ctrl-C while the command imports the package: one line and exit 130, no traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

# Stalls the import of gymnasium (which importing episode_audit does) for 30 s, after leaving
# a mark: the Ctrl-C then lands inside the package's import, every time.
_SLOW_GYMNASIUM = """
import importlib.abc, os, sys, time

class SlowGymnasium(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "gymnasium":
            open(os.environ["EPISODE_AUDIT_TEST_MARK"], "w").close()
            time.sleep(30)
        return None

sys.meta_path.insert(0, SlowGymnasium())
"""


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_while_the_command_imports_the_package_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "sitecustomize.py").write_text(_SLOW_GYMNASIUM)
    mark = tmp_path / "importing"
    env = {
        **os.environ,
        "PYTHONPATH": f"{REPO}{os.pathsep}{tmp_path}",
        "EPISODE_AUDIT_TEST_MARK": str(mark),
    }
    # (the module the console script runs: pyproject's [project.scripts])
    proc = subprocess.Popen(
        [sys.executable, "-m", "episode_audit_cli", "--help"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_default_sigint,  # (as from a shell: pytest-xdist's workers ignore it)
    )
    deadline = time.monotonic() + 60
    while not mark.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert mark.exists(), proc.communicate()[1]
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert out == ""
    assert err.splitlines() == ["episode-audit: error: interrupted (Ctrl-C): stopped"]


@pytest.mark.parametrize(
    ("signum", "code", "said"),
    [
        (signal.SIGINT, 130, "interrupted (Ctrl-C): stopped"),
        # a CI job's timeout: Python's default ended the command at once, the file torn
        (signal.SIGTERM, 143, "terminated (SIGTERM): stopped"),
    ],
)
def test_ctrl_c_or_sigterm_while_recording_is_one_line_and_the_file_is_whole(
    tmp_path: Path, signum: int, code: int, said: str
) -> None:
    evidence = tmp_path / "run.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "episode_audit_cli", "record", "CartPole-v1", "--episodes",
         "100000000", "-o", str(evidence)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_default_sigint,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while not evidence.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(1)  # (recording by now)
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert err.splitlines() == [f"episode-audit: error: {said}"]
    check = subprocess.run(
        [sys.executable, "-m", "episode_audit_cli", "check", str(evidence)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert check.returncode == 0, check.stdout + check.stderr


# Stalls recover's fsync of the finished file for 30 s, after leaving a mark.
_SLOW_FSYNC = """
import os, time

_fsync = os.fsync

def fsync(fd):
    open(os.environ["EPISODE_AUDIT_TEST_MARK"], "w").close()
    time.sleep(30)
    _fsync(fd)

os.fsync = fsync
"""


@pytest.mark.parametrize(
    ("signum", "code", "said"),
    [
        (signal.SIGINT, 130, "interrupted (Ctrl-C): stopped"),  # was nothing said
        (signal.SIGTERM, 143, "terminated (SIGTERM): stopped"),  # was ended at once
    ],
)
def test_ctrl_c_or_sigterm_while_recovering_is_one_line_and_writes_nothing(
    tmp_path: Path, signum: int, code: int, said: str
) -> None:
    # (a URL's recovery downloads into a temporary folder, removed so on the way out)
    site, written = tmp_path / "site", tmp_path / "out"
    site.mkdir()
    written.mkdir()
    (site / "sitecustomize.py").write_text(_SLOW_FSYNC)
    mark = tmp_path / "syncing"
    env = {
        **os.environ,
        "PYTHONPATH": f"{REPO}{os.pathsep}{site}",
        "EPISODE_AUDIT_TEST_MARK": str(mark),
    }
    out = written / "fixed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "episode_audit_cli", "recover", str(REPO / "fixtures" / "torn.mcap"),
         "-o", str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True, preexec_fn=_default_sigint,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while not mark.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert mark.exists(), proc.communicate()[1]
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert err.splitlines() == [f"episode-audit: error: {said}"]
    assert list(written.iterdir()) == []


def test_the_console_script_runs_the_command() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "episode_audit_cli", "--version"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("episode-audit"), done.stdout


def test_a_ctrl_c_the_work_swallowed_still_stops_the_command() -> None:
    import pytest
    import typer

    from episode_audit.cli._app import interruptible

    # a library that turns the KeyboardInterrupt into another error (as an interrupted
    # `import mujoco` did: "MuJoCo is not installed"), which replay made a verdict of
    said: list[str] = []

    def work() -> None:
        with interruptible():
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1)
            except BaseException as exc:
                said.append(f"not installed ({type(exc).__name__})")

    with pytest.raises(typer.Exit) as stopped:
        work()
    assert said == ["not installed (KeyboardInterrupt)"]
    assert stopped.value.exit_code == 130
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_stop_whose_work_then_failed_is_the_stop_in_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """SIGTERM to the whole process group (`timeout`, systemd) reaches the workers too: the
    interrupt landed in an import of this process's share of the work, which swallowed it, then
    the dead workers made a WorkerError, and replay said that and exited 2, not 143."""
    import typer

    from episode_audit.cli._app import fail, interruptible

    def work() -> None:
        with interruptible():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1)
            except BaseException:
                pass  # (swallowed)
            fail("a worker process ended before it returned its results")

    # (the command watches SIGTERM only where its handler is the default one; a test run
    # earlier in this process may have left another)
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with pytest.raises(typer.Exit) as stopped:
            work()
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert stopped.value.exit_code == 143
    assert capsys.readouterr().err == "episode-audit: error: terminated (SIGTERM): stopped\n"
