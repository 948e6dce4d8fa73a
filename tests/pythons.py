"""The test suite on other CPythons (``make test-pythons``; ``make test`` runs it on ``.venv``'s).

For each interpreter given (default: every CPython 3.10 or newer that pyenv has, other than
``.venv``'s), build ``.venv-X.Y`` with the ``dev`` extra's packages but Stable-Baselines3 and
torch (only the machine's own Python has a CPU torch wheel on disk; elsewhere pip would fetch
gigabytes of CUDA wheels), build the compiled step, and run ``pytest -m "not slow"``; the SB3
tests skip there, and their doctests are not collected (``conftest.py``). When the oldest one
given is the oldest ``requires-python`` allows, it gets numpy 1 and pyproject's floors
(:data:`OLDEST`), and the next one Gymnasium 1.2 (:data:`BETWEEN`); otherwise each gets the
newest releases. With no interpreter given, ``.venv-sb3`` on ``.venv``'s own Python tests the
oldest Stable-Baselines3 the ``sb3`` extra allows (:data:`SB3_FLOORS`). Prints one line per
run; exits 1 when any suite fails or cannot be installed. ``tests/sid.sh`` runs this on Debian
sid's Python 3.14, for a machine whose pyenv has none.

    python tests/pythons.py [PYTHON ...]
"""

from __future__ import annotations

import functools
import glob
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
LEFT_OUT = ("stable-baselines3", "torch")
"""The ``dev`` extra's packages not installed on other Pythons (SB3 needs torch)."""
OLDEST = [
    "numpy==1.24.*",
    "pyarrow==25.*",
    "gymnasium[mujoco]==1.1.*",
    "mujoco==3.3.5",
    "mcap==1.5.*",
    "scipy==1.15.*",
    "pettingzoo==1.27.*",
    "typer==0.17.*",
    "rich==14.3.*",
    "zstandard==0.21.*",
    "zlib-ng==0.4.*",
    "typing_extensions==4.6.*",
    "s3fs==2024.3.*",
    "matplotlib==3.8.*",
    "pyparsing<3.2",
    "pillow==10.*",
]
"""On the oldest Python: pyproject's floors (numpy 1; pyarrow 26 needs numpy 2 and does not say
so: pip would pair them, and ``import pyarrow`` fails). pyarrow 21-24 made a process that forked
(``AsyncVectorEnv``) and then read evidence abort at exit now and then ("terminate called
without an active exception", in a garbage collection): ~8 % of runs of the README's
``AsyncVectorEnv`` block on Python 3.10, 1 in 260 with pyarrow 25, none seen with 26.
pyparsing 3.2 deprecates names matplotlib 3.8 uses, and the suite makes warnings errors."""
BETWEEN = ["gymnasium[mujoco]==1.2.*"]
"""On the second-oldest Python: the Gymnasium between the floor and the newest (Stable-Baselines3
2.7 and 2.8 cap it below 1.3)."""
SB3_FLOORS = ["stable-baselines3==2.6.*", "gymnasium[mujoco]==1.1.*"]
"""On ``.venv``'s own Python, SB3 and torch included: the oldest Stable-Baselines3 the ``sb3``
extra allows, with the newest Gymnasium it takes (``.venv-sb3``)."""


@functools.cache
def project() -> dict[str, Any]:
    """``pyproject.toml``'s ``[project]`` table."""
    try:
        import tomllib
    except ImportError:  # Python 3.10 (.venv made by a python3 3.10): pip's own copy of tomli
        from pip._vendor import tomli as tomllib

    table: dict[str, Any] = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    return table


def requirements(sb3: bool = False) -> list[str]:
    """The package's dependencies and its ``dev`` extra's, but :data:`LEFT_OUT` (unless ``sb3``)."""
    wanted = [*project()["dependencies"], *project()["optional-dependencies"]["dev"]]
    return [r for r in wanted if sb3 or not r.startswith(LEFT_OUT)]


