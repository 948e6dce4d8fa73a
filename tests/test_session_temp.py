"""The test session's temporary directory (conftest.py): what a session leaves there fails it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

_TESTS = """
import os, tempfile
from pathlib import Path

def test_leaves_a_folder():
    tempfile.mkdtemp(prefix="leaked-")

def test_ray_keeps_its_sessions():
    Path(tempfile.gettempdir(), "ray").mkdir()

def test_cleans_up():
    with tempfile.TemporaryDirectory(prefix="cleaned-"):
        pass

def test_a_child_process_shares_it():
    assert os.environ["TMPDIR"] == tempfile.gettempdir()
    assert Path(os.environ["TMPDIR"]).name == "tmp"
"""


def test_a_folder_left_in_the_temporary_directory_fails_the_session_named(
    pytester: pytest.Pytester,
) -> None:
    pytester.makeconftest((REPO / "conftest.py").read_text())
    pytester.makepyfile(test_leaky=_TESTS)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=4)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines(
        [
            "*= temporary files left behind =*",
            "*/tmp: left by the session's processes (1):",
            "  leaked-*",
        ]
    )


def test_a_session_that_leaves_nothing_passes(pytester: pytest.Pytester) -> None:
    pytester.makeconftest((REPO / "conftest.py").read_text())
    pytester.makepyfile(test_tidy=_TESTS.replace('tempfile.mkdtemp(prefix="leaked-")', "pass"))
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=4)
    assert result.ret == pytest.ExitCode.OK
    assert "left behind" not in result.stdout.str()


def test_this_session_has_its_own_temporary_directory() -> None:
    assert tempfile.gettempdir() == os.environ["TMPDIR"]
    assert Path(os.environ["TMPDIR"]).parent.name.startswith("pytest-")
    assert Path(os.environ["SB3_LOGDIR"]).parent == Path(os.environ["TMPDIR"]).parent
