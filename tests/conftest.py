"""Fixtures shared by every wing's tests: the small fake envs and the repository's paths."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.envs import ScriptedEnv

REPO = Path(__file__).resolve().parents[1]

# pytester for the plugin's own tests; the plugin itself (loaded by its pytest11 entry point
# once installed, named here for a checkout) for the reference tasks' contract tests.
pytest_plugins = ["pytester", "episode_audit_pytest"]


@pytest.fixture
def repo() -> Path:
    """The repository's root (``fixtures/``, ``docs/``, ``README.md`` live there)."""
    return REPO


@pytest.fixture
def ctrl_c() -> Iterator[None]:
    """Ctrl-C raises ``KeyboardInterrupt``, as in a user's script (whatever the runner set)."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


@pytest.fixture
def scripted_env() -> Callable[..., ScriptedEnv]:
    """Make a :class:`~tests.support.envs.ScriptedEnv` from ``step_fn`` / ``reset_fn``."""

    def make(**kwargs: Any) -> ScriptedEnv:
        return ScriptedEnv(**kwargs)

    return make


@pytest.fixture(autouse=True)
def _no_github_step_summary(monkeypatch: pytest.MonkeyPatch) -> None:
    """Commands append to ``$GITHUB_STEP_SUMMARY`` when it is set: never the CI's own."""
    monkeypatch.delenv("GITHUB_STEP_SUMMARY", raising=False)


@pytest.fixture(autouse=True)
def _no_columns(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test starts without ``$COLUMNS`` (a test that wants it sets it).

    Output not to a terminal is ``$COLUMNS`` wide when it is set, and pytest-xdist's workers
    set ``COLUMNS=80``.
    """
    monkeypatch.delenv("COLUMNS", raising=False)


_SMALL_DISK = "episode-audit-small-disk-"


@pytest.fixture
def small_disk() -> Any:
    """A 2 MiB tmpfs mounted for the test (root only; skipped where it cannot be mounted).

    Mounted in ``/tmp``, outside pytest's temporary folders (the session's ``$TMPDIR`` is one
    of them): a run killed midway leaves its mount behind, which in there would make the next
    run's clean-up of those folders fail ("Device or resource busy"). Such mounts, of
    processes that are gone, are unmounted here first.
    """
    _unmount_left_behind()
    mnt = Path(tempfile.mkdtemp(prefix=f"{_SMALL_DISK}{os.getpid()}-", dir="/tmp"))
    try:
        mounted = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
            capture_output=True, text=True, check=False, timeout=30,
        )  # fmt: skip
    except OSError as exc:
        mnt.rmdir()
        pytest.skip(f"cannot run mount: {exc}")
    if mounted.returncode != 0:
        mnt.rmdir()
        pytest.skip(f"cannot mount a small tmpfs (needs root): {mounted.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=True, timeout=30)
        mnt.rmdir()


def _unmount_left_behind() -> None:
    """Unmount and remove the small disks of test processes that no longer run."""
    prefix = f"/tmp/{_SMALL_DISK}"
    if not Path("/proc/mounts").is_file():
        return
    with open("/proc/mounts", encoding="utf-8") as mounts:
        points = [line.split()[1] for line in mounts if line.split()[1].startswith(prefix)]
    for point in points:
        pid = point[len(prefix) :].split("-")[0]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            subprocess.run(["umount", "-l", point], check=False, timeout=30)
            with contextlib.suppress(OSError):
                os.rmdir(point)
