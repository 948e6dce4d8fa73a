"""One writer per file (the writer's lock) and path templates: record/lock.py."""

from __future__ import annotations

import copy
import multiprocessing
import os
import pickle
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium as gym
import pytest

import episode_audit.record.lock as lock_module
from episode_audit import RecordEvidence, RecordVectorEvidence, check, open_evidence, recover
from episode_audit.errors import ConfigurationError, RecorderError, RecorderTroubleWarning
from episode_audit.read.liveness import writer_of
from episode_audit.record.lock import PathTemplate
from episode_audit.rollout import record_episodes

REPO = Path(__file__).resolve().parents[2]
HERE = f"this process \\(pid {os.getpid()}\\)"


def _held(path: Path, who: str) -> str:
    return f"^{re.escape(str(path))}: another live recorder is writing this file \\({who} holds"


def _record(env: RecordEvidence, steps: int = 5) -> None:
    env.reset(seed=0)
    for _ in range(steps):
        env.step(0)


def python(script: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", script, *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        cwd=REPO,
    )


# Records a few steps, flushes, says "ready" and waits for a line on stdin; then closes.
HOLDER = """
import sys
import gymnasium as gym
from episode_audit import RecordEvidence

env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1], flush_every_s=3600)
env.reset(seed=0)
for _ in range(5):
    env.step(0)
env.flush()
print(env.path, flush=True)
sys.stdin.readline()
env.close()
"""


# ------------------------------------------------------------------ one writer per file


@pytest.mark.parametrize("overwrite", [False, True])
def test_every_recorder_refuses_a_path_a_live_recorder_holds(
    tmp_path: Path, overwrite: bool
) -> None:
    path = tmp_path / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as first:
        _record(first)
        first.flush()
        size = path.stat().st_size
        held = _held(path, HERE)
        with pytest.raises(ConfigurationError, match=held):
            RecordEvidence(gym.make("CartPole-v1"), path, overwrite=overwrite)
        vector = gym.make_vec("CartPole-v1", num_envs=2, vectorization_mode="sync")
        with pytest.raises(ConfigurationError, match=held):
            RecordVectorEvidence(vector, path, overwrite=overwrite)
        vector.close()
        with pytest.raises(ConfigurationError, match=held):
            record_episodes("CartPole-v1", path, episodes=1, overwrite=overwrite)
        with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules
            warnings.simplefilter("ignore", DeprecationWarning)
            from pettingzoo.classic import rps_v2

        from episode_audit.record.pettingzoo import RecordAECEvidence, RecordParallelEvidence

        with pytest.raises(ConfigurationError, match=held):
            RecordAECEvidence(rps_v2.env(), path, overwrite=overwrite)
        with pytest.raises(ConfigurationError, match=held):
            RecordParallelEvidence(rps_v2.parallel_env(), path, overwrite=overwrite)
        assert path.stat().st_size == size  # not a byte written, nothing truncated
        first.step(0)
    ev = open_evidence(path)
    assert ev.finished and ev.steps().num_rows == 6
    assert check([path]).ok


