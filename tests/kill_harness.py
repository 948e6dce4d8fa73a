"""Crash-safety harness: kill recording processes with SIGKILL and measure what survives.

A zygote process (``python -m tests.kill_harness --zygote``) imports gymnasium and episode-audit
once, then forks one recording child per kill, so a kill costs the recording, not an interpreter
start. Each child records CartPole-v1 with a random ``block_steps`` and ``flush_every_s`` and,
after every ``step()`` and ``reset()``, appends a fixed-size progress record to a log file with
``os.write`` (it survives the kill): the step count, the time, the evidence file's size as the
kernel sees it, and whether the step ended an episode. The recorder's writer thread logs too:
as each flush's chunk is being written (with the steps it brings the file to) and once it is.
Kills land in five ways:

- ``timer``: the parent sends SIGKILL after a random delay (anywhere: mid-step, mid-flush);
- ``step``: the child SIGKILLs itself right after a random step;
- ``flush``: the child arms its file so that the next flush dies inside a write — the chunk or
  its message index — after handing a random prefix of that write to the OS (armed as that
  flush's writing begins, so a flush already under way in the writer thread is not cut);
- ``close``: the same inside ``close()`` (final chunk, index, run-end record, summary, footer);
- ``diskfull``: the disk fills up, for real: after a random step the child's file size limit
  (``RLIMIT_FSIZE``, no root needed) is set a random few bytes above the file's size, so the
  OS refuses (or takes a part of) the next flushes, one of them a ``flush()`` call; then space
  returns, the child records more, calls ``flush()`` and SIGKILLs itself. Half of these runs
  hold refused flushes for a retry (the default), half drop them (``RETRY_LIMIT_BYTES`` 0).
  Their progress log goes through a FIFO (the size limit would refuse it too).

The file is the library's own: only ``open`` in ``episode_audit.record.writer`` is shadowed by
one that returns a pass-through wrapper of the real file (``_Disk``); unarmed, it changes nothing.

For each kill :func:`judge` checks: the file reads; it is unfinished (unless ``close()``
completed); every step of a flush whose writing completed is in it;
every step reported more than ``flush_every_s`` + :data:`MARGIN` before the child's last
progress record is in it; the episodes with an end record are exactly those whose last step is
in the file; and ``recover`` rewrites it into a finished file with the same episodes and steps.
For ``diskfull`` (:func:`judge_disk_full`): ``check`` reads the file as it is (no ``recover``),
it holds every step recorded but the rows of the refused flushes the writer dropped (none when
it held them for a retry), and ``recover`` keeps the same steps.

Run directly for figures: ``python -m tests.kill_harness --kills 120``.
"""

from __future__ import annotations

import argparse
import builtins
import json
import os
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

REPO = Path(__file__).resolve().parents[1]
MODES = ("timer", "step", "flush", "close", "diskfull")
MARGIN = 0.25
"""Seconds allowed beyond ``flush_every_s`` (a flush's own duration, scheduling)."""

_REC = struct.Struct("<qqqq")  # kind, steps so far, monotonic ns, evidence file size
STEP, ENDED, RESET, KILL, CLOSED, FLUSHED, LOST, WRITING, WRITTEN = range(9)


# ----------------------------------------------------------------------------- child side


class _Disk:
    """The evidence file, passed through; when armed, dies inside the n-th non-empty write."""

    def __init__(self, f: IO[bytes], log: int, rng: random.Random) -> None:
        self.f = f
        self.log = log
        self.rng = rng
        self.armed: int | None = None

    def write(self, data: bytes) -> int:
        if self.armed is not None and len(data):
            if self.armed == 0:
                self.f.write(data[: self.rng.randrange(len(data))])
                self.f.flush()  # the OS got a prefix of this write, then the process died
                _log(self.log, KILL, -1, os.fstat(self.f.fileno()).st_size)
                os.kill(os.getpid(), signal.SIGKILL)
            self.armed -= 1
        return self.f.write(data)

    def tell(self) -> int:
        return self.f.tell()

    def flush(self) -> None:
        self.f.flush()

    def fileno(self) -> int:
        return self.f.fileno()

    def close(self) -> None:
        self.f.close()


