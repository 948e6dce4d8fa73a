"""The API's path, name and episode arguments (read/arguments.py), and the functions taking paths.

A bare ``str`` or path is one path everywhere a list of paths is taken, never its characters.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from episode_audit import (
    ConfigurationError,
    check,
    compare,
    export,
    open_evidence,
    recover,
    replay,
    report,
)
from episode_audit.read import evidence_files
from episode_audit.read.arguments import episode_index, name_list, path_list
from tests.read.helpers import record_cartpole


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    record_cartpole(out / "a.mcap", episodes=2)
    record_cartpole(out / "b.mcap", episodes=2)
    return out


@pytest.mark.parametrize("kind", [str, Path])
def test_one_path_is_one_file_everywhere_paths_are_taken(
    runs: Path, kind: type, tmp_path: Path
) -> None:
    a, b = kind(runs / "a.mcap"), kind(runs / "b.mcap")
    assert path_list(a) == [a]
    assert check(a).files == [str(runs / "a.mcap")]
    assert [g.key for g in report(a).groups] == [str(runs / "a.mcap")]
    assert {e.file for e in replay(a).episodes} == {str(runs / "a.mcap")}
    assert compare(a, b).baseline_files == 1
    assert len(export(a, tmp_path / "out").steps_files) == 1
    assert evidence_files(kind(runs)) == [runs / "a.mcap", runs / "b.mcap"]


def test_a_path_list_refuses_what_is_no_path() -> None:
    with pytest.raises(
        ConfigurationError, match=r"^paths: expected a path or a list of paths, got int"
    ):
        path_list(3)  # type: ignore[call-overload]
    with pytest.raises(ConfigurationError, match=r"^paths: expected a path, got an empty string"):
        path_list("")  # (it was the current folder: check("") said '.: a directory')


def test_an_empty_path_says_what_to_pass() -> None:
    with pytest.raises(
        ConfigurationError,
        match=r"^paths: expected a path, got an empty string; pass a file's path, "
        r"e\.g\. 'runs/run\.mcap'$",
    ):
        check("")


_NO_PATH = r": expected a path \(a str or pathlib\.Path\), got "
_PASS = r"; pass a file's path, e\.g\. 'runs/run\.mcap'$"


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda a: check([b"a.mcap"]), r"^paths\[0\]" + _NO_PATH + r"b'a\.mcap' \(bytes\)" + _PASS),
        (lambda a: check([a, None]), r"^paths\[1\]" + _NO_PATH + r"None \(NoneType\)" + _PASS),
        (lambda a: replay([3]), r"^paths\[0\]" + _NO_PATH + r"3 \(int\)" + _PASS),
        (lambda a: report([None]), r"^paths\[0\]" + _NO_PATH + r"None \(NoneType\)" + _PASS),
        (lambda a: compare([a], [3]), r"^candidate\[0\]" + _NO_PATH + r"3 \(int\)" + _PASS),
        (
            lambda a: compare([""], [a]),
            r"^baseline\[0\]: expected a path, got an empty string" + _PASS,
        ),
        (lambda a: export([a], b"out"), r"^out" + _NO_PATH + r"b'out' \(bytes\)" + _PASS),
        (lambda a: open_evidence(b"a.mcap"), r"^path" + _NO_PATH + r"b'a\.mcap' \(bytes\)" + _PASS),
        (lambda a: open_evidence(None), r"^path" + _NO_PATH + r"None \(NoneType\)" + _PASS),
        (lambda a: open_evidence(""), r"^path: expected a path, got an empty string" + _PASS),
        (lambda a: recover(None, "x.mcap"), r"^path" + _NO_PATH + r"None \(NoneType\)" + _PASS),
        (
            lambda a: recover([a], "x.mcap"),
            r"^path" + _NO_PATH + r"\['.*a\.mcap'\] \(list\)" + _PASS,
        ),
        (lambda a: recover("", "x.mcap"), r"^path: expected a path, got an empty string" + _PASS),
        (lambda a: recover(a, b"x.mcap"), r"^out" + _NO_PATH + r"b'x\.mcap' \(bytes\)" + _PASS),
    ],
)
def test_a_path_of_the_wrong_type_is_a_configuration_error(
    runs: Path, call: Any, message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """(Not Python's TypeError from deep inside, nor "" taken as the current folder.)"""
    monkeypatch.chdir(tmp_path)  # (nothing is written: an output would land here)
    with pytest.raises(ConfigurationError, match=message):
        call(str(runs / "a.mcap"))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("names", "message"),
    [
        (
            "reward",
            r"^terms: expected a list of names, got the string 'reward'; pass \['reward'\]$",
        ),
        (3, r"^terms: expected a list of names, got int; pass e\.g\. \['reward'\]$"),
        (["a", None], r"^terms\[1\]: expected a name \(a str\), got None \(NoneType\)$"),
    ],
)
def test_a_name_list_refuses_a_bare_string(names: object, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        name_list("terms", names)  # type: ignore[arg-type]


def test_an_episode_index_out_of_range_is_said_as_the_command_line_does() -> None:
    with pytest.raises(
        ConfigurationError,
        match=r"^--episode: expected an episode index from 0 to 2\*\*63 - 1, got -1$",
    ):
        episode_index("--episode", -1)
