"""--jobs and --ray: the same output, byte for byte, whatever runs the work.

A campaign directory of 200+ mixed evidence files (single-env, vector, PettingZoo, torn, one
unreadable) is checked, reported, replayed and exported with ``--jobs 1``, ``--jobs 2`` and
``--ray local`` (a Ray started in the test); the JSON and the exit code must not change.
"""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, RecordParallelEvidence, RecordVectorEvidence
from episode_audit._jobs import check_jobs, map_ordered, usable_cores
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError, CorruptEvidenceError, EvidenceError

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
    """A Ray started for the tests (two CPUs), shut down after them."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield "local"
    ray.shutdown()


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


def test_replay_splits_a_large_file_into_batches_with_the_same_result(tmp_path: Path) -> None:
    path = tmp_path / "many.mcap"
    with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=10), path) as env:
        for e in range(12):
            env.reset(seed=e)
            done = False
            while not done:
                *_, terminated, truncated, _ = env.step(e % 2)
                done = terminated or truncated
    from episode_audit.replay.run import _batches

    assert len(_batches([path], None, None, 2)) == 4  # 12 episodes in 4 batches of 3
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


def _wait_for_workers(pid: int, workers: int, timeout: float = 120) -> None:
    """Until ``pid`` has started ``workers`` worker processes (besides its resource tracker)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        if len(children) > workers:
            return
        time.sleep(0.2)
    raise AssertionError(f"no {workers} workers after {timeout} s")


def test_ctrl_c_stops_the_workers_and_exits_130(campaign: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    factory = "tests.support.factories:slow_cartpole"
    cmd = [sys.executable, "-m", "episode_audit", "replay", str(campaign), "--jobs", "2"]
    proc = subprocess.Popen(
        [*cmd, "--env-factory", factory],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    _wait_for_workers(proc.pid, 2)  # and then mid-replay (200 files x 0.5 s builds)
    time.sleep(3)
    assert proc.poll() is None
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
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


def test_the_library_report_takes_jobs(campaign: Path) -> None:
    from episode_audit.report import report

    files = sorted(p for p in campaign.glob("*.mcap") if "unreadable" not in p.name)[:40]
    assert report(files, by="env", jobs=2).to_dict() == report(files, by="env").to_dict()