def _log(fd: int, kind: int, n: int, size: int) -> None:
    os.write(fd, _REC.pack(kind, n, time.monotonic_ns(), size))


def _child(cfg: dict[str, Any]) -> None:
    import gymnasium as gym

    import episode_audit.record.writer as writer_module
    from episode_audit import RecordEvidence

    rng = random.Random(cfg["seed"])
    log = os.open(cfg["log"], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    disks: list[_Disk] = []

    def open_disk(path: Any, mode: str, **kwargs: Any) -> _Disk:
        disks.append(_Disk(builtins.open(path, mode, **kwargs), log, rng))  # noqa: SIM115
        return disks[-1]

    writer_module.open = open_disk  # type: ignore[attr-defined]  # shadows the builtin there
    env = RecordEvidence(
        gym.make("CartPole-v1"),
        cfg["path"],
        block_steps=cfg["block_steps"],
        flush_every_s=cfg["flush_every_s"],
    )
    disk = disks[0]
    fd = disk.fileno()
    mode, arm = cfg["mode"], cfg["arm"]
    arming: list[int] = []  # flush / close: armed as the next flush's writing begins
    writer = env._file.writer
    write_flush = writer._flush_now

    def flush_now(failed: list[Exception]) -> None:  # (in the recorder's writer thread)
        steps = env._file.counts["steps"]  # (the steps the file holds once this is written)
        if arming:
            disk.armed = arming.pop()
        _log(log, WRITING, steps, 0)
        write_flush(failed)
        if not failed:
            _log(log, WRITTEN, steps, os.fstat(fd).st_size)

    writer._flush_now = flush_now  # type: ignore[method-assign]
    env.action_space.seed(cfg["seed"])
    episode = 0
    env.reset(seed=cfg["seed"] * 1000)
    _log(log, RESET, 0, os.fstat(fd).st_size)
    n = 0
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        n += 1
        ended = terminated or truncated
        _log(log, ENDED if ended else STEP, n, os.fstat(fd).st_size)
        if n == arm and mode == "step":
            _log(log, KILL, n, os.fstat(fd).st_size)
            os.kill(os.getpid(), signal.SIGKILL)
        if n == arm and mode == "flush":
            arming.append(cfg["write"])
        if n == arm and mode == "close":
            arming.append(cfg["write"])
            env.close()
            _log(log, CLOSED, n, os.path.getsize(cfg["path"]))
            os.kill(os.getpid(), signal.SIGKILL)
        if mode == "diskfull" and n >= arm:
            _disk_full(env, cfg, n - arm, log, fd)
        if ended:
            episode += 1
            env.reset(seed=cfg["seed"] * 1000 + episode)
            _log(log, RESET, n, os.fstat(fd).st_size)
    os._exit(3)  # never killed: the parent reports it


def _disk_full(env: Any, cfg: dict[str, Any], n: int, log: int, fd: int) -> None:
    """The ``diskfull`` mode, ``n`` steps after it began: fill, refuse, free, flush, die."""
    import resource

    import episode_audit.record.writer as writer_module

    full, after = cfg["full_steps"], cfg["after_steps"]
    _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    if n == 0:
        import warnings

        warnings.simplefilter("ignore", RuntimeWarning)  # (the recorder's one-line warning)
        if cfg["drop"]:
            writer_module.RETRY_LIMIT_BYTES = 0  # type: ignore[misc]
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit: EFBIG, not a signal
        size = os.fstat(fd).st_size
        resource.setrlimit(resource.RLIMIT_FSIZE, (size + cfg["slack"], hard))
    elif n == full // 2:
        env.flush()  # a user's flush() on the full disk (refused, unless it fits the slack)
    elif n == full:
        resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))  # space returns
    elif n == full + after:
        env.flush()
        _log(log, FLUSHED, n + cfg["arm"], os.fstat(fd).st_size)
        stream = env._stream
        _log(log, LOST, env._file.writer.lost[stream.channels.steps], 0)
        os.kill(os.getpid(), signal.SIGKILL)


