"""Long harnesses, run by `make test-long` (marked slow; not part of `make test`)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from episode_audit import open_evidence

REPO = Path(__file__).resolve().parents[1]

RECORDER = """
import sys, gymnasium as gym
from episode_audit import RecordEvidence
env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], block_steps=int(sys.argv[2]),
                     flush_every_s=float(sys.argv[3]))
env.reset(seed=0)
env.action_space.seed(0)
n = 0
while True:
    _, _, term, trunc, _ = env.step(env.action_space.sample())
    n += 1
    if term or trunc:
        env.reset()
    if n % 997 == 0:
        env.flush()
        print(n, flush=True)
"""


@pytest.mark.slow
def test_kill_loop_never_loses_flushed_steps(tmp_path: Path) -> None:
    """Kill a recording subprocess at random moments; every file reads, no flushed step is lost."""
    rng = random.Random(1234)
    kills = int(os.environ.get("EPISODE_AUDIT_KILLS", "40"))
    unreadable = missing = 0
    for i in range(kills):
        path = tmp_path / f"kill-{i}.mcap"
        block = rng.choice([64, 256, 4096])
        proc = subprocess.Popen(
            [
                sys.executable,
                "-c",
                RECORDER,
                str(path),
                str(block),
                str(rng.choice([0.01, 0.1, 1.0])),
            ],
            stdout=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        assert proc.stdout is not None
        target = rng.randint(1, 6)
        flushed = 0
        deadline = time.monotonic() + 60
        while target > 0 and time.monotonic() < deadline:
            flushed = int(proc.stdout.readline())
            target -= 1
        time.sleep(rng.random() * 0.05)  # land anywhere: mid-step, mid-flush
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
        try:
            ev = open_evidence(path)
            steps = ev.steps(columns=["episode"]).num_rows
            assert not ev.finished
            ev.episodes()
        except Exception:
            unreadable += 1
            continue
        if steps < flushed:
            missing += 1
    assert (unreadable, missing) == (0, 0)
