"""``flush()`` from another thread: a timer thread hammering it while the loop steps loses no row,
numbers every step right and raises nothing in either thread; an idle recorder flushed from
another thread has its rows on disk."""

from __future__ import annotations

import shutil
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import RecordEvidence, RecordVectorEvidence, check, open_evidence
from tests.support.envs import ScriptedEnv


@pytest.fixture(autouse=True)
def _switch_often() -> Iterator[None]:
    """Switch threads every microsecond, so a race shows within a short run."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    yield
    sys.setswitchinterval(interval)


class Hammer(threading.Thread):
    """Calls ``flush()`` every millisecond until stopped; keeps what it raised."""

    def __init__(self, recorder: Any) -> None:
        super().__init__(daemon=True)
        self.recorder = recorder
        self.stop = threading.Event()
        self.raised: list[BaseException] = []
        self.flushes = 0

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                self.recorder.flush()
            except BaseException as exc:
                self.raised.append(exc)
                return
            self.flushes += 1
            time.sleep(0.001)


def assert_whole(path: Path, rows: int) -> None:
    ev = open_evidence(path)
    steps = ev.steps(columns=["episode", "step"])
    assert steps.num_rows == rows
    assert [f.code for f in check([path]).findings if f.severity == "error"] == []
    lengths = {e["episode"]: e["length"] for e in ev.episodes().to_pylist()}
    assert sum(lengths.values()) == rows


def test_a_timer_thread_hammering_flush_loses_no_row(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, block_steps=512, flush_every_s=3600)
    hammer = Hammer(env)
    env.action_space.seed(0)
    env.reset(seed=0)
    hammer.start()
    episode = 0
    for _ in range(20_000):
        if any(env.step(env.action_space.sample())[2:4]):
            episode += 1
            env.reset(seed=episode)
    hammer.stop.set()
    hammer.join()
    env.close()
    assert hammer.raised == [] and hammer.flushes > 10
    assert_whole(path, 20_000)


def test_a_timer_thread_hammering_a_vector_recorders_flush_loses_no_row(tmp_path: Path) -> None:
    path = tmp_path / "vec.mcap"
    venv = gym.make_vec("CartPole-v1", num_envs=4, vectorization_mode="sync")
    env = RecordVectorEvidence(venv, path, block_steps=512, flush_every_s=3600)
    hammer = Hammer(env)
    env.reset(seed=0)
    env.action_space.seed(0)
    hammer.start()
    for _ in range(3_000):
        env.step(env.action_space.sample())
    hammer.stop.set()
    hammer.join()
    env.close()
    assert hammer.raised == [] and hammer.flushes > 10
    ev = open_evidence(path)
    assert [f.code for f in check([path]).findings if f.severity == "error"] == []
    assert ev.steps(columns=["episode"]).num_rows == 3_000 * 4 - ev.resets().num_rows + 4


def test_an_idle_recorder_flushed_from_another_thread_has_its_rows_on_disk(
    tmp_path: Path,
) -> None:
    path = tmp_path / "idle.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, flush_every_s=3600)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.int64(0))
    flusher = threading.Thread(target=env.flush)
    flusher.start()
    flusher.join()
    shutil.copyfile(path, tmp_path / "killed.mcap")  # what a SIGKILL now leaves on disk
    env.close()
    assert open_evidence(tmp_path / "killed.mcap").steps(columns=["episode"]).num_rows == 5


def test_close_from_another_thread_keeps_every_step_that_returned(tmp_path: Path) -> None:
    """The step under way ends first; a later one raises the closed recorder's error."""
    from episode_audit.errors import RecorderError

    path = tmp_path / "closed.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, block_steps=64, flush_every_s=3600)
    env.action_space.seed(0)
    returned = 0
    refused: list[BaseException] = []

    def loop() -> None:
        nonlocal returned
        episode = 0
        env.reset(seed=0)
        try:
            while True:
                if any(env.step(env.action_space.sample())[2:4]):
                    episode += 1
                    env.reset(seed=episode)
                returned += 1
        except RecorderError as exc:
            refused.append(exc)

    stepper = threading.Thread(target=loop)
    stepper.start()
    time.sleep(0.5)
    env.close()
    stepper.join(timeout=30)
    assert len(refused) == 1 and "the recorder is closed" in str(refused[0])
    ev = open_evidence(path)
    assert ev.finished and ev.steps(columns=["episode"]).num_rows in (returned, returned + 1)


def _wait_for(condition: Any) -> None:
    deadline = time.monotonic() + 30
    while not condition():
        assert time.monotonic() < deadline, "the stepping thread never got there"
        time.sleep(0.001)


def test_a_thread_past_the_gate_counts_as_inside_and_one_held_at_it_does_not(
    tmp_path: Path,
) -> None:
    """A flush from another thread writes only while no thread can touch the recorder's rows.

    A thread held at the gate's lock touches nothing until the flush ends; one that got past the
    lock, still in ``_enter()``, steps next: a flush now would race its row (it must wait).
    """
    from episode_audit.record.file import _inside

    env = RecordEvidence(gym.make("CartPole-v1"), tmp_path / "gate.mcap", flush_every_s=3600)
    env.reset(seed=0)
    file = env._file
    past_the_lock = threading.Event()
    go_on = threading.Event()
    check_open = file.check_open

    def pausing_check_open() -> None:
        check_open()
        if threading.current_thread() is stepper and not env._flush_lock.locked():
            past_the_lock.set()
            go_on.wait(30)

    stepper = threading.Thread(target=env.step, args=(np.int64(0),))
    assert not _inside(env)  # between steps
    with env._flush_lock:
        env._gated = True  # (as flush() does, holding its lock)
        stepper.start()
        _wait_for(lambda: not env._busy and stepper.is_alive())
        file.check_open = pausing_check_open  # type: ignore[method-assign]
        assert not _inside(env)  # held at the lock
    _wait_for(past_the_lock.is_set)
    with env._flush_lock:
        assert _inside(env)  # past the lock: it steps next
    env._gated = False
    env.flush()  # from this thread: left to the end of the stepper's step
    assert file.flush_at == 0
    go_on.set()
    stepper.join()
    file.check_open = check_open  # type: ignore[method-assign]
    assert file.flush_at > 0  # the stepper flushed as its step ended
    assert not env._busy and not _inside(env)
    env.close()


