"""episode-audit benchmarks, reported as ratios against a baseline measured in the same run.

    python bench/run.py                 # everything (a few minutes on 2 cores)
    python bench/run.py record check    # a selection

Targets (docs/benchmarks.md): recording overhead <= 1.15x on CartPole-v1 and <= 1.03x on
Reacher-v5 / HalfCheetah-v5, <= 1.20x per sub-env step of a CartPole x8 SyncVectorEnv (each
side stepped in turns of a few ms, so that the host's slowdowns land on both), and the same for
a Reacher-v5 x8 (reward terms in every info); <= 22 bytes per
CartPole step; recorder memory flat (<= 64 MB growth) over a 1 M-step episode; check >= 5 M
steps/s; replay <= 1.05x bare stepping; export to Foxglove MCAP >= 1 M steps per minute on one
core (a CartPole file, pinned to one CPU; process CPU time and wall time, with the load
average). SB3 (bench_sb3.py): a real PPO run with / without RecordVecEnvEvidence, and its cost
per sub-env step (skipped when SB3 is not installed); jobs (bench_jobs.py): check, report and
replay over 1 000 files (+ 50 Reacher-v5 episodes for replay) with --jobs 1 vs 2, as library
calls and as fresh command-line processes, 3 rounds, medians (replay >= 1.8x), the load
average, and an Amdahl estimate to N cores.
Results are printed and written to bench/results/latest.json. Nothing here is a timed test.
The files the benches write (~400 MB) go to a folder of the temporary directory, removed at the
end (an error and Ctrl-C included) unless EPISODE_AUDIT_BENCH_KEEP is set; then its path is
printed.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import bench_jobs
import bench_sb3
import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.record.fast import PURE_PYTHON_ENV
from episode_audit.record.fast import compiled as fast_compiled

RESULTS = Path(__file__).resolve().parent / "results"
KEEP = "EPISODE_AUDIT_BENCH_KEEP"
TMP: Path
"""The run's scratch folder, made by main() (:func:`scratch`)."""


@contextlib.contextmanager
def scratch() -> Iterator[Path]:
    """A folder for the benches' files, removed at the end unless $EPISODE_AUDIT_BENCH_KEEP is set.

    SB3's logger makes a folder in the temporary directory at each learn() (none configured):
    $SB3_LOGDIR puts them here meanwhile.
    """
    path = Path(tempfile.mkdtemp(prefix="episode-audit-bench-"))
    before = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(path / "sb3-logs")
    try:
        yield path
    finally:
        if before is None:
            del os.environ["SB3_LOGDIR"]
        else:
            os.environ["SB3_LOGDIR"] = before
        if os.environ.get(KEEP):
            print(f"bench files kept in {path} ({KEEP} is set)", file=sys.stderr)
        else:
            shutil.rmtree(path, ignore_errors=True)


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def actions_for(env_id: str, n: int, seed: int = 0) -> list[Any]:
    space = gym.make(env_id).action_space
    space.seed(seed)
    return [space.sample() for _ in range(n)]


def run_steps(env: gym.Env[Any, Any], actions: list[Any]) -> float:
    """Seconds to step through `actions`, resetting (seeded) at episode ends."""
    loop = stepper(env)
    gc.collect()
    start = time.perf_counter()
    loop(actions)
    return time.perf_counter() - start


def stepper(env: gym.Env[Any, Any]) -> Callable[[list[Any]], None]:
    """Reset ``env`` (seed 0); a function that steps it through a slice of actions, resetting
    (seeded 1, 2, ...) at episode ends, from where the previous slice left it."""
    env.reset(seed=0)
    episode = 0

    def loop(actions: list[Any]) -> None:
        nonlocal episode
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                episode += 1
                env.reset(seed=episode)

    return loop


