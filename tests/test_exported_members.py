"""`episode_audit.__all__` is exactly the public surface, sorted; every export is documented."""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
from importlib.util import find_spec
from pathlib import Path

import pytest

import episode_audit
from tests.support.mypy_run import mypy_output


def test_all_is_sorted_and_complete() -> None:
    names = episode_audit.__all__
    assert list(names) == sorted(names)
    public = {
        name
        for name, value in vars(episode_audit).items()
        if not name.startswith("_") and not inspect.ismodule(value)
    }
    # the PettingZoo recorders are loaded on first access (pettingzoo is optional)
    assert public | {"__version__"} | set(episode_audit._LAZY) == set(names)


def test_dir_lists_every_export_the_lazy_ones_included() -> None:
    assert set(episode_audit.__all__) <= set(dir(episode_audit))
    assert set(episode_audit._LAZY) <= set(dir(episode_audit))
    assert "open_evidence" in dir(episode_audit) and "__version__" in dir(episode_audit)


def test_every_export_is_documented() -> None:
    for name in episode_audit.__all__:
        lazy = episode_audit._LAZY.get(name)
        if lazy is not None and find_spec(episode_audit._EXTRAS[lazy][0]) is None:
            continue  # (its extra is not installed: the test above covers the error)
        value = getattr(episode_audit, name)
        if inspect.isclass(value) or inspect.isfunction(value):
            assert value.__doc__ and value.__doc__.strip(), name


@pytest.mark.parametrize(
    ("name", "package", "extra"),
    [
        ("RecordVecEnvEvidence", "stable_baselines3", "sb3"),
        ("record_evaluation", "stable_baselines3", "sb3"),
        ("RecordAECEvidence", "pettingzoo", "pettingzoo"),
    ],
)
def test_an_optional_recorder_without_its_package_names_the_extra(
    name: str, package: str, extra: str
) -> None:
    """(In a fresh interpreter where the package cannot be imported, as if not installed.)"""
    code = f"import sys; sys.modules[{package!r}] = None; from episode_audit import {name}"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 1
    assert done.stderr.splitlines()[-1] == (
        f"ModuleNotFoundError: episode_audit.{name} needs the {package!r} package; "
        f"install it with pip install 'episode-audit[{extra}]'"
    )


def test_the_lazily_loaded_names_have_their_types_for_mypy(tmp_path: Path) -> None:
    found = mypy_output(
        tmp_path,
        """
        from episode_audit import (
            RecordAECEvidence,
            RecordEvalCallback,
            RecordParallelEvidence,
            RecordVecEnvEvidence,
            record_evaluation,
        )

        reveal_type(RecordVecEnvEvidence)
        reveal_type(RecordEvalCallback)
        reveal_type(RecordAECEvidence)
        reveal_type(RecordParallelEvidence)
        reveal_type(record_evaluation)
        """,
    )
    revealed = re.findall(r'Revealed type is "(.*)"', found)
    assert len(revealed) == 5, found
    for name, shown in zip(
        ["RecordVecEnvEvidence", "RecordEvalCallback", "RecordAECEvidence"], revealed
    ):
        assert shown.startswith("def ") and shown.endswith(f".{name}"), (name, shown)
    assert revealed[3].endswith(".RecordParallelEvidence"), revealed[3]
    assert re.match(r"def \(model: .*\) -> tuple\[", revealed[4]), revealed[4]
