"""The docs stay true to the code: README's Python examples run as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


README_PYTHON = re.findall(r"```python\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)


def test_readme_python_examples_are_short() -> None:
    # Gymnasium, path templates, vector env, CleanRL, Stable-Baselines3, PettingZoo
    assert len(README_PYTHON) == 6
    assert all(len(block.strip().splitlines()) <= 17 for block in README_PYTHON)


@pytest.mark.parametrize("block", README_PYTHON, ids=[f"block{i}" for i in range(6)])
def test_readme_python_example_runs(tmp_path: Path, block: str) -> None:
    pytest.importorskip("mujoco")
    for extra in ("stable_baselines3", "pettingzoo"):  # (the sb3 / pettingzoo extras)
        if re.search(rf"^(from|import) {extra}\b", block, flags=re.M):
            pytest.importorskip(extra)
    # (an example's tempfile.mkdtemp() folder, as a user's, is left: in tmp_path, not /tmp)
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    subprocess.run(
        [sys.executable, "-c", block], cwd=tmp_path, env=env, check=True, capture_output=True
    )


def test_readme_quick_start_is_two_commands() -> None:
    text = (REPO / "README.md").read_text()
    quick = text.split("## Quick start", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    commands = [line.split("#")[0].strip() for line in quick.strip().splitlines()]
    assert commands == ["make demo", "make test"]


def test_cli_reference_lists_every_option() -> None:
    from typer.main import get_command

    from episode_audit.cli import app

    doc = (REPO / "docs" / "cli.md").read_text()
    group = get_command(app)
    for name, command in group.commands.items():  # type: ignore[attr-defined]
        assert f"## `episode-audit {name}" in doc, name
        for param in command.params:
            for opt in getattr(param, "opts", []):
                if opt.startswith("--"):
                    assert opt in doc, f"{name} {opt} is not in docs/cli.md"