def interleaved(
    loops: Mapping[str, Callable[[Any], None]],
    actions: Sequence[Any] | np.ndarray[Any, Any],
    slice_steps: int,
) -> dict[str, float]:
    """Seconds each loop takes over ``actions``, the loops taking turns a slice at a time.

    Each slice of ``slice_steps`` actions is stepped by every loop in turn (the order rotating
    from slice to slice), each turn timed on its own: a slowdown of the host that lasts longer
    than a slice (a few ms) lands on every side alike, where whole runs one after another each
    meet a different host.
    """
    names = list(loops)
    seconds = dict.fromkeys(names, 0.0)
    gc.collect()
    for k, start in enumerate(range(0, len(actions), slice_steps)):
        chunk = actions[start : start + slice_steps]
        turn = k % len(names)
        for name in names[turn:] + names[:turn]:
            t0 = time.perf_counter()
            loops[name](chunk)
            seconds[name] += time.perf_counter() - t0
    return seconds


def ratios(base: list[float], other: list[float]) -> dict[str, Any]:
    """The median of the per-round ratios, and the ratio of the fastest rounds.

    Host noise only ever adds time, so the fastest round of each side is the closest to its
    own cost; on a quiet machine the two figures agree.
    """
    per_round = [o / b for b, o in zip(base, other, strict=True)]
    return {
        "ratio_median": statistics.median(per_round),
        "ratio_of_minimums": min(other) / min(base),
        "ratios": [round(x, 4) for x in per_round],
    }


def noise_floor(first: list[float], second: list[float]) -> dict[str, Any]:
    """The same work timed twice in each round (an A/A test): how far apart two equal runs
    land on this host. A ratio inside this spread cannot be told from 1 here."""
    per_round = [b / a for a, b in zip(first, second, strict=True)]
    q1, _, q3 = statistics.quantiles(per_round, n=4)
    return {"aa_median": statistics.median(per_round), "aa_quartiles": [round(q1, 4), round(q3, 4)]}


def _recorded(
    env_id: str,
    path: Path,
    pure: bool,
    *,
    deferred: bool = False,
    flush_every_s: float = 1.0,
) -> RecordEvidence[Any, Any]:
    """A recorder of ``env_id``: the compiled step, or (``pure``) the pure-Python one.

    ``deferred``: one block for the whole run, flushed at ``close()`` only (what the loop would
    cost if writing blocks and episode records cost it nothing).
    """
    os.environ[PURE_PYTHON_ENV] = "1" if pure else "0"
    try:
        if deferred:
            return RecordEvidence(
                gym.make(env_id), path, overwrite=True, flush_every_s=1e9, block_steps=1 << 40
            )
        return RecordEvidence(gym.make(env_id), path, overwrite=True, flush_every_s=flush_every_s)
    finally:
        del os.environ[PURE_PYTHON_ENV]


def timed_close(env: Any) -> float:
    """Milliseconds ``env.close()`` takes."""
    t0 = time.perf_counter()
    env.close()
    return (time.perf_counter() - t0) * 1e3


