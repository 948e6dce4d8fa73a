"""--jobs 1 vs --jobs 2: check, report and replay over a campaign of many files.

1 000 CartPole files (one episode each; copies of 50 recorded ones) and one Reacher-v5 file of
50 episodes; ``check`` and ``report`` over the 1 000 files, ``replay`` over all of them. Rounds
alternate the two settings; the speedup is the median of the per-round ratios. The scaling
estimate to N cores is Amdahl's law with the serial fraction the measured 2-core speedup
implies: s = 2 / S2 - 1, S(N) = 1 / (s + (1 - s) / N) (an upper bound: it assumes the
parallel part scales perfectly, and takes no account of other load on the host).
"""

from __future__ import annotations

import os
import shutil
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

from episode_audit import RecordEvidence
from episode_audit.check import check
from episode_audit.replay import replay
from episode_audit.report.inputs import report_inputs

CARTPOLE_FILES = 1000
MUJOCO_EPISODES = 50


def campaign(tmp: Path) -> tuple[list[Path], Path]:
    """The 1 000 CartPole files and the Reacher-v5 file (made once per run)."""
    root = tmp / "jobs"
    files = sorted(root.glob("cartpole-*.mcap"))
    reacher = root / "reacher.mcap"
    if len(files) == CARTPOLE_FILES and reacher.exists():
        return files, reacher
    root.mkdir(parents=True, exist_ok=True)
    recorded = []
    for seed in range(50):
        path = root / f"recorded-{seed:02d}.mcap"
        with RecordEvidence(gym.make("CartPole-v1"), path) as env:
            env.action_space.seed(seed)
            env.reset(seed=seed)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
        recorded.append(path)
    files = []
    for i in range(CARTPOLE_FILES):
        files.append(root / f"cartpole-{i:04d}.mcap")
        shutil.copyfile(recorded[i % len(recorded)], files[-1])
    with RecordEvidence(gym.make("Reacher-v5"), reacher) as env:
        env.action_space.seed(0)
        for e in range(MUJOCO_EPISODES):
            env.reset(seed=e)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
    return files, reacher


def timed(fn: Callable[[], Any]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def compare(run: Callable[[int], Any], rounds: int) -> dict[str, Any]:
    """Alternating rounds of ``run(1)`` and ``run(2)``: seconds and the median speedup."""
    one: list[float] = []
    two: list[float] = []
    for _ in range(rounds):
        one.append(timed(lambda: run(1)))
        two.append(timed(lambda: run(2)))
    speedup = statistics.median(a / b for a, b in zip(one, two, strict=True))
    serial = min(1.0, max(0.0, 2 / speedup - 1))
    return {
        "jobs1_seconds_median": statistics.median(one),
        "jobs2_seconds_median": statistics.median(two),
        "speedup_median": speedup,
        "serial_fraction_amdahl": serial,
        "estimated_speedup": {str(n): 1 / (serial + (1 - serial) / n) for n in (4, 8, 16, 32, 64)},
    }


def bench(tmp: Path, rounds: int = 3) -> dict[str, Any]:
    """The three commands, --jobs 1 vs --jobs 2, with the load average around the run."""
    files, reacher = campaign(tmp)
    load_before = os.getloadavg()
    out: dict[str, Any] = {
        "files": len(files),
        "check": compare(lambda jobs: check(files, jobs=jobs), rounds),
        "report": compare(lambda jobs: report_inputs(files, jobs=jobs), rounds),
        "replay": compare(lambda jobs: replay([*files, reacher], jobs=jobs), rounds),
        "method": "Amdahl: s = 2 / S2 - 1 from the measured 2-core speedup S2; "
        "S(N) = 1 / (s + (1 - s) / N)",
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "target": "replay speedup >= 1.8 with --jobs 2 on 2 cores",
    }
    out["replay"]["meets_target"] = out["replay"]["speedup_median"] >= 1.8
    return out