def test_another_process_is_refused_with_the_holder_s_pid(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    child = python(HOLDER, str(path))
    assert child.stdout is not None and child.stdin is not None
    try:
        assert child.stdout.readline().strip() == str(path)
        size = path.stat().st_size
        for overwrite in (False, True):
            with pytest.raises(ConfigurationError, match=_held(path, f"pid {child.pid}")):
                RecordEvidence(gym.make("CartPole-v1"), path, overwrite=overwrite)
        assert path.stat().st_size == size
        child.stdin.write("close\n")
        child.stdin.flush()
        assert child.wait(timeout=60) == 0
    finally:
        if child.poll() is None:
            child.kill()
        child.communicate(timeout=60)
    ev = open_evidence(path)
    assert ev.finished and ev.steps().num_rows == 5 and check([path]).ok
    # closed: the lock is gone, and overwrite=True may replace the file
    with RecordEvidence(gym.make("CartPole-v1"), path, overwrite=True) as env:
        _record(env, 2)
    assert open_evidence(path).steps().num_rows == 2


def test_a_crashed_writer_s_file_is_unlocked_and_recoverable(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    child = python(HOLDER, str(path))
    assert child.stdout is not None
    try:
        assert child.stdout.readline().strip() == str(path)
        assert writer_of(path) is not None and writer_of(path).pid == child.pid  # type: ignore[union-attr]
        child.kill()
        child.wait(timeout=60)
    finally:
        child.communicate(timeout=60)
    assert writer_of(path) is None  # the lock died with the process
    ev = open_evidence(path)
    assert ev.writer is None and ev.torn and "without a summary" in ev.torn
    result = recover(path, tmp_path / "fixed.mcap")
    assert result.steps == 5 and open_evidence(tmp_path / "fixed.mcap").finished


def test_closing_releases_the_lock_that_a_forked_child_still_shares(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    _record(env)
    # a fork (e.g. a DataLoader worker) shares the open file, and with it the lock
    child = multiprocessing.get_context("fork").Process(target=time.sleep, args=(30,))
    child.start()
    try:
        env.close()
        assert writer_of(path) is None
        with RecordEvidence(gym.make("CartPole-v1"), path, overwrite=True) as again:
            _record(again, 2)
    finally:
        child.kill()
        child.join()
    assert open_evidence(path).steps().num_rows == 2


def test_a_filesystem_without_locks_records_anyway_and_warns_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (no filesystem here refuses flock: the refusal is what such a filesystem returns)
    def no_locks(fd: int, *, shared: bool = False) -> bool:
        raise OSError(37, "No locks available")

    monkeypatch.setattr(lock_module, "try_lock", no_locks)
    monkeypatch.setattr(lock_module, "_warned_no_locks", False)
    with pytest.warns(RecorderTroubleWarning, match="cannot lock files \\(No locks available\\)"):
        first = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "a.mcap")
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / "b.mcap") as second:  # no warning
        _record(second)
        # this process still refuses a second recorder on a file it writes
        with pytest.raises(ConfigurationError, match=_held(tmp_path / "b.mcap", HERE)):
            RecordEvidence(gym.make("CartPole-v1"), tmp_path / "b.mcap", overwrite=True)
    first.close()
    assert check([tmp_path / "a.mcap", tmp_path / "b.mcap"]).ok


def test_a_file_deleted_while_recorded_is_warned_once_and_the_loop_goes_on(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    env.reset(seed=0)
    path.unlink()
    with pytest.warns(RecorderTroubleWarning, match=r"run.mcap was deleted while being recorded: "):
        env.flush()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (once)
        for _ in range(5):
            env.step(0)
        env.flush()
        env.close()
    assert not path.exists()


# ------------------------------------------------------------------ path templates


def test_index_takes_the_lowest_free_path(tmp_path: Path) -> None:
    template = str(tmp_path / "train-{index}.mcap")
    (tmp_path / "train-1.mcap").write_bytes(b"taken")
    envs = [RecordEvidence(gym.make("CartPole-v1"), template) for _ in range(3)]
    assert [env.path.name for env in envs] == ["train-0.mcap", "train-2.mcap", "train-3.mcap"]
    envs[1].close()
    assert not (tmp_path / "train-2.mcap").exists()
    with RecordEvidence(gym.make("CartPole-v1"), template) as again:
        assert again.path.name == "train-2.mcap"
    for env in envs:
        env.close()
    assert (tmp_path / "train-1.mcap").read_bytes() == b"taken"
    # a recorder that never reset gives its index back: its file held no episode
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train-1.mcap"]
    with RecordEvidence(gym.make("CartPole-v1"), template) as env:
        env.reset(seed=0)  # an episode (even without a step) keeps the file
    assert open_evidence(tmp_path / "train-0.mcap").episodes().num_rows == 1


@pytest.mark.parametrize("name", ["runs/a/x.mcap", "runs/a/train-{index}.mcap"])
def test_a_missing_folder_is_created(tmp_path: Path, name: str) -> None:
    with RecordEvidence(gym.make("CartPole-v1"), tmp_path / name) as env:
        env.reset(seed=0)
    assert env.path.parent == tmp_path / "runs" / "a" and env.path.is_file()
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigurationError, match=r"x\.mcap: .*file is a file, not a folder"):
        RecordEvidence(gym.make("CartPole-v1"), tmp_path / "file" / "x.mcap")


def test_pid_time_format_specs_and_literal_braces(tmp_path: Path) -> None:
    with RecordEvidence(
        gym.make("CartPole-v1"), tmp_path / "{{x}}-{pid}-{time}-{index:03d}.mcap"
    ) as env:
        _record(env, 1)
        name = env.path.name
    assert re.fullmatch(rf"\{{x\}}-{os.getpid()}-\d{{8}}T\d{{6}}Z-000\.mcap", name), name
    assert open_evidence(tmp_path / name).finished


@pytest.mark.parametrize(
    ("path", "options", "error"),
    [
        ("run-{seed}.mcap", {}, "unknown field {seed}; a path template knows {index}, {pid}"),
        ("run-{}.mcap", {}, "unknown field {}"),
        ("run-{index!r}.mcap", {}, "{index!r}: no conversions"),
        ("run-{index.real}.mcap", {}, "unknown field {index.real}"),
        ("run-{index.mcap", {}, "a literal brace is written '{{' or '}}'"),
        ("run}.mcap", {}, "Single '}' encountered"),
        ("run-{index:q}.mcap", {}, "Unknown format code 'q'"),
        ("{index}/run.mcap", {}, "{index} must be in the file name, not in a directory"),
        ("run-{index}.mcap", {"overwrite": True}, "overwrite=True with {index}"),
    ],
)
def test_a_bad_template_is_refused_at_construction(
    tmp_path: Path, path: str, options: dict[str, bool], error: str
) -> None:
    with pytest.raises(ConfigurationError, match=re.escape(error)):
        RecordEvidence(gym.make("CartPole-v1"), tmp_path / path, **options)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_template_text_is_the_path_as_given() -> None:
    assert PathTemplate("a/b-{index}.mcap").render(12) == "a/b-12.mcap"
    assert PathTemplate("plain.mcap").fields == set()


def _worker_env() -> gym.Env:  # type: ignore[type-arg]
    return RecordEvidence(gym.make("CartPole-v1"), os.environ["EA_TEMPLATE"])


def test_async_vector_env_workers_each_get_their_own_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("EA_TEMPLATE", str(tmp_path / "train-{index}.mcap"))
    envs = gym.vector.AsyncVectorEnv([_worker_env] * 4, context="fork")
    try:
        envs.reset(seed=0)
        for _ in range(60):
            envs.step(envs.action_space.sample())
    finally:
        envs.close()
    paths = sorted(tmp_path.iterdir())
    assert [p.name for p in paths] == [f"train-{i}.mcap" for i in range(4)]
    for path in paths:
        ev = open_evidence(path)
        # 60 steps of the vector env; a step after an episode's end was a reset of its sub-env
        assert ev.finished and 50 < ev.steps().num_rows == int(ev.run_end["steps"]) <= 60  # type: ignore[index]
    assert check(paths).ok


RACER = """
import os, sys, time
import gymnasium as gym
from episode_audit import RecordEvidence

template, go = sys.argv[1], sys.argv[2]
env = gym.make("CartPole-v1")
while not os.path.exists(go):  # everyone imported: claim at once
    time.sleep(0.001)
with RecordEvidence(env, template) as rec:
    rec.reset(seed=0)
    rec.step(0)
    print(rec.path, flush=True)
"""


def test_processes_racing_for_an_index_get_distinct_files(tmp_path: Path) -> None:
    template = str(tmp_path / "runs" / "train-{index}.mcap")
    (tmp_path / "runs").mkdir()
    go = tmp_path / "go"
    racers = [python(RACER, template, str(go)) for _ in range(6)]
    time.sleep(3)
    go.touch()
    claimed = []
    for racer in racers:
        out, err = racer.communicate(timeout=120)
        assert racer.returncode == 0, err
        claimed.append(Path(out.strip()).name)
    assert sorted(claimed) == [f"train-{i}.mcap" for i in range(6)]
    assert check(sorted((tmp_path / "runs").iterdir())).ok


def test_the_record_command_takes_a_template_and_names_the_file(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from episode_audit.cli import app

    out = str(tmp_path / "run-{index}.mcap")
    for index in (0, 1):
        result = CliRunner().invoke(app, ["record", "CartPole-v1", "--out", out, "--episodes", "1"])
        assert result.exit_code == 0, result.output
        assert f"to {tmp_path / f'run-{index}.mcap'}:" in result.stdout
    # the command names its own option (it said overwrite=True … drop overwrite, Python's)
    result = CliRunner().invoke(app, ["record", "CartPole-v1", "--out", out, "--overwrite"])
    assert result.exit_code == 2 and "overwrite=True" not in result.stderr
    assert "--overwrite with {index}" in result.stderr and "drop --overwrite," in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run-0.mcap", "run-1.mcap"]


_FORKED = """
import os, sys
import gymnasium as gym
from episode_audit import RecordEvidence
env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1])
env.reset(seed=0)
for _ in range(5):
    env.step(0)
if os.fork() == 0:
    sys.exit(0)  # a child that ends normally runs the interpreter's exit hooks
os.wait()
for _ in range(3):
    env.step(1)
env.close()
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_forked_child_ending_normally_leaves_the_parents_file_alone(tmp_path: Path) -> None:
    path = tmp_path / "forked.mcap"
    subprocess.run([sys.executable, "-c", _FORKED, str(path)], check=True, timeout=120)
    result = check([path])
    assert result.ok and not result.warnings, [f.message for f in result.findings]
    assert open_evidence(path).steps(columns=["episode"]).num_rows == 8


_CHILD_USES_IT = """
import os, sys
import gymnasium as gym
import numpy as np
from episode_audit import RecordEvidence, RecordVectorEvidence
from episode_audit.errors import RecorderError
from episode_audit.read.liveness import writer_of
path = sys.argv[1]
if sys.argv[2] == "vector":
    env = RecordVectorEvidence(gym.make_vec("CartPole-v1", 2, vectorization_mode="sync"), path)
    action = np.zeros(2, dtype=np.int64)
else:
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    action = 0
env.reset(seed=0)
for _ in range(5):
    env.step(action)
pid = os.fork()
if pid == 0:
    refused = []
    for call in (lambda: env.step(action), env.flush, lambda: env.reset(seed=1)):
        try:
            call()
        except RecorderError as exc:
            refused.append(str(exc))
    if sys.argv[3] == "close":
        env.close()  # closes the child's env; writes nothing, keeps the parent's lock
    assert writer_of(path) is not None and writer_of(path).pid == os.getppid()
    print("\\n".join(refused), flush=True)
    sys.exit(0)
os.waitpid(pid, 0)
for _ in range(3):
    env.step(action)
env.close()
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
@pytest.mark.parametrize("kind", ["single", "vector"])
@pytest.mark.parametrize("end", ["close", "exit"])
def test_a_forked_child_cannot_record_into_its_parents_file(
    tmp_path: Path, kind: str, end: str
) -> None:
    """Refused in the child, whether it closes the recorder or exits without; no warning."""
    path = tmp_path / "forked.mcap"
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", _CHILD_USES_IT, str(path), kind, end],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    refused = done.stdout.splitlines()
    assert len(refused) == 3, done.stdout + done.stderr
    for message in refused:
        assert re.match(
            rf"^{re.escape(str(path))}: this process \(pid \d+\) is a fork of the one recording "
            r"\(pid \d+\), and the recorder records only there; create the recorder in this",
            message,
        ), message
    assert "was not closed" not in done.stderr and "Traceback" not in done.stderr, done.stderr
    result = check([path])
    assert result.ok and not result.warnings, [f.message for f in result.findings]
    envs = 2 if kind == "vector" else 1
    assert open_evidence(path).steps(columns=["episode"]).num_rows == 8 * envs


@pytest.mark.parametrize("how", ["copy", "deepcopy", "pickle"])
def test_a_recorder_is_neither_copied_nor_pickled(tmp_path: Path, how: str) -> None:
    # a copy's close() finished the file under the original, which then recorded nothing
    path = tmp_path / "run.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path)
    _record(env, 3)
    make = {"copy": copy.copy, "deepcopy": copy.deepcopy, "pickle": pickle.dumps}[how]
    verb = "pickled" if how == "pickle" else "copied"
    with pytest.raises(
        RecorderError,
        match=rf"^{re.escape(str(path))}: a recorder cannot be {verb}: it owns an open evidence "
        "file, which a copy's close",
    ):
        make(env)
    env.step(1)
    env.close()
    assert check([path]).ok and open_evidence(path).steps().num_rows == 4