def bench_record(env_id: str, steps: int, rounds: int, slice_steps: int) -> dict[str, Any]:
    """Bare, two reference wrappers, and recorded with the compiled and the pure-Python step,
    over the same actions, stepped in turns of ``slice_steps`` (:func:`interleaved`), a second
    bare env among them for the A/A noise; medians of per-round ratios to bare.

    Each recorder records every round as one run, as a training run would, and flushes as
    often, counted in its own steps, as it would alone. A recorder flushes when its block is
    full or ``flush_every_s`` of wall time has passed; here it gets one turn in seven, so it is
    given seven seconds. (With one second, each flush would hold a seventh of a run alone's
    steps, and its fixed cost, ~1.3 ms, would be paid seven times as often.) Its ``close()``,
    once a run, is timed apart (``close_ms``). One more recorder, ``loop``, writes nothing until
    ``close()``, which does not count: the cost of the step and reset paths alone, about what
    the loop would pay if its flushes cost nothing (a little more: its ended episodes stay in
    memory, for the garbage collector to walk)."""
    actions = actions_for(env_id, steps)
    warm = RecordEvidence(gym.make(env_id), TMP / f"warm-{env_id}.mcap", overwrite=True)
    run_steps(warm, actions[: min(steps, 5000)])
    warm.close()
    kinds = ("bare", "bare_again", "wrapper", "stats", "pure", "rec", "loop")
    runs = {
        kind: _recorded(
            env_id, TMP / f"{env_id}-{kind}.mcap", pure=kind == "pure", flush_every_s=len(kinds)
        )
        for kind in ("pure", "rec")
    }
    run_loops = {kind: stepper(env) for kind, env in runs.items()}
    times: dict[str, list[float]] = {k: [] for k in kinds}
    for r in range(rounds):
        envs: dict[str, gym.Env[Any, Any]] = {
            "bare": gym.make(env_id),
            "bare_again": gym.make(env_id),
            "wrapper": gym.Wrapper(gym.make(env_id)),
            "stats": gym.wrappers.RecordEpisodeStatistics(gym.make(env_id)),
            "loop": _recorded(env_id, TMP / f"{env_id}-loop-{r}.mcap", pure=False, deferred=True),
        }
        loops = {k: run_loops[k] if k in run_loops else stepper(envs[k]) for k in kinds}
        seconds = interleaved(loops, actions, slice_steps)
        envs["loop"].close()  # (not counted: its one flush is what it leaves out)
        for kind in kinds:
            times[kind].append(seconds[kind])
    close_ms = {kind: timed_close(env) for kind, env in runs.items()}
    size = runs["rec"].path.stat().st_size
    bare_t = times["bare"]
    per_step = {k: statistics.median(v) / steps * 1e6 for k, v in times.items()}
    return {
        "env": env_id,
        "steps": steps,
        "rounds": rounds,
        "slice_steps": slice_steps,
        "compiled_step": fast_compiled(),
        "bare_us_per_step": per_step["bare"],
        "recorded_us_per_step": per_step["rec"],
        **ratios(bare_t, times["rec"]),
        **noise_floor(bare_t, times["bare_again"]),
        "pure_python_ratio_median": ratios(bare_t, times["pure"])["ratio_median"],
        "empty_wrapper_ratio_median": ratios(bare_t, times["wrapper"])["ratio_median"],
        "episode_statistics_ratio_median": ratios(bare_t, times["stats"])["ratio_median"],
        "flushes_deferred_ratio_median": ratios(bare_t, times["loop"])["ratio_median"],
        # per round, the extra time over that round's bare run; the median of those
        "overhead_us": {
            name: statistics.median(
                (t - b) / steps * 1e6 for t, b in zip(times[kind], bare_t, strict=True)
            )
            for name, kind in (
                ("recorder", "rec"),
                ("recorder_flushes_deferred", "loop"),
                ("pure_python", "pure"),
                ("empty_wrapper", "wrapper"),
                ("RecordEpisodeStatistics", "stats"),
            )
        },
        "close_ms": close_ms["rec"],
        "bytes_per_step": size / (steps * rounds),
    }


def run_vector(envs: Any, actions: np.ndarray[Any, Any]) -> float:
    """Seconds to step a vector env through `actions` (one row per vector step), autoresetting."""
    envs.reset(seed=0)
    gc.collect()
    start = time.perf_counter()
    vector_stepper(envs)(actions)
    return time.perf_counter() - start


def vector_stepper(envs: Any) -> Callable[[np.ndarray[Any, Any]], None]:
    """A function that steps ``envs`` through a slice of action rows (Gymnasium's autoreset)."""

    def loop(actions: np.ndarray[Any, Any]) -> None:
        for action in actions:
            envs.step(action)

    return loop


