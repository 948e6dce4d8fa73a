"""Collection, and the session's own temporary directory.

``--doctest-modules`` imports every module of ``episode_audit``; those of the SB3 and PettingZoo
recorders import their library at the top, so without it (a Python the ``dev`` extra's torch
has no wheel for, say) they are not collected, and their tests skip.

The session's temporary directory (``$TMPDIR``, for this process, pytest-xdist's workers and
every process they start) is a folder of pytest's basetemp: what the tests, the library and
third-party code (Stable-Baselines3's logger, Chromium, Ray, multiprocessing) put there does not
pile up in ``/tmp``, and what is left in it at the end of the session fails the run, named.
"""

from __future__ import annotations

import os
import re
import signal
import tempfile
from collections.abc import Generator, Iterator
from importlib.util import find_spec
from pathlib import Path

import pytest

import episode_audit

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    # started in the background (`make test &`: a shell ignores Ctrl-C there, and Python then
    # leaves it ignored): the Ctrl-C tests need it raised as KeyboardInterrupt, as at a terminal
    signal.signal(signal.SIGINT, signal.default_int_handler)

_PACKAGE = Path(episode_audit.__file__).resolve().parent
_NEEDS = {
    _PACKAGE.joinpath(*module.split(".")): package
    for module, (package, _) in episode_audit._EXTRAS.items()
}
"""A recorder's folder: the library it needs (the package's own map of its optional recorders)."""

_TEMP = pytest.StashKey[Path]()
_KEPT = re.compile(r"pytest-of-.*|ray|torchinductor_.*")
"""What others keep in the temporary directory on purpose, by name, not checked: a
pytest run inside a test (pytester) makes its basetemp here; Ray keeps each session's logs and
sockets in ``ray/``; torch's compile cache (``torchinductor_<user>``). pytest removes old
basetemps, these with them."""

_ALIVE = re.compile(r"pymp-.*")
"""What this process removes as it exits (its fork server's folder): left out of the check
when the tests ran in this process."""


def pytest_ignore_collect(collection_path: Path) -> bool | None:
    """Skip the folder of a recorder whose optional library is not installed."""
    package = _NEEDS.get(collection_path)
    return True if package is not None and find_spec(package) is None else None


@pytest.hookimpl(trylast=True)
def pytest_configure(config: pytest.Config) -> None:
    """Make the session's temporary directory, ``<basetemp>/tmp``, everyone's ``$TMPDIR``.

    The controller does it (pytest-xdist's workers start after this, with its environment).
    Stable-Baselines3's logger makes a folder at each ``learn()`` none is configured for:
    ``$SB3_LOGDIR`` is one folder beside it. The path stays short: Ray's and multiprocessing's
    sockets live under it (an AF_UNIX path holds 107 bytes).
    """
    factory = getattr(config, "_tmp_path_factory", None)
    if hasattr(config, "workerinput") or factory is None:
        return
    basetemp = factory.getbasetemp()
    temp = basetemp / "tmp"
    temp.mkdir()
    config.stash[_TEMP] = temp
    os.environ["TMPDIR"] = str(temp)
    os.environ["SB3_LOGDIR"] = str(basetemp / "sb3-logs")
    tempfile.tempdir = None  # (computed again from $TMPDIR)


@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_sessionfinish(session: pytest.Session) -> Generator[None, None, None]:
    """Fail the run if the temporary directory holds anything but what others keep (:data:`_KEPT`).

    Checked after pytest-xdist's workers have exited (their ``atexit`` handlers run), before
    the summary.
    """
    yield
    temp = session.config.stash.get(_TEMP, None)
    if temp is None:
        return
    # In a run without pytest-xdist's workers, this process is still up: multiprocessing's
    # folder of its fork server (jobs > 1) is removed when it exits, after this check.
    alive = _ALIVE if not getattr(session.config.option, "numprocesses", None) else None
    left = sorted(
        p.name
        for p in temp.iterdir()
        if not _KEPT.fullmatch(p.name) and not (alive and alive.fullmatch(p.name))
    )
    if not left:
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write("\n")
        reporter.section("temporary files left behind", red=True)
        reporter.line(f"{temp}: left by the session's processes ({len(left)}):")
        for name in left[:20]:
            reporter.line(f"  {name}", red=True)
        if len(left) > 20:
            reporter.line(f"  ... and {len(left) - 20} more")
        reporter.line("clean up what a test or the library creates (see conftest.py)")
    if session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture(autouse=True)
def _doctest_temp(request: pytest.FixtureRequest) -> Iterator[None]:
    """A doctest's ``tempfile.mkdtemp()`` (its example's folder) is made in its ``tmp_path``.

    Examples make their folder as a user would, and leave it; pytest removes ``tmp_path``.
    """
    if not isinstance(request.node, pytest.DoctestItem):
        yield
        return
    before = tempfile.tempdir
    tempfile.tempdir = str(request.getfixturevalue("tmp_path"))
    try:
        yield
    finally:
        tempfile.tempdir = before
