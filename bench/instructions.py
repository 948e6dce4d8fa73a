"""Recording's (or replay's) cost in instructions and cache misses, under valgrind's cachegrind.

    python bench/instructions.py Reacher-v5 [CartPole-v1 ...]

Counts are what the host's noise does not move, so an A/B of a change to the recorder reads
here in one run when the wall clock (``make bench``) needs many. Each env is stepped through
the same seeded random actions bare and wrapped in ``RecordEvidence`` (time-based flushes off:
under valgrind a second is a few steps; blocks and ``close()`` are counted), for 500 and 2 500
steps, so the per-step figures (the difference over the 2 000 extra steps) leave out start-up.
``est_cycles`` weighs an L1 miss as 10 instructions and a last-level miss as 100. The children
run under callgrind with a count per thread: ``main_thread`` is the recorder's share of the
loop's own thread, the rest is its writer thread's (compressing and writing chunks, beside the
loop). Needs ``valgrind`` (not part of ``make bench``; about 5 minutes per env on 2 cores).

    python bench/instructions.py --vector CartPole-v1 [N=8]

counts the same for a ``SyncVectorEnv`` of N sub-envs (``gym.make_vec``, seeded random action
batches, Gymnasium's autoreset) bare and wrapped in ``RecordVectorEvidence`` (time-based
flushes off), for 500 and 2 500 vector steps; per-step figures are per sub-env step.

    python bench/instructions.py --replay CartPole-v1 [Reacher-v5 ...]

counts replay instead: the episodes ``make bench`` replays (same counts, seeds and actions)
are recorded once outside valgrind, with a 2-episode file; then three children count (1) the
set-up alone (imports, the file's actions, a warm-up step of the env and a replay of the small
file, so first-call costs are outside what is compared, as in the bench's later rounds), (2) the
set-up and the bare loop (``gym.make`` and the same resets and actions), (3) the set-up and
``replay()`` of the file (opening, reading, building the env, stepping, comparing).
``instructions_ratio`` is (3 - 1) / (2 - 1): what ``make bench`` times as ``ratio_median``,
without the host's noise; ``est_cycles_ratio`` weighs in the simulated cache misses.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Mapping
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
    _steady_heap()
    env.reset(seed=0)
    episode = 0
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            episode += 1
            env.reset(seed=episode)
    env.close()


def _steady_heap() -> None:
    """Collect, then switch the garbage collector off for the loop: its full passes over the
    start-up heap, landing in one child's loop and not the other's, moved a per-step figure by
    thousands of instructions. (The counts leave out the collector's work.)"""
    import gc

    gc.collect()
    gc.disable()


def vector_child(kind: str, env_id: str, num_envs: int, steps: int, out: str) -> None:
    """Step a ``SyncVectorEnv`` of ``num_envs`` (bare or recorded) through ``steps`` batches."""
    import gymnasium as gym
    import numpy as np

    from episode_audit import RecordVectorEvidence

    envs: Any = gym.make_vec(env_id, num_envs, vectorization_mode="sync")
    space = envs.action_space
    space.seed(0)
    actions = [np.asarray(space.sample()) for _ in range(steps)]
    if kind == "recorded":
        envs = RecordVectorEvidence(envs, out, overwrite=True, flush_every_s=1e9)
    _steady_heap()
    envs.reset(seed=0)
    for action in actions:
        envs.step(action)
    envs.close()


# numpy's OpenBLAS threads spin after a call, adding millions of instructions that vary from run
# to run; one hash seed keeps dict and set layouts (and so lookup costs) the same. MUJOCO_GL is
# left out: nothing here renders, and with MUJOCO_GL=egl under valgrind the recorded Reacher-v5
# child counted ~16 k more instructions a step than without (the same code; in wall time the
# two settings time the same)
_STEADY = {
    **{k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")},
    "PYTHONHASHSEED": "0",
    "OPENBLAS_NUM_THREADS": "1",
}


def _cachegrind(
    args: list[str], out_file: str, env: dict[str, str] | None = None
) -> dict[str, int]:
    """cachegrind's totals for this script run as a child with ``args``."""
    run = subprocess.run(
        [
            "valgrind",
            "--tool=cachegrind",
            "--cache-sim=yes",
            f"--cachegrind-out-file={out_file}",
            sys.executable,
            __file__,
            *args,
        ],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    return {m[1]: int(m[2].replace(",", "")) for m in _LINE.finditer(run.stderr)}


# callgrind's events, as cachegrind's summary names them
_EVENTS = {
    "I": ("Ir",),
    "I1": ("I1mr",),
    "LLi": ("ILmr",),
    "D": ("Dr", "Dw"),
    "D1": ("D1mr", "D1mw"),
    "LLd": ("DLmr", "DLmw"),
    "LL": ("ILmr", "DLmr", "DLmw"),
}


def _callgrind(args: list[str], out_file: str, env: dict[str, str]) -> dict[str, dict[str, int]]:
    """callgrind's totals for this script run as a child: ``all`` threads, and ``main``'s."""
    subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            "--cache-sim=yes",
            "--separate-threads=yes",
            f"--callgrind-out-file={out_file}",
            sys.executable,
            __file__,
            *args,
        ],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    threads: dict[str, dict[str, int]] = {}
    for path in Path(out_file).parent.glob(Path(out_file).name + "-*"):
        text = path.read_text()
        names = re.search(r"^events: (.*)$", text, re.M)
        totals = re.search(r"^totals: (.*)$", text, re.M)
        if names is None or totals is None:
            raise RuntimeError(f"{path}: no events or totals line in callgrind's output")
        got = dict(zip(names[1].split(), map(int, totals[1].split()), strict=True))
        threads[path.name.rsplit("-", 1)[1]] = {
            k: sum(got[e] for e in events) for k, events in _EVENTS.items()
        }
        path.unlink()
    return {
        "all": {k: sum(t[k] for t in threads.values()) for k in _EVENTS},
        "main": threads["01"],
    }


def counts(
    kind: str, env_id: str, steps: int, tmp: Path, num_envs: int = 0
) -> dict[str, dict[str, int]]:
    """callgrind's totals for one child run (a vector env of ``num_envs`` if not 0)."""
    out = str(tmp / f"{kind}-{steps}.mcap")
    args = ["--child", kind, env_id, str(steps), out]
    if num_envs:
        args = ["--vector-child", kind, env_id, str(num_envs), str(steps), out]
    return _callgrind(args, str(tmp / f"{kind}-{steps}.cg"), _STEADY)


def measure(env_id: str, num_envs: int = 0) -> dict[str, Any]:
    """Per-step counts of the bare and the recorded loop, and the recorder's share.

    With ``num_envs``: a ``SyncVectorEnv`` of that many sub-envs, counts per sub-env step.
    """
    with tempfile.TemporaryDirectory(prefix="episode-audit-instr-") as d:
        jobs = [(kind, n) for kind in ("bare", "recorded") for n in STEPS]
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            runs = pool.map(lambda j: counts(j[0], env_id, j[1], Path(d), num_envs), jobs)
            got = dict(zip(jobs, runs, strict=True))
    lo, hi = STEPS
    sub = max(num_envs, 1)

    def per_step(kind: str, threads: str) -> dict[str, float]:
        a, b = got[kind, lo][threads], got[kind, hi][threads]
        return {k: (b[k] - a[k]) / ((hi - lo) * sub) for k in a}

    bare, rec, main = (
        per_step("bare", "all"),
        per_step("recorded", "all"),
        per_step("recorded", "main"),
    )
    return {
        "env": f"{env_id} x{num_envs} (sync)" if num_envs else env_id,
        "per_step_bare": {k: round(v) for k, v in bare.items()},
        "per_step_recorder": {k: round(rec[k] - bare[k]) for k in bare},
        "instructions_ratio": rec["I"] / bare["I"],
        "est_cycles_ratio": _cycles(rec) / _cycles(bare),
        "per_step_recorder_main_thread": {k: round(main[k] - bare[k]) for k in bare},
        "main_thread_instructions_ratio": main["I"] / bare["I"],
        "main_thread_est_cycles_ratio": _cycles(main) / _cycles(bare),
    }


def _cycles(c: Mapping[str, float]) -> float:
    """Estimated cycles: an L1 miss weighs 10 instructions, a last-level miss 100."""
    return c["I"] + 10 * (c["I1"] + c["D1"]) + 100 * c["LL"]


REPLAY_EPISODES = {"CartPole-v1": 1000, "Reacher-v5": 200, "HalfCheetah-v5": 10}
"""How many episodes ``make bench`` replays per env (others: 100)."""


def replay_child(kind: str, env_id: str, path: str, warm_path: str) -> None:
    """Set up, then (``kind``) nothing, the bare loop, or ``replay()`` of ``path``."""
    import gymnasium as gym

    from episode_audit import open_evidence, replay
    from episode_audit.replay.recorded import replay_actions as _replay_actions
    from episode_audit.replay.recorded import row_ranges as _row_ranges

    ev = open_evidence(path)
    codec = ev.action_codec
    assert codec is not None
    episodes = ev.episodes().column("episode").to_pylist()
    steps = ev.steps()
    every, _ = _replay_actions(steps.column("action"), codec)
    rows = _row_ranges(steps.column("episode").to_numpy())
    actions = [every[rows[e][0] : rows[e][0] + rows[e][1]] for e in episodes]
    warm = gym.make(env_id)
    warm.reset(seed=0)
    warm.step(actions[0][0])
    assert replay([warm_path]).count("identical") == 2
    if kind == "bare":
        env = gym.make(env_id)
        for e, episode_actions in zip(episodes, actions, strict=True):
            env.reset(seed=e)
            for a in episode_actions:
                env.step(a)
    elif kind == "replay":
        result = replay([path])
        assert result.count("identical") == len(episodes), result


def replay_counts(kind: str, env_id: str, path: Path, warm_path: Path) -> dict[str, int]:
    """cachegrind's totals for one replay child."""
    return _cachegrind(
        ["--replay-child", kind, env_id, str(path), str(warm_path)],
        "/dev/null",
        _STEADY,
    )


def measure_replay(env_id: str) -> dict[str, Any]:
    """Instructions of replaying ``make bench``'s episodes against the bare loop's."""
    import gymnasium as gym

    from episode_audit import RecordEvidence

    episodes = REPLAY_EPISODES.get(env_id, 100)
    with tempfile.TemporaryDirectory(prefix="episode-audit-instr-") as d:
        path, warm_path = Path(d) / "replay.mcap", Path(d) / "warm.mcap"
        space = gym.make(env_id).action_space
        space.seed(1)
        for file, first, count in ((path, 0, episodes), (warm_path, 10**6, 2)):
            with RecordEvidence(gym.make(env_id), file) as env:
                for e in range(first, first + count):
                    env.reset(seed=e)
                    done = False
                    while not done:
                        _, _, terminated, truncated, _ = env.step(space.sample())
                        done = terminated or truncated
        kinds = ("none", "bare", "replay")
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            counted = pool.map(lambda k: replay_counts(k, env_id, path, warm_path), kinds)
            got = dict(zip(kinds, counted, strict=True))
    bare = {k: got["bare"][k] - got["none"][k] for k in got["none"]}
    rep = {k: got["replay"][k] - got["none"][k] for k in got["none"]}
    return {
        "env": env_id,
        "episodes": episodes,
        "bare": bare,
        "replay": rep,
        "instructions_ratio": rep["I"] / bare["I"],
        "est_cycles_ratio": _cycles(rep) / _cycles(bare),
    }


def main(argv: list[str]) -> int:
    if argv[:1] == ["--child"]:
        child(argv[1], argv[2], int(argv[3]), argv[4])
        return 0
    if argv[:1] == ["--vector-child"]:
        vector_child(argv[1], argv[2], int(argv[3]), int(argv[4]), argv[5])
        return 0
    if argv[:1] == ["--replay-child"]:
        replay_child(argv[1], argv[2], argv[3], argv[4])
        return 0
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (apt install valgrind)", file=sys.stderr)
        return 2
    if argv[:1] == ["--replay"]:
        for env_id in argv[1:] or ["CartPole-v1"]:
            print(json.dumps(measure_replay(env_id), indent=2), flush=True)
        return 0
    if argv[:1] == ["--vector"]:
        env_id = argv[1] if len(argv) > 1 else "CartPole-v1"
        num_envs = int(argv[2]) if len(argv) > 2 else 8
        print(json.dumps(measure(env_id, num_envs), indent=2), flush=True)
        return 0
    for env_id in argv or ["Reacher-v5"]:
        print(json.dumps(measure(env_id), indent=2), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
