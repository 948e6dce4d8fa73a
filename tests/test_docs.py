"""The docs stay true to the code: README's Python examples and docs/viewers.md's commands run
as written."""

from __future__ import annotations

import importlib.util
import inspect
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
    done = subprocess.run(
        [sys.executable, "-c", block], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, f"exit {done.returncode}:\n{done.stderr[-4000:]}"


VIEWERS_BASH = re.findall(
    r"```bash\n(.*?)```", (REPO / "docs" / "viewers.md").read_text(), flags=re.S
)


def test_viewers_commands_run(tmp_path: Path) -> None:
    """docs/viewers.md's commands run as written, in order, beside a ``run.mcap`` and README's
    ``vec.mcap``: its layout command named a ``viewers/vec.foxglove.mcap`` no command made.
    (``pip install`` is left out, and so is ``rerun FILE``, which opens the viewer.)"""
    import gymnasium as gym

    from episode_audit import RecordEvidence, RecordVectorEvidence

    pytest.importorskip("foxglove")
    has_rerun = importlib.util.find_spec("rerun") is not None
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "run.mcap") as env:
        env.reset(seed=0)
        for _ in range(30):
            if any(env.step(env.action_space.sample())[2:4]):
                env.reset()
    vec = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with RecordVectorEvidence(vec, tmp_path / "vec.mcap") as envs:
        envs.reset(seed=0)
        for _ in range(30):
            envs.step(envs.action_space.sample())
    lines = [line.split("  #")[0].strip() for block in VIEWERS_BASH for line in block.splitlines()]
    commands = [c for c in lines if c and not c.startswith(("pip ", "rerun "))]
    assert len(commands) >= 4, commands  # (export, export, layout, layout)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    for command in commands:
        if "rerun" in command and not has_rerun:
            continue  # (rerun-sdk: Python >= 3.11, and the rerun extra)
        done = subprocess.run(
            command, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, f"{command}: exit {done.returncode}:\n{done.stderr}"
    assert (tmp_path / "env_1.layout.json").read_text().count('"/env_1/steps.reward"') >= 1


_ONLY_THESE = """
import importlib.machinery, sys
class _Installed(importlib.machinery.PathFinder):
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            return None
        return super().find_spec(name, path, target)
sys.meta_path[:] = [
    _Installed if f is importlib.machinery.PathFinder else f for f in sys.meta_path
]
"""
"""Code run before an example: the modules of ``BLOCKED`` behave as if not installed."""


def _installed_with(extra: str) -> set[str]:
    """The distributions ``pip install 'episode-audit[EXTRA]'`` installs (canonical names):
    the package's dependencies and the extra's, and theirs (those installed here)."""
    from importlib import metadata

    tomllib = pytest.importorskip("tomllib")  # (Python >= 3.11)
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    todo = [(r, "") for r in project["dependencies"] + project["optional-dependencies"][extra]]
    seen = {"episode-audit"}
    while todo:
        text, parent_extra = todo.pop()
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate({"extra": parent_extra}):
            continue
        name = canonicalize_name(req.name)
        try:
            dist = metadata.distribution(req.name)
        except metadata.PackageNotFoundError:
            continue
        if name in seen and not req.extras:
            continue
        seen.add(name)
        todo += [(r, e) for r in dist.requires or [] for e in ("", *req.extras)]
    return seen


@pytest.mark.parametrize(
    ("extra", "package"), [("pettingzoo", "pettingzoo"), ("sb3", "stable_baselines3")]
)
def test_readme_example_of_an_extra_runs_with_only_what_the_extra_installs(
    tmp_path: Path, extra: str, package: str
) -> None:
    """README's PettingZoo example (tictactoe_v3) needs pygame, which the ``pettingzoo`` extra
    did not install: it failed after ``pip install 'episode-audit[pettingzoo]'``."""
    from importlib import metadata

    from packaging.utils import canonicalize_name

    pytest.importorskip(package)
    (block,) = [b for b in README_PYTHON if re.search(rf"^from {package}\b", b, flags=re.M)]
    text = (REPO / "README.md").read_text()
    assert f"pip install 'episode-audit[{extra}]'" in text  # (the README names the extra)
    allowed = _installed_with(extra)
    blocked = {
        module
        for module, dists in metadata.packages_distributions().items()
        if not any(canonicalize_name(d) in allowed for d in dists)
    }
    prelude = f"BLOCKED = {sorted(blocked)!r}\n{_ONLY_THESE}"
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, "-c", prelude + block], cwd=tmp_path, env=env, capture_output=True
    )
    assert done.returncode == 0, done.stderr.decode()[-2000:]


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


def test_recording_lists_every_recorder_option() -> None:
    """docs/recording.md's list of the recorders' keyword options is `RecorderOptions`' fields,
    in their order, as is the `RecorderSettings` docstring it points to."""
    from episode_audit.record.settings import RecorderOptions, RecorderSettings

    declared = list(RecorderOptions.__annotations__)
    doc = (REPO / "docs" / "recording.md").read_text()
    listed = re.search(r"All four take the same keyword options \((.*?)\), declared", doc, re.S)
    assert listed is not None, "docs/recording.md lost its sentence listing the options"
    assert re.findall(r"`(\w+)`", listed[1]) == declared
    # (cleandoc: Python 3.13 strips docstrings' indentation itself, earlier ones do not)
    doc = inspect.cleandoc(RecorderSettings.__doc__ or "")
    args = doc.split("Args:", 1)[1].split("Raises:", 1)[0]
    assert re.findall(r"^    (\w+):", args, flags=re.M) == declared
