"""The replay command a violation prints runs as printed, for a factory in the script run too."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = """\
import gymnasium as gym
from episode_audit.errors import ContractViolation
from episode_audit.testing import ContractCase, check_contract

def make_cartpole():
    return gym.make("CartPole-v1")

if __name__ == "__main__":
    case = ContractCase(make_cartpole, seed=0, actions=[0] * 50, expect="success")
    try:
        check_contract(case, "evidence")
    except ContractViolation as exc:
        print(exc)
"""

CLI = Path(sys.executable).with_name("episode-audit")


def _hint(args: list[str], cwd: Path) -> str:
    """The ``replay it:`` command the script prints, run with ``args`` in ``cwd``."""
    done = subprocess.run(
        [sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    (line,) = [s for s in done.stdout.splitlines() if s.startswith("  replay it: ")]
    return line.removeprefix("  replay it: ")


def _replays(command: str, cwd: Path) -> None:
    """``command`` (as printed) run in ``cwd`` replays the episode identical."""
    match = re.fullmatch(r"episode-audit replay (\S+) --env-factory (\S+)", command)
    assert match, command
    done = subprocess.run(
        [str(CLI), "replay", match[1], "--env-factory", match[2]],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "1 identical" in done.stdout, done.stdout


def test_a_script_in_the_current_folder_is_named_by_its_module(tmp_path: Path) -> None:
    (tmp_path / "contract_script.py").write_text(SCRIPT)
    command = _hint(["contract_script.py"], tmp_path)
    assert command.endswith(" --env-factory contract_script:make_cartpole"), command
    _replays(command, tmp_path)


def test_a_module_run_with_python_m_is_named_by_its_name(tmp_path: Path) -> None:
    (tmp_path / "envpkg").mkdir()
    (tmp_path / "envpkg" / "__init__.py").write_text("")
    (tmp_path / "envpkg" / "contract_mod.py").write_text(SCRIPT)
    command = _hint(["-m", "envpkg.contract_mod"], tmp_path)
    assert command.endswith(" --env-factory envpkg.contract_mod:make_cartpole"), command
    _replays(command, tmp_path)


@pytest.mark.parametrize("where", ["another folder", "shadowed", "-c"])
def test_a_script_the_cli_cannot_import_gets_the_placeholder_and_what_to_do(
    tmp_path: Path, where: str
) -> None:
    """Run from another folder; named as an installed module (``this``); ``python -c``."""
    (tmp_path / "elsewhere").mkdir()
    if where == "another folder":
        (tmp_path / "contract_script.py").write_text(SCRIPT)
        command = _hint(["../contract_script.py"], tmp_path / "elsewhere")
    elif where == "shadowed":
        (tmp_path / "this.py").write_text(SCRIPT)
        command = _hint(["this.py"], tmp_path)
    else:
        command = _hint(["-c", SCRIPT], tmp_path)
    assert re.fullmatch(
        r"episode-audit replay \S+ --env-factory MODULE:CALLABLE \(make_cartpole is defined "
        r"in the script being run, which the CLI cannot import: put it in an importable "
        r"module\)",
        command,
    ), command
