"""--jobs and --ray: the same output, byte for byte, whatever runs the work.

A campaign directory of 200+ mixed evidence files (single-env, vector, PettingZoo, torn, one
unreadable) is checked, reported, replayed and exported with ``--jobs 1``, ``--jobs 2`` and
``--ray local`` (a Ray started in the test); the JSON and the exit code must not change.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import pickle
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordParallelEvidence, RecordVectorEvidence
from episode_audit._jobs import check_jobs, map_ordered, usable_cores
from episode_audit.cli import app
from episode_audit.errors import (
    ConfigurationError,
    CorruptEvidenceError,
    EvidenceError,
    WorkerError,
)

with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.classic import rps_v2

REPO = Path(__file__).resolve().parents[1]
FILES = 210
runner = CliRunner()


def _single(path: Path, seed: int) -> None:
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=15), path) as env:
        env.action_space.seed(seed)
        for e in range(2):
            env.reset(seed=seed * 10 + e)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated


def _vector(path: Path, seed: int) -> None:
    envs = gym.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path) as rec:
        rec.reset(seed=seed)
        for _ in range(30):
            rec.step(np.array([0, 1]))


def _rps(path: Path, seed: int) -> None:
    with RecordParallelEvidence(
        rps_v2.parallel_env(max_cycles=3), path, env_kwargs={"max_cycles": 3}
    ) as env:
        env.reset(seed=seed)
        while env.agents:
            env.step(dict.fromkeys(env.agents, 1))


@pytest.fixture(scope="session")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """210 files: copies of a few recorded ones of each kind, a torn one, an unreadable one."""
    made = tmp_path_factory.mktemp("made")
    templates = []
    for seed in range(3):
        for kind, record in (("single", _single), ("vector", _vector), ("rps", _rps)):
            path = made / f"{kind}-{seed}.mcap"
            record(path, seed)
            templates.append(path)
    templates += [REPO / "fixtures" / "torn.mcap", REPO / "fixtures" / "terms_mismatch.mcap"]
    out = tmp_path_factory.mktemp("campaign")
    for i in range(FILES - 1):
        template = templates[i % len(templates)]
        shutil.copyfile(template, out / f"{i:03d}-{template.stem}.mcap")
    (out / "150-unreadable.mcap").write_bytes(b"not an evidence file\n" * 10)
    return out


@pytest.fixture(scope="session")
def ray_local() -> Iterator[str]:
    """A Ray started for the tests (two CPUs), shut down after them.

    Its session folder holds its sockets, whose paths hold at most 107 bytes: under a long
    ``$TMPDIR`` (the session's, in a long basetemp) it is a short folder of ``/tmp`` instead,
    removed after.
    """
    ray = pytest.importorskip("ray")
    short = None
    if len(tempfile.gettempdir()) > _RAY_TEMP_LONGEST:
        short = tempfile.mkdtemp(prefix="ray-", dir="/tmp")
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        configure_logging=False,
        _temp_dir=short,
    )
    yield "local"
    ray.shutdown()
    if short is not None:
        shutil.rmtree(short, ignore_errors=True)


_RAY_TEMP_LONGEST = 39
"""The longest ``$TMPDIR`` Ray's session folder goes in: its sockets' paths add up to 68 bytes."""


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


@pytest.mark.parametrize("command", ["check", "report", "replay"])
def test_jobs_and_ray_give_the_same_json_and_exit_code(
    campaign: Path, ray_local: str, command: str
) -> None:
    assert len(list(campaign.glob("*.mcap"))) >= 200
    code, one, err = run(command, str(campaign), "-f", "json", "--jobs", "1")
    assert code == 2, err  # the unreadable file
    assert "150-unreadable.mcap" in err and '"150-unreadable.mcap' not in one[:0]
    for options in (["--jobs", "2"], ["--ray", ray_local]):
        got_code, got, got_err = run(command, str(campaign), "-f", "json", *options)
        assert (got_code, got) == (code, one), options
        assert got_err == err, options


@pytest.fixture(scope="module")
def reference_sides(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The drawer task's evidence: a scripted baseline and a reward-hacking candidate, six
    files of four episodes a side (the candidate's files on other seeds but two), and an
    unreadable file among the candidate's."""
    from episode_audit.rollout import record_episodes
    from episode_audit.tasks import DRAWER_OPEN_ID

    out = tmp_path_factory.mktemp("sides")
    for side, policy in (("base", "scripted"), ("cand", "hacker")):
        (out / side).mkdir()
        for i in range(6):
            seed = 40 * i + (1000 if side == "cand" and i > 1 else 0)
            record_episodes(
                DRAWER_OPEN_ID, out / side / f"{i}.mcap", policy=policy, episodes=4, seed=seed,
                env_kwargs={"proxy_reward": True},
            )  # fmt: skip
    (out / "cand" / "3-unreadable.mcap").write_bytes(b"not an evidence file\n" * 10)
    return out / "base", out / "cand"


@pytest.mark.mujoco
@pytest.mark.parametrize("by", ["all", "env"])
def test_compare_gives_the_same_json_and_exit_code_with_jobs_and_ray(
    reference_sides: tuple[Path, Path], ray_local: str, by: str
) -> None:
    base, cand = map(str, reference_sides)
    args = ["compare", base, "--candidate", cand, "--by", by, "-f", "json"]
    code, one, err = run(*args, "--jobs", "1")
    assert code == 2 and "3-unreadable.mcap" in err  # compared, and the unreadable file named
    assert json.loads(one)["verdict"] == "regressed"
    for options in (["--jobs", "2"], ["--jobs", "3"], ["--ray", ray_local]):
        assert run(*args, *options) == (code, one, err), options


def test_export_writes_the_same_files_with_jobs(campaign: Path, tmp_path: Path) -> None:
    outs = []
    for jobs in ("1", "2"):
        out = tmp_path / f"out{jobs}"
        code, stdout, _ = run("export", str(campaign), "--out", str(out), "--jobs", jobs)
        assert code == 2, stdout  # the unreadable file; the others exported
        outs.append(out)
    names = sorted(p.name for p in outs[0].iterdir())
    assert len(names) == FILES and names == sorted(p.name for p in outs[1].iterdir())
    for name in names:
        assert pq.read_table(outs[0] / name).equals(pq.read_table(outs[1] / name)), name


def test_replay_splits_a_large_file_into_batches_with_the_same_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "many.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=10), path) as env:
        for e in range(12):
            env.reset(seed=e)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(e % 2)
                done = terminated or truncated
    from episode_audit.replay import run as replay_run

    assert len(replay_run._batches([path], None, None, 2)[0]) == 1  # small: one batch
    monkeypatch.setattr(replay_run, "MIN_BATCH_BYTES", path.stat().st_size // 4)
    batches, costs = replay_run._batches([path], None, None, 2)
    assert [b[2] for b in batches] == [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]]
    assert sum(costs) == pytest.approx(path.stat().st_size)
    code, one, _ = run("replay", str(path), "-f", "json", "--jobs", "1")
    assert code == 0
    assert run("replay", str(path), "-f", "json", "--jobs", "2")[:2] == (code, one)


def test_an_unreachable_ray_cluster_is_one_line_and_exit_2(campaign: Path) -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    start = time.monotonic()
    code, out, err = run("check", str(campaign), "--ray", f"ray://127.0.0.1:{port}")
    assert time.monotonic() - start < 30
    assert code == 2 and out == ""
    assert err.splitlines() == [
        f"episode-audit: error: --ray ray://127.0.0.1:{port}: cannot reach the Ray cluster "
        "(Connection refused after at most 10 s): is it running, and is the address right?"
    ]
    code, _, err = run("check", str(campaign), "--ray", "runs/")
    assert code == 2 and "expected local, auto, ray://HOST:PORT or HOST:PORT" in err


def test_a_local_ray_under_a_long_tmpdir_is_one_line_and_exit_2(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    long = tmp_path / ("t" * 80)  # Ray's socket paths there: over 107 bytes
    long.mkdir()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "episode_audit",
            "check",
            str(REPO / "fixtures" / "clean.mcap"),
            "--ray",
            "local",
        ],
        env={**os.environ, "TMPDIR": str(long)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [
        f"episode-audit: error: --ray local: Ray's socket paths under TMPDIR ({long}) would be "
        "over the 107 bytes a socket path holds: set TMPDIR to a shorter folder (e.g. TMPDIR=/tmp)"
    ]


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:  # gone
        return []


def _wait_for_a_worker(pid: int, timeout: float = 120) -> int:
    """A worker of ``pid``: a process its fork server (a child of ``pid``) forked."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for child in _children(pid):
            if _children(child):
                return _children(child)[0]
        time.sleep(0.2)
    raise AssertionError(f"no worker after {timeout} s")


def _gone(pid: int, timeout: float = 30) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except FileNotFoundError:
            return True
        if state == "Z":
            return True
        time.sleep(0.2)
    return False


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _slow_replay(campaign: Path, **popen: Any) -> subprocess.Popen[Any]:
    """``episode-audit replay CAMPAIGN --jobs 2`` of slow CartPoles, in a session of its own."""
    env = {**os.environ, "PYTHONPATH": str(REPO), **popen.pop("env", {})}
    factory = "tests.support.factories:slow_cartpole"
    cmd = [sys.executable, "-m", "episode_audit", "replay", str(campaign), "--jobs", "2"]
    return subprocess.Popen(
        [*cmd, "--env-factory", factory], cwd=REPO, env=env, start_new_session=True, **popen
    )


def test_ctrl_c_stops_the_workers_and_exits_130(campaign: Path) -> None:
    proc = _slow_replay(
        campaign,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # as from a shell: Ctrl-C not ignored (pytest-xdist's workers ignore it, and an ignored
        # signal stays ignored in the programs they start)
        preexec_fn=_default_sigint,
    )
    worker = _wait_for_a_worker(proc.pid)  # and then mid-replay (200 files x 0.5 s builds)
    time.sleep(3)
    assert proc.poll() is None
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and out == ""
    assert err.splitlines()[-1] == "episode-audit: error: interrupted (Ctrl-C): stopped"
    assert _gone(worker)


def test_sigterm_stops_the_workers_exits_143_and_leaves_no_temporary_files(
    campaign: Path, tmp_path: Path
) -> None:
    # a CI job's timeout, `timeout`, `docker stop`: SIGTERM to the command alone. Python's
    # default ended it at once: its worker waited for work forever (holding the fork server
    # up, and the command's stderr open) and multiprocessing's folder (pymp-*) stayed behind
    # (a short path: the fork server's socket, pymp-*/listener-*, must fit in 107 bytes)
    temp = Path(tempfile.mkdtemp(prefix="t"))
    with (tmp_path / "out").open("w+") as out, (tmp_path / "err").open("w+") as err:
        proc = _slow_replay(campaign, env={"TMPDIR": str(temp)}, stdout=out, stderr=err)
        try:
            worker = _wait_for_a_worker(proc.pid)
            time.sleep(3)
            assert proc.poll() is None
            proc.terminate()
            proc.wait(timeout=60)
            stopped = _gone(worker)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)  # whatever is left of it
            proc.wait()
    said = (tmp_path / "err").read_text()
    assert proc.returncode == 143, said
    assert "Traceback" not in said and (tmp_path / "out").read_text() == ""
    assert said.splitlines()[-1] == "episode-audit: error: terminated (SIGTERM): stopped"
    assert stopped
    left = sorted(p.name for p in temp.iterdir())
    shutil.rmtree(temp)
    assert left == []


def test_a_sigkilled_command_s_workers_end_too(campaign: Path, tmp_path: Path) -> None:
    # SIGKILL (a CI runner's last resort, the OOM killer) lets the command do nothing: its
    # worker, forked from the fork server, waited for work forever (the command's stderr held
    # open: a caller reading it hung). A worker now ends once the command is gone. (What the
    # command could not remove, killed, goes with its own TMPDIR: multiprocessing's folder.)
    temp = Path(tempfile.mkdtemp(prefix="t"))
    env = {"TMPDIR": str(temp)}
    proc = _slow_replay(campaign, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        worker = _wait_for_a_worker(proc.pid)
        time.sleep(1)
        proc.kill()
        proc.wait()  # (reaped: its pid is gone)
        assert _gone(worker, timeout=20)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # whatever is left of it
        shutil.rmtree(temp, ignore_errors=True)


def _long_temp(tmp_path: Path) -> Path:
    """A temporary directory whose path leaves no room for the fork server's socket."""
    temp = tmp_path / ("t" * 80)
    temp.mkdir()
    return temp


def test_a_temporary_directory_too_long_for_the_workers_socket_is_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the fork server's socket is <temp>/pymp-XXXXXXXX/listener-XXXXXXXX, an AF_UNIX path at
    # most 107 bytes: it could not start, and the error blamed a worker killed or out of memory
    temp = _long_temp(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    said = (
        r"jobs > 1: the temporary directory .*t{80} is too long a path for the workers' socket "
        r"\(\d+ bytes; at most \d+\): set TMPDIR to a shorter folder, or run with jobs=1 "
        r"\(--jobs 1\)$"
    )
    with pytest.raises(ConfigurationError, match=said):
        list(map_ordered(_double_or_fail, [1, 2], jobs=2))


def test_the_command_says_so_in_one_line_and_exits_2(campaign: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO), "TMPDIR": str(_long_temp(tmp_path))}
    cmd = [sys.executable, "-m", "episode_audit", "check", str(campaign), "--jobs", "2"]
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr  # was a traceback, and exit 1 (findings)
    assert done.stderr.splitlines()[-1].startswith(
        "episode-audit: error: jobs > 1: the temporary directory /"
    )
    assert "Traceback" not in done.stderr


_SLOW_PANDAS = """
import importlib.abc, os, sys, time

class SlowPandas(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "pandas":
            open(os.environ["EPISODE_AUDIT_TEST_MARK"], "w").close()
            time.sleep(3)
        return None

sys.meta_path.insert(0, SlowPandas())
"""


def test_ctrl_c_while_pyarrow_imports_pandas_is_not_lost(campaign: Path, tmp_path: Path) -> None:
    # pyarrow imports pandas on its first conversion of a column, and loses a Ctrl-C that
    # comes meanwhile (the command then ran to its end); here that import takes 3 s
    (tmp_path / "sitecustomize.py").write_text(_SLOW_PANDAS)
    mark = tmp_path / "importing-pandas"
    env = {
        **os.environ,
        "PYTHONPATH": f"{REPO}{os.pathsep}{tmp_path}",
        "EPISODE_AUDIT_TEST_MARK": str(mark),
    }
    cmd = [sys.executable, "-m", "episode_audit", "replay", str(campaign), "--jobs", "1"]
    proc = subprocess.Popen(
        cmd,
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_default_sigint,
    )
    deadline = time.monotonic() + 60
    while not mark.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert mark.exists(), proc.communicate()[1]
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and out == ""
    assert err.splitlines()[-1] == "episode-audit: error: interrupted (Ctrl-C): stopped"


def test_evidence_errors_come_back_from_a_worker_as_raised() -> None:
    exc = CorruptEvidenceError("run.mcap", "x" * 5000)
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is CorruptEvidenceError
    assert (str(back), back.path, back.problem) == (str(exc), exc.path, exc.problem)


def _double_or_fail(item: int, progress: object) -> int:
    if item == 3:
        raise EvidenceError("three.mcap", "cannot be read")
    return item * 2


def test_map_ordered_keeps_the_order_and_raises_at_the_failing_item() -> None:
    assert list(map_ordered(_double_or_fail, range(4, 100), jobs=2)) == list(range(8, 200, 2))
    got = map_ordered(_double_or_fail, range(1, 41), jobs=2)  # 40 items in runs of 2
    assert [next(got), next(got)] == [2, 4]
    with pytest.raises(EvidenceError, match=r"three\.mcap: cannot be read"):
        next(got)


def _die_in_a_worker(item: int, progress: object) -> int:
    if _MARK == "as imported":  # (a worker: this process set the mark)
        os._exit(3)  # as a crash in native code, or the OOM killer
    time.sleep(0.05)  # (this process is slow: the worker takes its first run)
    return item


def test_a_worker_that_dies_is_a_worker_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys.modules[__name__], "_MARK", "set in this process")
    with pytest.raises(
        WorkerError, match=r"a worker process ended .* run again with jobs=1 \(--jobs 1\) to see"
    ):
        list(map_ordered(_die_in_a_worker, range(20), jobs=2))
    assert list(map_ordered(_die_in_a_worker, range(20), jobs=1)) == list(range(20))


def dying_cartpole() -> gym.Env[Any, Any]:
    """CartPole whose step ends the process when it is a worker (as the OOM killer would).

    Its spec is CartPole's as recorded (no wrapper says what its step does).
    """
    env = gym.make("CartPole-v1")
    cartpole: Any = env.unwrapped
    step = cartpole.step

    def dying(action: Any) -> Any:
        if _MARK == "as imported":  # (a worker: this process set the mark)
            os._exit(3)
        time.sleep(0.3)  # (this process is slow: a worker takes a batch)
        return step(action)

    cartpole.step = dying
    return env


def test_replay_whose_worker_dies_says_so_in_one_line_and_exits_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from episode_audit.replay import run as replay_run

    monkeypatch.setattr(sys.modules[__name__], "_MARK", "set in this process")
    monkeypatch.setattr(replay_run, "MIN_BATCH_BYTES", 1)  # (a batch per file: to the workers)
    paths = [tmp_path / f"c{i}.mcap" for i in range(8)]
    for path in paths:
        with RecordEvidence(gym.make("CartPole-v1"), path) as env:
            env.reset(seed=0)
            env.step(0)
    factory = f"{__name__}:dying_cartpole"
    args = ["replay", *map(str, paths), "--jobs", "2", "--env-factory", factory]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert result.stderr.startswith("episode-audit: error: a worker process ended before")
    assert len(result.stderr.splitlines()) == 1


def test_a_ray_task_whose_worker_dies_is_a_worker_error(
    monkeypatch: pytest.MonkeyPatch, ray_local: str, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(sys.modules[__name__], "_MARK", "set in this process")
    with pytest.raises(
        WorkerError,
        match=r"a Ray task ended .* \(WorkerCrashedError: .* run again with jobs=1 \(--jobs 1\)",
    ):
        list(map_ordered(_die_in_a_worker, range(8), ray_address=ray_local))
    gc.collect()  # (Ray logs an error nobody took when its reference goes, from a thread)
    time.sleep(1.0)
    assert "Unhandled error" not in caplog.text  # (the other tasks' errors: taken)
    assert list(map_ordered(_square, range(4), ray_address=ray_local)) == [0, 1, 4, 9]


def _square(item: int, progress: object) -> int:
    return item * item


def test_overlapping_jobs_calls_leave_the_threads_excepthook_as_it_was(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import threading

    from episode_audit._jobs import _MANAGER_NOISE

    original = threading.excepthook
    first = _MANAGER_NOISE.hidden(stopping=False)
    second = _MANAGER_NOISE.hidden(stopping=True)
    first.__enter__()
    second.__enter__()
    first.__exit__(None, None, None)  # (not in the order they began: as from two threads)
    assert threading.excepthook is not original  # (the second still hides the noise)
    second.__exit__(None, None, None)
    assert threading.excepthook is original
    # two calls whose workers die, at once from two threads: each a WorkerError, no hook left
    monkeypatch.setattr(sys.modules[__name__], "_MARK", "set in this process")
    errors: list[BaseException] = []

    def call() -> None:
        try:
            list(map_ordered(_die_in_a_worker, range(20), jobs=2))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=call) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert [type(e) for e in errors] == [WorkerError, WorkerError]
    assert threading.excepthook is original


_UNGUARDED = """
import sys
from episode_audit import WorkerError, check
try:
    check(sys.argv[1:], jobs=2)
except WorkerError as exc:
    print("WorkerError:", exc)
"""


def test_a_script_asking_for_jobs_without_a_main_guard_is_told_what_to_do(
    campaign: Path, tmp_path: Path
) -> None:
    script = tmp_path / "unguarded.py"
    script.write_text(_UNGUARDED)
    files = [str(p) for p in sorted(campaign.glob("*.mcap"))[:3]]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    run = subprocess.run(
        [sys.executable, str(script), *files], env=env, capture_output=True, text=True, timeout=120
    )
    assert run.stdout.startswith("WorkerError: a worker process ended"), run.stderr
    assert 'make the call under `if __name__ == "__main__":`' in run.stderr  # the worker's
    assert "BrokenProcessPool" not in run.stderr and "leaked" not in run.stderr


_NO_INTERPRETER = """
import multiprocessing, sys
multiprocessing.set_executable(sys.argv[1])  # (a host whose interpreter cannot be executed)
if __name__ == "__main__":
    from episode_audit.cli import main
    sys.argv[1:2] = []
    main()
"""


def _not_executable(tmp_path: Path) -> Path:
    """A script that runs the command where a worker's interpreter cannot be executed, and
    that interpreter (a file without the execute bit: as under seccomp or a ``noexec``
    mount)."""
    (tmp_path / "no_interpreter.py").write_text(_NO_INTERPRETER)
    interpreter = tmp_path / "not-executable"
    interpreter.write_text("not a program\n")
    return interpreter


_NOT_STARTED = (
    r"episode-audit: warning: worker processes could not be started \({}\): the work runs in "
    r"this process alone \(jobs=1 \(--jobs 1\) does so without this warning\)$"
)


def test_workers_that_cannot_be_started_leave_the_work_to_this_process(
    campaign: Path, tmp_path: Path
) -> None:
    # the fork server and the resource tracker never ran: a broken pipe or a refused
    # connection, as it fell, was exit 1 and nothing said, or exit 2, no results and tracebacks
    interpreter = _not_executable(tmp_path)
    code, one, err = run("check", str(campaign), "-f", "json", "--jobs", "1")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    script = [sys.executable, str(tmp_path / "no_interpreter.py"), str(interpreter)]
    done = subprocess.run(
        [*script, "check", str(campaign), "-f", "json", "--jobs", "2"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert (done.returncode, done.stdout) == (code, one), done.stderr
    first, *rest = done.stderr.splitlines()
    assert re.match(_NOT_STARTED.format(f"cannot execute {interpreter}: Permission denied"), first)
    assert rest == err.splitlines()  # (the unreadable file's line)


_LIBRARY_NOT_STARTED = """
import multiprocessing, sys, warnings
multiprocessing.set_executable(sys.argv[1])
from episode_audit._jobs import map_ordered

def double(item, progress):
    progress(1)
    return 2 * item

if __name__ == "__main__":
    told = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        done = list(map_ordered(double, range(50), jobs=2, progress=told.append))
    print(done == [2 * i for i in range(50)], sum(told))
    print(*(f"{w.category.__name__}: {w.message}" for w in caught), sep="\\n")
"""


def test_the_library_warns_and_does_the_work_itself_when_workers_cannot_be_started(
    tmp_path: Path,
) -> None:
    interpreter = _not_executable(tmp_path)
    (tmp_path / "library.py").write_text(_LIBRARY_NOT_STARTED)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, str(tmp_path / "library.py"), str(interpreter)],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = done.stdout.splitlines()
    assert out[0] == "True 50"  # every item, in order; every step told once
    assert out[1:] == [
        f"WorkerWarning: worker processes could not be started (cannot execute {interpreter}: "
        "Permission denied): the work runs in this process alone (jobs=1 (--jobs 1) does so "
        "without this warning)"
    ]
    assert "Traceback" not in done.stderr and "resource_tracker" not in done.stderr


_NO_DEV_SHM = {
    # where POSIX semaphores go on Linux: read-only, as in some containers and AWS Lambda
    "read-only": "mount -t tmpfs -o ro tmpfs /dev/shm",
    # or not there at all (a /dev of its own holding only the devices a command needs)
    "missing": (
        "mkdir -p {tmp}/dev && mount --bind /dev {tmp}/dev && mount -t tmpfs tmpfs /dev && "
        "for n in null zero random urandom; do touch /dev/$n && mount --bind {tmp}/dev/$n "
        "/dev/$n || exit 1; done && ln -s /proc/self/fd /dev/fd"
    ),
}


def _no_dev_shm(how: str, command: list[str], tmp: Path) -> list[str]:
    """``command`` where ``/dev/shm`` is ``how`` (read-only or missing: a mount namespace of
    its own); skips the test where one cannot be made here."""
    unshare = shutil.which("unshare")
    if unshare is None or sys.platform != "linux":
        pytest.skip("needs Linux's unshare(1) to mount a read-only /dev/shm")
    user = [] if os.geteuid() == 0 else ["--map-root-user"]
    mount = _NO_DEV_SHM[how].format(tmp=tmp)
    tried = subprocess.run(
        [unshare, *user, "--mount", "sh", "-c", f"{mount} && touch /dev/shm/x"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    said = {"read-only": "Read-only file system", "missing": "No such file or directory"}[how]
    if said not in tried.stderr:
        pytest.skip(f"cannot make a {how} /dev/shm here: {tried.stderr.strip()[:200]}")
    return [unshare, *user, "--mount", "sh", "-c", f'{mount} && exec "$@"', "sh", *command]


@pytest.mark.parametrize(
    ("how", "said"),
    [("read-only", "Read-only file system"), ("missing", "No such file or directory")],
)
def test_without_a_writable_dev_shm_the_work_is_left_to_this_process(
    how: str, said: str, campaign: Path, tmp_path: Path
) -> None:
    # multiprocessing's queues need semaphores in /dev/shm: the pool could not be made, and
    # the command said only "Read-only file system", with no results; then that without
    # naming /dev/shm, which is what to fix
    code, one, err = run("report", str(campaign), "-f", "json", "--jobs", "1")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "episode_audit", "report", str(campaign), "-f", "json"]
    done = subprocess.run(
        _no_dev_shm(how, [*command, "--jobs", "2"], tmp_path),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert (done.returncode, done.stdout) == (code, one), done.stderr
    first, *rest = done.stderr.splitlines()
    cause = (
        f"creating their queues: /dev/shm: {said}: their semaphores need a writable /dev/shm "
        "(mount a tmpfs there)"
    )
    assert re.match(_NOT_STARTED.format(re.escape(cause)), first), first
    assert rest == err.splitlines()


def test_runs_go_costliest_first_and_a_large_item_alone() -> None:
    from episode_audit._jobs import _chunks

    costs = [1.0] * 30 + [50.0] + [1.0] * 19  # one large item among small ones
    runs = _chunks(costs, 2)  # a run: about 100 / 16 of the cost
    assert runs[0] == [30]
    assert sorted(i for run in runs for i in run) == list(range(50))
    assert all(sum(costs[i] for i in run) <= 100 / 16 for run in runs[1:])
    assert [run[0] for run in runs[1:]] == sorted(run[0] for run in runs[1:])  # ties: in order


def test_the_last_runs_are_small_so_the_processes_end_together() -> None:
    from episode_audit._jobs import _chunks

    costs = [1.0] * 1000
    runs = _chunks(costs, 2)
    assert len(runs[0]) == 1000 // 16  # the first: 1 / (8 * processes) of the whole
    assert [len(run) for run in runs] == sorted((len(run) for run in runs), reverse=True)
    assert all(len(run) <= 1000 // 64 for run in runs[-4:])  # a worker holds up to three at the end


def test_this_process_takes_the_runs_no_worker_started_in_their_order() -> None:
    """As the workers do, so that all end on the smallest runs (the last), together."""
    from concurrent.futures import Future

    from episode_audit._jobs import _gather

    order: list[int] = []

    def work(item: int, progress: object) -> int:
        order.append(item)
        return item

    runs = [[0, 1], [2, 3], [4, 5]]  # costliest first, as _chunks makes them
    futures: dict[int, Future[Any]] = {k: Future() for k in range(3)}  # no worker took any
    assert list(_gather(work, list(range(6)), runs, futures, None, {})) == list(range(6))
    assert order == [0, 1, 2, 3, 4, 5]  # (taken from the back: 4, 5, 2, 3, 0, 1)


_MARK = "as imported"


def _where(item: int, progress: object) -> tuple[int, int, str]:
    time.sleep(0.02)
    return item, os.getpid(), _MARK


def test_this_process_works_too_and_workers_inherit_nothing_of_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(sys.modules[__name__], "_MARK", "set in this process")
    done = list(map_ordered(_where, range(200), jobs=2))
    assert [item for item, _, _ in done] == list(range(200))
    by = {pid: mark for _, pid, mark in done}
    assert len(by) == 2 and by.pop(os.getpid()) == "set in this process"
    assert list(by.values()) == ["as imported"]  # a fresh worker: not a fork of this process


def _environ(item: int, progress: object) -> str | None:
    time.sleep(0.02)
    return os.environ.get("EPISODE_AUDIT_TEST_MARK")


def test_workers_see_the_environment_as_it_is_now(monkeypatch: pytest.MonkeyPatch) -> None:
    list(map_ordered(_environ, range(10), jobs=2))  # the fork server is up: its env is older
    monkeypatch.setenv("EPISODE_AUDIT_TEST_MARK", "set since")  # as credentials may be
    assert set(map_ordered(_environ, range(100), jobs=2)) == {"set since"}


def _steps(item: int, progress: Callable[[int], None] | None) -> int:
    assert progress is not None
    progress(item)
    return item


def test_progress_counts_every_step_once_whoever_does_the_work() -> None:
    told: list[int] = []
    assert list(map_ordered(_steps, range(100), jobs=2, progress=told.append)) == list(range(100))
    assert sum(told) == sum(range(100))


def test_jobs_must_be_a_positive_number() -> None:
    assert check_jobs(None) == usable_cores() >= 1
    with pytest.raises(ConfigurationError, match="jobs: expected a number of processes >= 1"):
        check_jobs(0)


def test_small_inputs_stay_in_this_process_unless_jobs_is_given(tmp_path: Path) -> None:
    from episode_audit.cli._app import SMALL_INPUTS, jobs_for

    small, large = tmp_path / "small.mcap", tmp_path / "large.mcap"
    small.write_bytes(b"x" * 100)
    with large.open("wb") as f:  # sparse: its size without writing it
        f.truncate(SMALL_INPUTS)
    assert jobs_for(None, [small]) == 1
    assert jobs_for(None, [small, large]) is None  # every usable core
    assert jobs_for(3, [small]) == 3


def test_report_and_compare_read_in_this_process_below_their_own_size(tmp_path: Path) -> None:
    from episode_audit.cli._app import SMALL_INPUTS, SMALL_TABLES, listed_jobs, lister

    (tmp_path / "medium.mcap").touch()
    os.truncate(tmp_path / "medium.mcap", SMALL_INPUTS * 4)  # (sparse)
    assert listed_jobs(None, lister([str(tmp_path)])) == 1
    (tmp_path / "large.mcap").touch()
    os.truncate(tmp_path / "large.mcap", SMALL_TABLES)
    assert listed_jobs(None, lister([str(tmp_path)])) is None
    assert listed_jobs(2, lister([str(tmp_path / "nothing-here")])) == 2


def test_the_library_report_takes_jobs(campaign: Path) -> None:
    from episode_audit.report import report

    # (one copy of each recorded file: copies of one run would count its episodes twice)
    files = sorted(p for p in campaign.glob("*.mcap") if "unreadable" not in p.name)[:11]
    assert report(files, by="env", jobs=2).to_dict() == report(files, by="env").to_dict()


_STARTING = """
import json, os, time
from episode_audit._jobs import map_ordered

def stamp(item, progress):
    start = time.monotonic()
    time.sleep(0.02)
    return os.getpid(), start, time.monotonic()

if __name__ == "__main__":
    done = list(map_ordered(stamp, range(300), jobs=2))
    print(json.dumps({"me": os.getpid(), "done": done}))
"""


def test_this_process_works_while_the_first_worker_starts(tmp_path: Path) -> None:
    # a fresh process: its fork server imports episode-audit before the first worker exists
    script = tmp_path / "starting.py"
    script.write_text(_STARTING)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    run = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    here = [end for pid, _, end in out["done"] if pid == out["me"]]
    there = [start for pid, start, _ in out["done"] if pid != out["me"]]
    assert here and there, "both processes take part"
    assert sum(end < min(there) for end in here) >= 3  # done here before the worker began
