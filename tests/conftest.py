"""Fixtures shared by every wing's tests: the small fake envs and the repository's paths."""

from __future__ import annotations

import signal
import subprocess
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


@pytest.fixture
def small_disk(tmp_path: Path) -> Any:
    """A 2 MiB tmpfs mounted for the test (root only; skipped where it cannot be mounted)."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    try:
        mounted = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
            capture_output=True, text=True, check=False, timeout=30,
        )  # fmt: skip
    except OSError as exc:
        pytest.skip(f"cannot run mount: {exc}")
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs (needs root): {mounted.stderr.strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=True, timeout=30)