def vector_actions(env_id: str, steps: int, num_envs: int) -> np.ndarray[Any, Any]:
    """``steps`` rows of ``num_envs`` actions of ``env_id``, the same in every run."""
    space = gym.make(env_id).action_space
    if isinstance(space, gym.spaces.Discrete):
        return np.random.default_rng(0).integers(0, int(space.n), size=(steps, num_envs))
    space.seed(0)
    return np.array([[space.sample() for _ in range(num_envs)] for _ in range(steps)])


def bench_vector(
    num_envs: int,
    steps: int,
    rounds: int,
    slice_steps: int,
    mode: str = "sync",
    env_id: str = "CartPole-v1",
) -> dict[str, Any]:
    """Per-sub-env-step overhead of RecordVectorEvidence on a vector ``env_id``, bare and
    recorded (and bare again, for the A/A noise) taking turns a slice at a time."""
    actions = vector_actions(env_id, steps, num_envs)

    def make() -> Any:
        return gym.make_vec(env_id, num_envs, vectorization_mode=mode)

    warm = RecordVectorEvidence(make(), TMP / "warm-vector.mcap", overwrite=True)
    run_vector(warm, actions[: min(steps, 1000)])
    warm.close()
    kinds = ("bare", "bare_again", "rec")
    # one run over every round, flushing as often as alone (see bench_record)
    rec = RecordVectorEvidence(
        make(), TMP / f"vector-{env_id}.mcap", overwrite=True, flush_every_s=len(kinds)
    )
    rec.reset(seed=0)
    rec_loop = vector_stepper(rec)
    times: dict[str, list[float]] = {k: [] for k in kinds}
    for _ in range(rounds):
        envs = {"bare": make(), "bare_again": make()}
        for env in envs.values():
            env.reset(seed=0)
        loops = {**{k: vector_stepper(env) for k, env in envs.items()}, "rec": rec_loop}
        seconds = interleaved(loops, actions, slice_steps)
        for env in envs.values():
            env.close()
        for kind, t in seconds.items():
            times[kind].append(t)
    close_ms = timed_close(rec)
    size = rec.path.stat().st_size
    bare_t, rec_t = times["bare"], times["rec"]
    sub_steps = steps * num_envs
    return {
        "env": f"{env_id} x{num_envs} ({mode})",
        "vector_steps": steps,
        "rounds": rounds,
        "slice_steps": slice_steps,
        "bare_us_per_sub_env_step": statistics.median(bare_t) / sub_steps * 1e6,
        "recorded_us_per_sub_env_step": statistics.median(rec_t) / sub_steps * 1e6,
        "overhead_us_per_sub_env_step": statistics.median(
            [(rt - bt) / sub_steps * 1e6 for rt, bt in zip(rec_t, bare_t, strict=True)]
        ),
        **ratios(bare_t, rec_t),
        **noise_floor(bare_t, times["bare_again"]),
        "close_ms": close_ms,
        "bytes_per_sub_env_step": size / (sub_steps * rounds),
    }