def zygote() -> None:
    """Read one JSON plan per line; fork a recording child for each; report its pid and end."""
    import tempfile

    import gymnasium as gym

    from episode_audit import RecordEvidence

    # Warm up once before forking (lazy imports, first flush), like a long-running trainer.
    with tempfile.TemporaryDirectory() as tmp:
        with RecordEvidence(
            gym.make("CartPole-v1"), Path(tmp) / "warm.mcap", block_steps=16
        ) as env:
            env.reset(seed=0)
            for _ in range(100):
                if any(env.step(env.action_space.sample())[2:4]):
                    env.reset()
    for line in sys.stdin:
        cfg = json.loads(line)
        sys.stdout.flush()
        pid = os.fork()
        if pid == 0:
            try:
                _child(cfg)
            except BaseException:
                import traceback

                traceback.print_exc()
            finally:
                os._exit(4)
        print(pid, flush=True)
        _, status = os.waitpid(pid, 0)
        print(pid, status, flush=True)


# ----------------------------------------------------------------------------- parent side


@dataclass
class Plan:
    """One kill: how the child records and where it dies."""

    index: int
    mode: str
    block_steps: int
    flush_every_s: float
    seed: int
    arm: int  # step: the step to die after; flush: the step after which to arm; close: when
    write: int  # flush / close: which non-empty write dies (0 = the first)
    delay_s: float  # timer: when the parent kills
    full_steps: int = 0  # diskfull (from arm): steps while the disk is full
    after_steps: int = 0  # diskfull: steps after space returned, before the flush and the kill
    slack: int = 0  # diskfull: bytes the full disk still takes
    drop: bool = False  # diskfull: drop refused flushes (RETRY_LIMIT_BYTES 0), not retry them


def plans(kills: int, seed: int, scale: float = 1.0) -> list[Plan]:
    """``kills`` plans, cycling through the modes, with random sizes, intervals and moments.

    ``scale`` shortens the recordings (at most ``10_000 * scale`` steps, ``0.4 * scale`` s).
    """
    rng = random.Random(seed)
    return [
        Plan(
            index=i,
            mode=MODES[i % len(MODES)],
            block_steps=rng.choice([16, 256, 4096]),
            flush_every_s=rng.choice([0.01, 0.05, 0.2]),
            seed=rng.randrange(1 << 20),
            arm=rng.randint(1, max(1, int(10_000 * scale))),
            write=rng.randrange(2) if MODES[i % len(MODES)] == "flush" else rng.randrange(7),
            delay_s=rng.uniform(0.0, 0.4 * scale),
            full_steps=rng.randint(2, max(2, int(8_000 * scale))),
            after_steps=rng.randint(1, max(1, int(3_000 * scale))),
            slack=rng.choice([0, rng.randrange(4096)]),
            drop=i // len(MODES) % 2 == 1,
        )
        for i in range(kills)
    ]


@dataclass
class Verdict:
    """What one kill left, and what was wrong with it (``problems`` empty: all held)."""

    plan: Plan
    reported: int = 0  # steps the child reported
    in_file: int = 0  # step rows in the file
    flushed: int = 0  # steps of the flushes whose writing completed before the child died
    lost: int = 0  # reported steps not in the file
    oldest_lost_s: float = 0.0  # age of the oldest lost step at the child's last report
    closed: bool = False
    recover_lost: bool | None = None
    dropped_record: str | None = None  # what recover found cut off at the torn end
    problems: list[str] = field(default_factory=list)


def _records(log: Path) -> list[tuple[int, int, int, int]]:
    raw = log.read_bytes()
    return [_REC.unpack_from(raw, i) for i in range(0, len(raw) - _REC.size + 1, _REC.size)]