def floor_python() -> str:
    """The oldest Python ``pyproject.toml`` allows (``requires-python``): ``"3.10"``."""
    return str(project()["requires-python"]).removeprefix(">=")


def version_of(python: str) -> str:
    """``"3.12"`` for a Python 3.12 interpreter."""
    code = "import sys; print('%d.%d' % sys.version_info[:2])"
    return subprocess.run(
        [python, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()


def pythons() -> list[str]:
    """pyenv's CPythons 3.10 and newer, but the one ``.venv`` runs."""
    own = f"{sys.version_info.major}.{sys.version_info.minor}"
    found = sorted(glob.glob(os.path.expanduser("~/.pyenv/versions/3.*/bin/python3")))
    chosen: dict[str, str] = {}
    for python in found:
        version = version_of(python)
        if tuple(map(int, version.split("."))) >= (3, 10) and version != own:
            chosen[version] = python  # (the newest patch release of each)
    return list(chosen.values())


def run(python: str, name: str, extra: list[str], sb3: bool = False) -> tuple[int, str]:
    """Install in ``.venv-NAME`` (with the ``extra`` requirements) and test on ``python``.

    ``sb3``: with Stable-Baselines3 and torch (pip installs torch first, by pyproject's pin, so
    that a wheel already on the machine is taken: uv reads no pip.conf). Returns the exit
    status and the last line of pytest.
    """
    venv = REPO / f".venv-{name}"
    bin_ = venv / "bin"
    env = {**os.environ, "EPISODE_AUDIT_REQUIRE_EXTENSION": "1"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    wanted = requirements(sb3)
    torch = [r for r in wanted if r.startswith("torch")]
    steps = [
        [python, "-m", "venv", str(venv)],
        [str(bin_ / "python"), "-m", "pip", "install", "--quiet", "uv", *torch],
        [str(bin_ / "python"), "-m", "uv", "pip", "install", "--quiet", "--python",
         str(bin_ / "python"), *wanted, *extra, "-e", "."],
    ]  # fmt: skip
    for step in steps:
        done = subprocess.run(step, cwd=REPO, env=env, capture_output=True, text=True)
        if done.returncode:
            why = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
            return 1, f"install failed: {why}"
    test = [str(bin_ / "python"), "-m", "pytest", "-q", "-m", "not slow", "-n", "2"]
    done = subprocess.run(
        [*test, "--dist", "loadfile"], cwd=REPO, env=env, capture_output=True, text=True
    )
    lines = done.stdout.strip().splitlines() or ["(no output)"]
    if done.returncode:
        (venv / "pytest.log").write_text(done.stdout + done.stderr)
    return done.returncode, lines[-1].strip("= ")


def main(argv: list[str]) -> int:
    chosen = argv or pythons()
    if not chosen:
        print("no other CPython >= 3.10 found (pass interpreters as arguments)")
        return 1
    versions = {python: version_of(python) for python in chosen}
    ordered = sorted(chosen, key=lambda python: tuple(map(int, versions[python].split("."))))
    floors = versions[ordered[0]] == floor_python()
    extras = dict(zip(ordered, [OLDEST, BETWEEN])) if floors else {}
    legs = [(python, versions[python], extras.get(python, []), False) for python in chosen]
    if not argv:
        own = f"{sys.version_info.major}.{sys.version_info.minor}"
        legs.append((sys._base_executable, own, SB3_FLOORS, True))
    failed = 0
    for python, version, extra, sb3 in legs:
        start = time.monotonic()
        name = "sb3" if sb3 else version
        code, last = run(python, name, extra, sb3)
        label = f"Python {version}{' with SB3' if sb3 else ''}"
        label += f" ({', '.join(extra)})" if extra else ""
        failed += code != 0
        took = time.monotonic() - start
        print(f"{label}: {'ok' if code == 0 else 'FAILED'} in {took:.0f} s: {last}")
        if code:
            print(f"  (the whole output: .venv-{name}/pytest.log)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