class Endless(gym.Env[np.ndarray, np.int64]):
    """A cheap env that never ends by itself (for the long-episode memory benchmark)."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        return self.np_random.uniform(-1, 1, 4).astype(np.float32), {}

    def step(self, action: Any) -> Any:
        obs = self.np_random.uniform(-1, 1, 4).astype(np.float32)
        return obs, 1.0, False, False, {"reward_terms": {"alive": 1.0}}


def bench_memory(steps: int) -> dict[str, Any]:
    """RSS growth of a recorder over one `steps`-long episode."""
    env = RecordEvidence(Endless(), TMP / "memory.mcap", overwrite=True)
    env.reset(seed=0)
    gc.collect()
    samples = []
    base = rss_mb()
    for i in range(steps):
        env.step(np.int64(i & 1))
        if i % (steps // 20) == 0:
            samples.append(rss_mb() - base)
    env.close()
    return {
        "steps": steps,
        "rss_growth_mb_samples": [round(s, 1) for s in samples],
        "rss_growth_mb_max": max(samples),
    }


def big_cartpole_file(steps: int) -> Path:
    path = TMP / f"cartpole-{steps}.mcap"
    if path.exists():
        return path
    space = gym.make("CartPole-v1").action_space
    space.seed(0)
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    env.reset(seed=0)
    episode = 0
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(space.sample())
        if terminated or truncated:
            episode += 1
            env.reset(seed=None if episode % 2 else episode)
    env.close()
    return path


def bench_check(steps: int, rounds: int) -> dict[str, Any]:
    from episode_audit.check.core import check

    path = big_cartpole_file(steps)
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        result = check([path])
        times.append(time.perf_counter() - t0)
    best = statistics.median(times)
    return {
        "steps": result.steps,
        "seconds_median": best,
        "steps_per_second": result.steps / best,
        "findings": len(result.findings),
    }


def bench_replay(env_id: str, episodes: int, rounds: int) -> dict[str, Any]:
    """Replay time vs stepping the bare env with the same actions (and the same resets).

    Both sides make the env, reset each episode with its seed and step the very action
    objects replay steps with (numpy integers for a Discrete space, as ``Discrete.sample()``
    gives); replay also opens and reads the file and compares. Each round times bare, replay,
    bare: replay against the mean of the two bare runs around it (drift cancels), median of
    the per-round ratios; the two bare runs against each other give the noise floor.
    """
    from episode_audit.replay import replay
    from episode_audit.replay.recorded import replay_actions as _replay_actions

    path = TMP / f"replay-{env_id}.mcap"
    space = gym.make(env_id).action_space
    space.seed(1)
    with RecordEvidence(gym.make(env_id), path, overwrite=True) as env:
        for e in range(episodes):
            env.reset(seed=e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(space.sample())
                done = term or trunc
    ev = open_evidence(path)
    codec = ev.action_codec
    assert codec is not None
    episodes_actions = [
        _replay_actions(ev.episode(e).steps.column("action"), codec)[0] for e in range(episodes)
    ]

    def bare() -> float:
        gc.collect()
        t0 = time.perf_counter()
        bare_env = gym.make(env_id)
        for e, actions in enumerate(episodes_actions):
            bare_env.reset(seed=e)
            for a in actions:
                bare_env.step(a)
        return time.perf_counter() - t0

    before_t, rep_t, after_t = [], [], []
    for _ in range(rounds):
        before_t.append(bare())
        gc.collect()
        t0 = time.perf_counter()
        result = replay([path])
        rep_t.append(time.perf_counter() - t0)
        assert result.count("identical") == episodes, result
        after_t.append(bare())
    # each replay against the mean of the bare runs around it (drift cancels)
    bare_t = [(b + a) / 2 for b, a in zip(before_t, after_t, strict=True)]
    steps = sum(len(a) for a in episodes_actions)
    own = replay_own_seconds(path, env_id, rounds, episodes_actions)
    return {
        "env": env_id,
        "episodes": episodes,
        "steps": steps,
        "rounds": rounds,
        "bare_us_per_step": statistics.median(bare_t) / steps * 1e6,
        "replay_us_per_step": statistics.median(rep_t) / steps * 1e6,
        **ratios(bare_t, rep_t),
        **noise_floor(before_t, after_t),
        "own_us_per_step": own / steps * 1e6,
        "ratio_own_work": 1 + own / min(bare_t),
    }


def bench_export(steps: int, rounds: int) -> dict[str, Any]:
    """``export --to foxglove`` of a CartPole file, pinned to one CPU: steps per minute.

    Process CPU time is what the export costs the core it runs on (other processes on a busy
    host do not add to it); wall time is what a user waits on a host as loaded as the load
    average says.
    """
    from episode_audit.export import export

    path = big_cartpole_file(steps)
    out = TMP / "export.foxglove.mcap"
    affinity = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(affinity)})
    try:
        cpu, wall = [], []
        for _ in range(rounds):
            gc.collect()
            c0, w0 = time.process_time(), time.perf_counter()
            result = export([path], out, to="foxglove", overwrite=True)
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
    finally:
        os.sched_setaffinity(0, affinity)
    return {
        "steps": result.steps,
        "rounds": rounds,
        "cpu_seconds_min": min(cpu),
        "wall_seconds_min": min(wall),
        "steps_per_minute_cpu": result.steps / min(cpu) * 60,
        "steps_per_minute_wall": result.steps / min(wall) * 60,
        "bytes_per_step": out.stat().st_size / result.steps,
        "load_average": os.getloadavg(),
    }


class Playback(gym.Env[Any, Any]):
    """Hands back a file's recorded resets and steps, whatever the action: an env whose own
    cost is next to nothing, so that replaying in it times replay's own work. Its spec is the
    recorded env's, so replay takes it as that env."""

    def __init__(self, path: Path, env_id: str) -> None:
        ev = open_evidence(path)
        real = gym.make(env_id)
        self.observation_space, self.action_space = real.observation_space, real.action_space
        self.spec = gym.spec(env_id)  # (replay verifies a factory's env by its spec)
        obs_codec = ev.observation_codec
        assert obs_codec is not None
        steps = ev.steps()
        resets = ev.resets()
        firsts = obs_codec.decode(resets.column("observation").combine_chunks())
        self.resets = dict(zip(resets.column("episode").to_pylist(), firsts, strict=True))
        self.seeds = {r["seed"]: r["episode"] for r in ev.episodes().to_pylist()}
        rows = zip(
            steps.column("episode").to_pylist(),
            obs_codec.decode(steps.column("observation").combine_chunks()),
            steps.column("reward").to_pylist(),
            steps.column("terminated").to_pylist(),
            steps.column("truncated").to_pylist(),
            steps.column("terms").to_pylist(),
            strict=True,
        )
        self.episodes: dict[int, list[Any]] = {}
        for e, obs, reward, term, trunc, terms in rows:
            step = (obs, reward, term, trunc, dict(terms or []))
            self.episodes.setdefault(e, []).append(step)
        self.rows: list[Any] = []
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        episode = self.seeds[seed]
        self.rows, self.t = self.episodes[episode], 0
        return self.resets[episode], {}

    def step(self, action: Any) -> Any:
        self.t += 1
        return self.rows[self.t - 1]