def judge_disk_full(plan: Plan, path: Path, log: Path, out: Path) -> Verdict:
    """Check what a ``diskfull`` run left: readable as it is, lost = dropped refused rows."""
    from episode_audit import check, open_evidence, recover
    from episode_audit.errors import EpisodeAuditError

    verdict = Verdict(plan)
    records = _records(log)
    flushed = [r for r in records if r[0] == FLUSHED]
    lost = [r[1] for r in records if r[0] == LOST]
    if not flushed or not lost:
        verdict.problems.append("the child did not reach its last flush")
        return verdict
    verdict.reported = verdict.flushed = flushed[0][1]
    verdict.lost = lost[0]
    try:
        checked = check([path])
        verdict.in_file = open_evidence(path).steps(columns=["episode"]).num_rows
    except EpisodeAuditError as exc:
        verdict.problems.append(f"unreadable: {exc}")
        return verdict
    if checked.steps != verdict.in_file:
        verdict.problems.append(f"check read {checked.steps} steps, the reader {verdict.in_file}")
    if verdict.in_file != verdict.reported - verdict.lost:
        verdict.problems.append(
            f"{verdict.in_file} steps in the file, {verdict.reported} recorded, "
            f"{verdict.lost} dropped"
        )
    if verdict.lost and not plan.drop:
        verdict.problems.append(f"{verdict.lost} steps dropped although held for a retry")
    # + the rows not yet flushed when the disk filled, and those of a flush whose write the
    # writer thread had not yet made (each at most a block): refused by the full disk too
    if verdict.lost > plan.full_steps + 2 * plan.block_steps:
        verdict.problems.append(f"{verdict.lost} steps dropped, {plan.full_steps} while full")
    try:
        recover(path, out)
        if open_evidence(out).steps(columns=["episode"]).num_rows != verdict.in_file:
            verdict.problems.append("the recovered file's steps differ")
    except EpisodeAuditError as exc:
        verdict.problems.append(f"recover failed: {exc}")
    return verdict


def judge(plan: Plan, path: Path, log: Path, out: Path) -> Verdict:
    """Check what one killed recording left (see the module docstring)."""
    import pyarrow.compute as pc

    from episode_audit import open_evidence, recover
    from episode_audit.errors import EpisodeAuditError

    if plan.mode == "diskfull":
        return judge_disk_full(plan, path, log, out)
    verdict = Verdict(plan)
    records = _records(log)
    probes = [r for r in records if r[0] in (STEP, ENDED, RESET)]
    verdict.closed = any(r[0] == CLOSED for r in records)
    if not probes:
        verdict.problems.append("the child reported nothing")
        return verdict
    _, last_n, last_t, _ = probes[-1]
    verdict.reported = last_n
    written = [r[1] for r in records if r[0] == WRITTEN]
    verdict.flushed = max(written, default=0)
    writing = sum(1 for r in records if r[0] == WRITING) > len(written)  # (when it died)
    try:
        ev = open_evidence(path)
        verdict.in_file = ev.steps(columns=["episode"]).num_rows
        episodes = ev.episodes()
    except EpisodeAuditError as exc:
        verdict.problems.append(f"unreadable: {exc}")
        return verdict
    if ev.finished != verdict.closed:
        verdict.problems.append(f"finished={ev.finished} but close() completed={verdict.closed}")
    if verdict.in_file < verdict.flushed:
        verdict.problems.append(f"{verdict.flushed - verdict.in_file} flushed steps missing")
    times = {r[1]: r[2] for r in probes if r[0] != RESET}
    lost = [n for n in times if verdict.in_file < n <= last_n]
    verdict.lost = len(lost)
    if lost:
        verdict.oldest_lost_s = (last_t - times[min(lost)]) / 1e9
        if verdict.oldest_lost_s > plan.flush_every_s + MARGIN:
            verdict.problems.append(
                f"lost a step {verdict.oldest_lost_s:.3f} s old (flush_every_s "
                f"{plan.flush_every_s} + margin {MARGIN})"
            )
    ended_steps = sum(1 for r in probes if r[0] == ENDED and r[1] <= verdict.in_file)
    has_record = episodes.filter(episodes["ended"])
    ended_in_file = has_record.filter(pc.not_equal(has_record["outcome"], "incomplete"))
    # A flush can complete inside the step the child died in (before it could report it).
    unreported = 1 if verdict.in_file > last_n else 0
    if not ended_steps <= ended_in_file.num_rows <= ended_steps + unreported:
        verdict.problems.append(
            f"{ended_in_file.num_rows} ended episodes in the file, {ended_steps} ended steps"
        )
    if episodes.num_rows - has_record.num_rows > 1:
        verdict.problems.append(f"{episodes.num_rows - has_record.num_rows} episodes cut off")
    if not (ev.finished or verdict.in_file or episodes.num_rows or ev.resets().num_rows):
        _judge_nothing_to_recover(verdict, path, out)  # (killed before its first flush)
        return verdict
    try:
        result = recover(path, out)
        fixed = open_evidence(out)
        verdict.recover_lost = result.lost
        verdict.dropped_record = result.dropped_record
        if not fixed.finished:
            verdict.problems.append("the recovered file is unfinished")
        if not fixed.episodes().equals(episodes):
            verdict.problems.append("the recovered file's episodes differ")
        if fixed.steps(columns=["episode"]).num_rows != verdict.in_file:
            verdict.problems.append("the recovered file's steps differ")
        cut = episodes.filter(pc.invert(episodes["ended"]))["episode"].to_pylist()
        if list(result.cut_off_episodes) != cut:
            verdict.problems.append(f"recover cut off {result.cut_off_episodes}, reader {cut}")
        between_calls = (plan.mode == "step" and not writing) or (
            plan.mode == "flush" and plan.write == 1
        )
        if between_calls and result.data_dropped:
            verdict.problems.append(f"recover dropped data after a clean cut: {result.dropped}")
        if plan.mode != "close" and not result.lost:
            verdict.problems.append(f"a kill mid-run recovered as nothing lost: {result.summary()}")
        if verdict.closed and (result.lost or not result.already_finished):
            verdict.problems.append(f"recover of a finished file: {result.summary()}")
    except EpisodeAuditError as exc:
        verdict.problems.append(f"recover failed: {exc}")
    return verdict


