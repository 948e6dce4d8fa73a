"""Recording's cost in instructions and simulated cache misses, under valgrind's cachegrind.

    python bench/instructions.py Reacher-v5 [CartPole-v1 ...]

Counts are what the host's noise does not move, so an A/B of a change to the recorder reads
here in one run when the wall clock (``make bench``) needs many. Each env is stepped through
the same seeded random actions bare and wrapped in ``RecordEvidence`` (time-based flushes off:
under valgrind a second is a few steps; blocks and ``close()`` are counted), for 500 and 2 500
steps, so the per-step figures (the difference over the 2 000 extra steps) leave out start-up.
``est_cycles`` weighs an L1 miss as 10 instructions and a last-level miss as 100. Needs
``valgrind`` (not part of ``make bench``; about 4 minutes per env on 2 cores).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

STEPS = (500, 2500)
_LINE = re.compile(r"==\d+== (I|I1|LLi|D|D1|LLd|LL) +(?:refs|misses): +([\d,]+)")


def child(kind: str, env_id: str, steps: int, out: str) -> None:
    """Step ``env_id`` (bare or recorded) through ``steps`` seeded random actions."""
    import gymnasium as gym

    from episode_audit import RecordEvidence

    space = gym.make(env_id).action_space
    space.seed(0)
    actions = [space.sample() for _ in range(steps)]
    env: Any = gym.make(env_id)
    if kind == "recorded":
        env = RecordEvidence(env, out, overwrite=True, flush_every_s=1e9)
    env.reset(seed=0)
    episode = 0
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            episode += 1
            env.reset(seed=episode)
    env.close()


def counts(kind: str, env_id: str, steps: int, tmp: Path) -> dict[str, int]:
    """cachegrind's totals for one child run."""
    run = subprocess.run(
        [
            "valgrind",
            "--tool=cachegrind",
            "--cache-sim=yes",
            f"--cachegrind-out-file={tmp / f'{kind}-{steps}.cg'}",
            sys.executable,
            __file__,
            "--child",
            kind,
            env_id,
            str(steps),
            str(tmp / f"{kind}-{steps}.mcap"),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    return {m[1]: int(m[2].replace(",", "")) for m in _LINE.finditer(run.stderr)}


def measure(env_id: str) -> dict[str, Any]:
    """Per-step counts of the bare and the recorded loop, and the recorder's share."""
    with tempfile.TemporaryDirectory(prefix="episode-audit-instr-") as d:
        jobs = [(kind, n) for kind in ("bare", "recorded") for n in STEPS]
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            runs = pool.map(lambda j: counts(j[0], env_id, j[1], Path(d)), jobs)
            got = dict(zip(jobs, runs, strict=True))
    lo, hi = STEPS
    per = {
        kind: {k: (got[kind, hi][k] - got[kind, lo][k]) / (hi - lo) for k in got[kind, lo]}
        for kind in ("bare", "recorded")
    }

    def cycles(c: dict[str, float]) -> float:
        return c["I"] + 10 * (c["I1"] + c["D1"]) + 100 * c["LL"]

    bare, rec = per["bare"], per["recorded"]
    return {
        "env": env_id,
        "per_step_bare": {k: round(v) for k, v in bare.items()},
        "per_step_recorder": {k: round(rec[k] - bare[k]) for k in bare},
        "instructions_ratio": rec["I"] / bare["I"],
        "est_cycles_ratio": cycles(rec) / cycles(bare),
    }


def main(argv: list[str]) -> int:
    if argv[:1] == ["--child"]:
        child(argv[1], argv[2], int(argv[3]), argv[4])
        return 0
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (apt install valgrind)", file=sys.stderr)
        return 2
    for env_id in argv or ["Reacher-v5"]:
        print(json.dumps(measure(env_id), indent=2), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