def replay_own_seconds(path: Path, env_id: str, rounds: int, actions: list[Any]) -> float:
    """Replay's own work on ``path``: replay in :class:`Playback` (behind the env's TimeLimit)
    minus stepping :class:`Playback` bare with the same ``actions`` per episode (numpy slices,
    as replay steps with: iterating them costs both sides), fastest rounds. The host's noise
    barely moves it. Replay counts the TimeLimit itself where the bare side calls it, so this
    is net of that call."""
    from episode_audit.replay import replay

    limit = gym.spec(env_id).max_episode_steps
    playback = Playback(path, env_id)

    def make() -> gym.Env[Any, Any]:
        return TimeLimit(playback, limit) if limit else playback

    bare_t, rep_t = [], []
    for _ in range(rounds):
        gc.collect()
        t0 = time.perf_counter()
        env = make()
        for seed, episode in playback.seeds.items():
            env.reset(seed=seed)
            for a in actions[episode]:
                env.step(a)
        bare_t.append(time.perf_counter() - t0)
        gc.collect()
        t0 = time.perf_counter()
        result = replay([path], env_factory=make)
        rep_t.append(time.perf_counter() - t0)
        assert result.count("identical") == len(playback.seeds), result
    return min(rep_t) - min(bare_t)


def _state_cases() -> dict[str, Callable[[], Any]]:
    """What each shipped state adapter snapshots, built and warmed up (optional libs if there)."""
    wrappers = gym.wrappers

    def warm(env: Any, steps: int = 500) -> Any:
        env.reset(seed=0)
        env.action_space.seed(0)
        for _ in range(steps):
            result = env.step(env.action_space.sample())
            if not hasattr(env, "num_envs") and (result[2] or result[3]):
                env.reset()
        return env

    cases: dict[str, Callable[[], Any]] = {
        "NormalizeObservation, CartPole-v1": lambda: warm(
            wrappers.NormalizeObservation(gym.make("CartPole-v1"))
        ),
        "NormalizeReward, CartPole-v1": lambda: warm(
            wrappers.NormalizeReward(gym.make("CartPole-v1"))
        ),
        "NormalizeObservation, HalfCheetah-v5": lambda: warm(
            wrappers.NormalizeObservation(gym.make("HalfCheetah-v5"))
        ),
        "vector NormalizeObservation, CartPole-v1 x8": lambda: warm(
            wrappers.vector.NormalizeObservation(gym.make_vec("CartPole-v1", 8))
        ),
    }
    try:
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.vec_env import VecNormalize

        def vec_normalize() -> Any:
            env = VecNormalize(make_vec_env("CartPole-v1", n_envs=8, seed=0))
            env.reset()
            for _ in range(500):
                env.step(np.zeros(8, dtype=np.int64))
            return env

        cases["SB3 VecNormalize, CartPole-v1 x8"] = vec_normalize
    except ImportError:
        pass
    try:
        import ale_py

        gym.register_envs(ale_py)
        cases["ALE Pong-v5"] = lambda: warm(gym.make("ALE/Pong-v5"), 200)
    except ImportError:
        pass
    return cases