def _judge_nothing_to_recover(verdict: Verdict, path: Path, out: Path) -> None:
    """A torn file that holds no episode, reset or step: recover refuses it, writing nothing."""
    from episode_audit import recover
    from episode_audit.errors import EvidenceError

    try:
        result = recover(path, out)
    except EvidenceError as exc:
        if "nothing to recover" not in str(exc):
            verdict.problems.append(f"recover failed: {exc}")
    else:
        verdict.problems.append(f"recover copied a file that holds nothing: {result.summary()}")
    if out.exists():
        verdict.problems.append("recover wrote an output for a file that holds nothing")


def run(kills: int, directory: Path, seed: int = 2026, scale: float = 1.0) -> list[Verdict]:
    """Kill ``kills`` recordings (see the module docstring) and judge each."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    zyg = subprocess.Popen(
        [sys.executable, "-m", "tests.kill_harness", "--zygote"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=env,
    )
    assert zyg.stdin is not None and zyg.stdout is not None
    verdicts = []
    try:
        for plan in plans(kills, seed, scale):
            path = directory / f"kill-{plan.index}.mcap"
            log = directory / f"kill-{plan.index}.log"
            cfg = {**plan.__dict__, "path": str(path), "log": str(log)}
            relay = _Relay(log) if plan.mode == "diskfull" else None
            if relay is not None:
                cfg["log"] = str(relay.fifo)
            zyg.stdin.write(json.dumps(cfg) + "\n")
            zyg.stdin.flush()
            pid = int(zyg.stdout.readline())
            if plan.mode == "timer":
                deadline = time.monotonic() + 30
                while not (log.exists() and log.stat().st_size) and time.monotonic() < deadline:
                    time.sleep(0.001)  # the delay counts from the first reset
                time.sleep(plan.delay_s)
                os.kill(pid, signal.SIGKILL)
            _, status = map(int, zyg.stdout.readline().split())
            if relay is not None:
                relay.finish()
            verdict = judge(plan, path, log, directory / f"kill-{plan.index}.recovered.mcap")
            if not (os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL):
                verdict.problems.append(f"the child was not killed (wait status {status})")
            verdicts.append(verdict)
    finally:
        zyg.stdin.close()
        zyg.wait(timeout=30)
        zyg.stdout.close()
    return verdicts


class _Relay(threading.Thread):
    """Copies a child's progress log from a FIFO to ``log`` (a file size limit spares FIFOs)."""

    def __init__(self, log: Path) -> None:
        super().__init__(daemon=True)
        self.log = log
        self.fifo = log.with_suffix(".fifo")
        os.mkfifo(self.fifo)
        self.start()

    def run(self) -> None:
        with open(self.fifo, "rb") as src, open(self.log, "wb") as dst:
            while chunk := src.read(1 << 16):
                dst.write(chunk)

    def finish(self) -> None:
        """Wait for the copy (the child is dead: its end of the FIFO is closed)."""
        if self.is_alive():
            try:  # a child that died before opening its log: let the reader see an end
                os.close(os.open(self.fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        self.join(timeout=30)
        self.fifo.unlink()


def summary(verdicts: list[Verdict]) -> str:
    """The figures of a run, in one paragraph."""
    modes = Counter(v.plan.mode for v in verdicts)
    unreadable = sum(any(p.startswith("unreadable") for p in v.problems) for v in verdicts)
    missing = sum(max(0, v.flushed - v.in_file) for v in verdicts if v.plan.mode != "diskfull")
    late = sum(any(p.startswith("lost a step") for p in v.problems) for v in verdicts)
    killed = [v for v in verdicts if v.plan.mode != "diskfull"] or verdicts
    worst = max(killed, key=lambda v: v.oldest_lost_s - v.plan.flush_every_s)
    excess = worst.oldest_lost_s - worst.plan.flush_every_s
    problems = sum(bool(v.problems) for v in verdicts)
    exits = {
        m: Counter(int(bool(v.recover_lost)) for v in verdicts if v.plan.mode == m) for m in MODES
    }
    cut = Counter(v.dropped_record or "nothing" for v in verdicts if v.plan.mode != "diskfull")
    full = [v for v in verdicts if v.plan.mode == "diskfull"]
    held = [v for v in full if not v.plan.drop]
    dropping = [v for v in full if v.plan.drop]
    return (
        f"{len(verdicts)} kills ({', '.join(f'{m} {modes[m]}' for m in MODES)}), "
        f"{sum(v.closed for v in verdicts)} close() completed before the armed write: "
        f"{unreadable} unreadable files, {missing} flushed steps missing, "
        f"{late} kills lost a step older than flush_every_s + {MARGIN} s; "
        f"max steps lost {max(v.lost for v in killed)}, oldest lost step "
        f"{worst.oldest_lost_s:.3f} s at flush_every_s {worst.plan.flush_every_s} "
        f"(excess {excess:+.3f} s); torn ends: "
        f"{', '.join(f'{k} {n}' for k, n in sorted(cut.items()))}; recover exit 0/1 by mode: "
        f"{', '.join(f'{m} {exits[m][0]}/{exits[m][1]}' for m in MODES if m != 'diskfull')}; "
        f"disk full: {len(full)} runs ({len(held)} retrying refused flushes, steps lost "
        f"{sum(v.lost for v in held)}; {len(full) - len(held)} dropping them, steps lost "
        f"{sum(v.lost for v in dropping)} of {sum(v.reported for v in dropping)} recorded; "
        f"{sum(v.in_file for v in full)} steps read by check without recover); "
        f"{problems} kills with problems"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--zygote", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--kills", type=int, default=120)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--dir", type=Path, default=None)
    args = parser.parse_args()
    if args.zygote:
        zygote()
        return
    import tempfile

    directory = args.dir or Path(tempfile.mkdtemp(prefix="kill-harness-"))
    start = time.monotonic()
    verdicts = run(args.kills, directory, args.seed)
    print(summary(verdicts))
    for v in verdicts:
        if v.problems:
            print(f"kill {v.plan.index} ({v.plan}): {'; '.join(v.problems)}")
    print(f"{time.monotonic() - start:.1f} s, files in {directory}")


if __name__ == "__main__":
    main()