def test_a_thread_inside_its_envs_step_counts_as_inside_and_flushes_as_it_ends(
    tmp_path: Path,
) -> None:
    """Another thread's flush never writes while a step is under way; that step writes it."""
    from episode_audit.record.file import _inside

    in_step, go_on = threading.Event(), threading.Event()

    def slow_step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        in_step.set()
        go_on.wait(30)
        return np.zeros(2, np.float32), 1.0, False, False, {}

    env = RecordEvidence(ScriptedEnv(step_fn=slow_step), tmp_path / "slow.mcap", flush_every_s=3600)
    env.reset(seed=0)
    stepper = threading.Thread(target=env.step, args=(np.int64(0),))
    stepper.start()
    _wait_for(in_step.is_set)
    assert _inside(env)
    blocks = env._file.counts["blocks"]
    env.flush()  # left to the end of the step under way
    assert env._file.flush_at == 0 and env._file.counts["blocks"] == blocks
    go_on.set()
    stepper.join()
    assert env._file.counts["blocks"] == blocks + 1 and env._file.flush_at > 0
    env.close()
    assert open_evidence(tmp_path / "slow.mcap").steps(columns=["episode"]).num_rows == 1


def test_a_flush_from_inside_the_stepping_threads_own_env_writes_at_once(
    tmp_path: Path,
) -> None:
    from episode_audit.record.file import _inside

    flushed: list[int] = []
    inside: list[bool] = []

    def flushing_step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        inside.append(_inside(recorder))  # (this thread's own call: not another's)
        recorder.flush()  # (a callback of the env's own, in the stepping thread)
        flushed.append(recorder._file.counts["blocks"])
        assert recorder._file.flush_at > 0  # written now, not left to the step's end
        return np.zeros(2, np.float32), 1.0, False, False, {}

    recorder = RecordEvidence(
        ScriptedEnv(step_fn=flushing_step), tmp_path / "own.mcap", flush_every_s=3600
    )
    recorder.reset(seed=0)
    recorder.step(np.int64(0))
    recorder.step(np.int64(0))
    recorder.close()
    assert flushed == [0, 1]  # the first flush had only the reset row; the second, a step too
    assert inside == [False, False]


def _slow_env(in_step: threading.Event, go_on: threading.Event) -> ScriptedEnv:
    def slow_step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        if threading.current_thread() is not threading.main_thread():
            in_step.set()
            go_on.wait(30)
        return np.zeros(2, np.float32), 1.0, False, False, {}

    return ScriptedEnv(step_fn=slow_step)


def _held_in_a_step(step: Any, action: Any, in_step: threading.Event) -> threading.Thread:
    stepper = threading.Thread(target=step, args=(action,))
    stepper.start()
    _wait_for(in_step.is_set)
    return stepper


SECOND_THREAD = "a second thread called this recorder while another is inside its step"


def test_a_second_thread_stepping_at_once_is_refused_and_the_file_stays_whole(
    tmp_path: Path,
) -> None:
    """Two threads inside one recorder would mix their rows: the second is refused, untouched."""
    from episode_audit.errors import RecorderError

    in_step, go_on = threading.Event(), threading.Event()
    path = tmp_path / "two.mcap"
    env = RecordEvidence(_slow_env(in_step, go_on), path, flush_every_s=3600)
    env.reset(seed=0)
    stepper = _held_in_a_step(env.step, np.int64(0), in_step)
    with pytest.raises(RecorderError, match=SECOND_THREAD):
        env.step(np.int64(1))
    with pytest.raises(RecorderError, match=SECOND_THREAD):
        env.reset(seed=1)
    assert env._busy  # (the refused calls left the stepping thread's mark)
    go_on.set()
    stepper.join()
    env.step(np.int64(1))  # one thread after another is fine
    env.close()
    assert_whole(path, 2)
    assert open_evidence(path).steps(columns=["action"]).column("action").to_pylist() == [0, 1]


def test_a_second_thread_stepping_a_vector_recorder_at_once_is_refused(tmp_path: Path) -> None:
    from episode_audit.errors import RecorderError

    in_step, go_on = threading.Event(), threading.Event()
    path = tmp_path / "vec-two.mcap"
    venv = gym.vector.SyncVectorEnv([lambda: _slow_env(in_step, go_on)])
    env = RecordVectorEvidence(venv, path, flush_every_s=3600)
    env.reset(seed=0)
    stepper = _held_in_a_step(env.step, np.array([0]), in_step)
    with pytest.raises(RecorderError, match=SECOND_THREAD):
        env.step(np.array([1]))
    go_on.set()
    stepper.join()
    env.close()
    assert [f.code for f in check([path]).findings if f.severity == "error"] == []
    assert open_evidence(path).steps(columns=["episode"]).num_rows == 1