def bench_state(rounds: int = 200) -> list[dict[str, Any]]:
    """Per shipped state adapter: bytes of the snapshot a reset row holds, and the time to take
    it (at every recorded reset) and to restore it (replay, before each episode's reset)."""
    from episode_audit.record.state import StateTargets, restore_snapshot

    out = []
    for name, make in _state_cases().items():
        env = make()
        targets = StateTargets(env)
        text = targets.capture([])
        assert text is not None, name
        take, put = [], []
        for _ in range(rounds):
            t0 = time.perf_counter()
            targets.capture([])
            t1 = time.perf_counter()
            restore_snapshot(env, text, seeded=False)
            put.append(time.perf_counter() - t1)
            take.append(t1 - t0)
        out.append(
            {
                "adapter": name,
                "bytes_per_episode": len(text),
                "us_per_reset": round(statistics.median(take) * 1e6, 1),
                "us_per_restore": round(statistics.median(put) * 1e6, 1),
            }
        )
        env.close()
    return out


def bench_atari(steps: int, rounds: int, slice_steps: int) -> dict[str, Any] | str:
    """ALE Pong-v5 (210x160x3 frames, ~100 KB a step), bare vs recorded, in turns as
    ``record`` (each recorder one run over every round, its ``close()`` timed apart): frames
    kept losslessly (the default) and as digests (``digest_min_bytes``)."""
    try:
        import ale_py
    except ImportError:
        return "skipped: ale-py not installed"
    gym.register_envs(ale_py)
    env_id = "ALE/Pong-v5"
    actions = actions_for(env_id, steps)
    warm = RecordEvidence(gym.make(env_id), TMP / "warm-atari.mcap", overwrite=True)
    run_steps(warm, actions[:500])
    warm.close()
    kinds = ("bare", "bare_again", "rec", "digest")
    # one run each over every round, flushing as often as alone (see bench_record)
    runs = {
        "rec": RecordEvidence(
            gym.make(env_id), TMP / "atari.mcap", overwrite=True, flush_every_s=len(kinds)
        ),
        "digest": RecordEvidence(
            gym.make(env_id),
            TMP / "atari-digest.mcap",
            overwrite=True,
            digest_min_bytes=4096,
            flush_every_s=len(kinds),
        ),
    }
    run_loops = {kind: stepper(env) for kind, env in runs.items()}
    times: dict[str, list[float]] = {k: [] for k in kinds}
    for _ in range(rounds):
        envs = {"bare": gym.make(env_id), "bare_again": gym.make(env_id)}
        loops = {k: run_loops[k] if k in run_loops else stepper(envs[k]) for k in kinds}
        seconds = interleaved(loops, actions, slice_steps)
        for kind in kinds:
            times[kind].append(seconds[kind])
    close_ms = {kind: timed_close(env) for kind, env in runs.items()}
    bare_t = times["bare"]
    return {
        "env": env_id,
        "steps": steps,
        "rounds": rounds,
        "bare_us_per_step": statistics.median(bare_t) / steps * 1e6,
        **ratios(bare_t, times["rec"]),
        **noise_floor(bare_t, times["bare_again"]),
        "digest_ratio_median": ratios(bare_t, times["digest"])["ratio_median"],
        "close_ms": close_ms["rec"],
        "bytes_per_step": runs["rec"].path.stat().st_size / (steps * rounds),
        "digest_bytes_per_step": runs["digest"].path.stat().st_size / (steps * rounds),
    }


