"""--jobs 1 vs --jobs 2: check, report and replay over a campaign of many files.

1 000 CartPole files (one episode each, each its own run) and one Reacher-v5 file of
50 episodes; ``check`` and ``report`` over the 1 000 files, ``replay`` over all of them. Each is
timed two ways, in alternating rounds: as library calls in this process (``jobs=1`` / ``2``;
the workers' fork server, started by the first call, stays up for the next ones, as in any
long-lived process) and as the command line, a fresh ``python -m episode_audit`` each time
(interpreter, imports and fork server included). A speedup is the median of the per-round
ratios. The CPU seconds of the whole process tree are taken too: the host's other load moves
them less than the wall-clock time (though contention adds to them), and
``2 * cpu(jobs=1) / cpu(jobs=2)`` is the speedup two idle cores give when the work divides
evenly. The scaling
estimate to N cores is Amdahl's law with the serial fraction the measured 2-core speedup
implies: s = 2 / S2 - 1, S(N) = 1 / (s + (1 - s) / N) (an upper bound: it assumes the parallel
part scales perfectly, and takes no account of other load on the host).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import threading
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
ROOT = Path(__file__).resolve().parents[1]


def _record(env: Any, episodes: int, seed: int) -> None:
    env.action_space.seed(seed)
    for e in range(episodes):
        env.reset(seed=seed + e)
        done = False
        while not done:
            *_, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated


def campaign(tmp: Path) -> tuple[list[Path], Path]:
    """The 1 000 CartPole files (in ``cartpole/``) and the Reacher-v5 file (made once a run)."""
    root = tmp / "jobs"
    files = sorted((root / "cartpole").glob("*.mcap"))
    reacher = root / "reacher" / "reacher.mcap"
    if len(files) == CARTPOLE_FILES and reacher.exists():
        return files, reacher
    for sub in ("cartpole", "reacher"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    files = []
    for i in range(CARTPOLE_FILES):  # (each its own run: report refuses copies of one run)
        files.append(root / "cartpole" / f"cartpole-{i:04d}.mcap")
        with RecordEvidence(gym.make("CartPole-v1"), files[-1], overwrite=True) as env:
            _record(env, 1, i % 50)
    with RecordEvidence(gym.make("Reacher-v5"), reacher, overwrite=True) as env:
        _record(env, MUJOCO_EPISODES, 0)
    return files, reacher


def _descendants(pid: int) -> list[int]:
    out: list[int] = []
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for child in map(int, children):
        out += [child, *_descendants(child)]
    return out


def _ticks(pid: int) -> int:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0
    return int(fields[11]) + int(fields[12])  # utime + stime


class TreeCPU:
    """CPU seconds of this process and its descendants over a ``with`` block (Linux).

    The descendants (the fork server, its workers) are sampled from /proc every 20 ms, so a
    worker's last 20 ms may be missed. The host's other load changes these seconds less than a
    wall-clock time, so ``2 * cpu(jobs=1) / cpu(jobs=2)`` estimates the speedup two idle cores
    would give if the work divides evenly, as the scheduling makes it.
    """

    def __enter__(self) -> TreeCPU:
        self._stop = threading.Event()
        self._start = {pid: _ticks(pid) for pid in _descendants(os.getpid())}
        self._seen: dict[int, int] = {}
        self._own = time.process_time()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(0.02):
            for pid in _descendants(os.getpid()):
                self._seen[pid] = max(self._seen.get(pid, 0), _ticks(pid))

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        own = time.process_time() - self._own
        ticks = sum(t - self._start.get(pid, 0) for pid, t in self._seen.items())
        self.seconds = own + ticks / os.sysconf("SC_CLK_TCK")


def timed(fn: Callable[[], Any]) -> tuple[float, float]:
    """Wall-clock seconds of ``fn()``, and the CPU seconds of this process tree."""
    with TreeCPU() as cpu:
        t0 = time.perf_counter()
        fn()
        wall = time.perf_counter() - t0
    return wall, cpu.seconds


def cli(*args: str) -> Callable[[int], Any]:
    """``episode-audit ARGS --jobs N`` in a fresh interpreter, its output discarded."""

    def run(jobs: int) -> None:
        cmd = [sys.executable, "-m", "episode_audit", *args, "-f", "json", "--jobs", str(jobs)]
        # as installed packages start: their modules compiled once and cached, not compiled
        # again in every process (as PYTHONDONTWRITEBYTECODE would have it: docs/cli.md)
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, check=True, cwd=ROOT)

    return run


def compare(run: Callable[[int], Any], rounds: int) -> dict[str, Any]:
    """Alternating rounds of ``run(1)`` and ``run(2)``: seconds and the median speedup."""
    one: list[float] = []
    two: list[float] = []
    cpu_one: list[float] = []
    cpu_two: list[float] = []
    for _ in range(rounds):
        for times, cpus, jobs in ((one, cpu_one, 1), (two, cpu_two, 2)):
            wall, cpu = timed(lambda: run(jobs))  # noqa: B023 - called at once
            times.append(wall)
            cpus.append(cpu)
    speedup = statistics.median(a / b for a, b in zip(one, two, strict=True))
    serial = min(1.0, max(0.0, 2 / speedup - 1))
    return {
        "jobs1_seconds_median": round(statistics.median(one), 3),
        "jobs2_seconds_median": round(statistics.median(two), 3),
        "speedup_median": round(speedup, 3),
        "speedups": [round(a / b, 3) for a, b in zip(one, two, strict=True)],
        "jobs1_cpu_seconds_median": round(statistics.median(cpu_one), 3),
        "jobs2_cpu_seconds_median": round(statistics.median(cpu_two), 3),
        "even_split_speedup_from_cpu": round(
            statistics.median(2 * a / b for a, b in zip(cpu_one, cpu_two, strict=True)), 3
        ),
        "serial_fraction_amdahl": round(serial, 3),
        "estimated_speedup": {
            str(n): round(1 / (serial + (1 - serial) / n), 2) for n in (4, 8, 16, 32, 64)
        },
    }


def bench(tmp: Path, rounds: int = 3) -> dict[str, Any]:
    """The three commands, --jobs 1 vs --jobs 2, with the load average around the run."""
    files, reacher = campaign(tmp)
    cartpole = str(files[0].parent)
    load_before = os.getloadavg()
    print(f"load average before: {load_before}", flush=True)
    out: dict[str, Any] = {
        "files": len(files),
        "library": {
            "check": compare(lambda jobs: check(files, jobs=jobs), rounds),
            "report": compare(lambda jobs: report_inputs(files, jobs=jobs), rounds),
            "replay": compare(lambda jobs: replay([*files, reacher], jobs=jobs), rounds),
        },
        "cli": {
            "check": compare(cli("check", cartpole), rounds),
            "report": compare(cli("report", cartpole), rounds),
            "replay": compare(cli("replay", cartpole, str(reacher)), rounds),
        },
        "method": "Amdahl: s = 2 / S2 - 1 from the measured 2-core speedup S2; "
        "S(N) = 1 / (s + (1 - s) / N)",
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "target": "replay speedup >= 1.8 with --jobs 2 on 2 cores",
    }
    print(f"load average after: {out['loadavg_after']}", flush=True)
    for way in ("library", "cli"):
        out[way]["replay"]["meets_target"] = out[way]["replay"]["speedup_median"] >= 1.8
    return out
