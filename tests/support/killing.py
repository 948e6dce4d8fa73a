"""Children killed midway: a Python job in a child process, SIGKILLed at a random moment."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def started(code: str, *args: str) -> subprocess.Popen[str]:
    """``python -c code args…`` in a child, once it printed ``go`` (about to do its work)."""
    child = subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert child.stdout is not None and child.stdout.readline() == "go\n"
    return child


def how_long(code: str, *args: str) -> float:
    """The seconds ``code`` took to do its work whole (it prints them after its ``go``)."""
    child = started(code, *args)
    assert child.stdout is not None
    took = float(child.stdout.readline())
    child.stdout.close()
    assert child.wait() == 0
    return took


def killed_midway(code: str, runs: Sequence[Sequence[str]], within_s: float) -> int:
    """Start ``code`` with each of ``runs``' arguments and SIGKILL it after a random time below
    ``within_s`` seconds (seeded: the same times each run; give about half the time the work
    takes whole, so that a host slower for the timed run than for these still kills them
    midway); how many the kill ended."""
    rng = random.Random(0)
    killed = 0
    for args in runs:
        child = started(code, *args)
        time.sleep(rng.uniform(0, within_s))
        child.send_signal(signal.SIGKILL)
        killed += child.wait() == -signal.SIGKILL
        child.stdout.close()  # type: ignore[union-attr]
    return killed