BENCHES: dict[str, Callable[[], Any]] = {
    "record": lambda: [
        # slices of ~5 ms of bare stepping
        bench_record("CartPole-v1", 200_000, 7, 1000),
        bench_record("Reacher-v5", 30_000, 7, 200),
        bench_record("HalfCheetah-v5", 30_000, 7, 200),
    ],
    "vector": lambda: bench_vector(8, 25_000, 7, 100),
    # camera frames: ~100 KB a step (slices of ~10 ms); "skipped: ..." without ale-py
    "atari": lambda: bench_atari(3_000, 5, 50),
    # reward terms in every step's info (slices of ~10 ms, as above)
    "vector_mujoco": lambda: bench_vector(8, 2_000, 7, 25, env_id="Reacher-v5"),
    "memory": lambda: bench_memory(1_000_000),
    "check": lambda: bench_check(1_000_000, 5),
    # 41 interleaved rounds: on a shared VM one round's ratio moves by +-10 %
    "replay": lambda: [
        bench_replay("CartPole-v1", 1000, 41),
        bench_replay("Reacher-v5", 200, 41),
        bench_replay("HalfCheetah-v5", 10, 41),
    ],
    "export": lambda: bench_export(200_000, 3),
    # inside a real PPO run, and per sub-env step; "skipped: SB3 not installed" without it
    "sb3": lambda: bench_sb3.bench(TMP, interleaved, vector_actions),
    # --jobs 1 vs 2 over 1 000 files (+ 50 MuJoCo episodes for replay); Amdahl estimate to N
    "jobs": lambda: bench_jobs.bench(TMP),
    "state": bench_state,
}


def warn_once() -> None:
    """Print each distinct MuJoCo warning once, not at every model build.

    Gymnasium's HalfCheetah model sets ``settotalmass``, which MuJoCo 3.3+ warns is deprecated
    each time a model is compiled: hundreds of times in one run of the benches.
    """
    import mujoco

    seen: set[str] = set()

    def warn(text: str) -> None:
        if text not in seen:
            seen.add(text)
            print(f"MuJoCo warning (shown once): {text}", file=sys.stderr, flush=True)

    mujoco.set_mju_user_warning(warn)


def main(argv: list[str]) -> int:
    wanted = argv or list(BENCHES)
    unknown = [w for w in wanted if w not in BENCHES]
    if unknown:
        print(f"unknown benchmark(s) {unknown}; choose from {list(BENCHES)}", file=sys.stderr)
        return 2
    results: dict[str, Any] = {
        "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}
    }
    warn_once()
    global TMP
    with scratch() as TMP:
        for name in wanted:
            print(f"== {name}", flush=True)
            results[name] = BENCHES[name]()
            print(json.dumps(results[name], indent=2), flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "latest.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
