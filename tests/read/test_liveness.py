"""Readers tell a live file from a torn one by its writer's lock: read/liveness.py."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import gymnasium as gym
import pytest

from episode_audit import RecordEvidence, open_evidence, recover
from episode_audit.errors import ConfigurationError, EvidenceError
from episode_audit.format.locking import try_lock, unlock
from episode_audit.record.lock import claim_output


def _record(env: RecordEvidence, steps: int = 5) -> None:
    env.reset(seed=0)
    for _ in range(steps):
        env.step(0)


def test_readers_say_a_file_is_still_being_written_and_recover_refuses_it(
    tmp_path: Path,
) -> None:
    path = tmp_path / "live.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, flush_every_s=3600)
    _record(env)
    env.flush()
    try:
        ev = open_evidence(path)
        me = f"pid {os.getpid()}"
        assert ev.writer is not None and ev.writer.pid == os.getpid()
        assert ev.torn is not None and ev.torn.startswith(
            f"still being written by this process ({me})"
        )
        with pytest.raises(ConfigurationError, match="is still being written by this process"):
            recover(path, tmp_path / "out.mcap")
        assert not (tmp_path / "out.mcap").exists()
        # nor does recovery replace a live recorder's file
        done = tmp_path / "done.mcap"
        with RecordEvidence(gym.make("CartPole-v1"), done) as other:
            _record(other)
        with pytest.raises(ConfigurationError, match="recovery never replaces a live recorder"):
            recover(done, path, overwrite=True)
        assert open_evidence(path).steps().num_rows == 5
        env.step(0)  # the writer never noticed the readers
    finally:
        env.close()
    ev = open_evidence(path)
    assert ev.finished and ev.writer is None and ev.steps().num_rows == 6


def test_a_live_file_that_holds_nothing_yet_says_so(tmp_path: Path) -> None:
    output = claim_output(tmp_path / "new.mcap")  # created and locked, nothing written yet
    try:
        with pytest.raises(EvidenceError, match=r"still being written by .* it holds nothing yet"):
            open_evidence(output.path)
    finally:
        output.release()
        os.close(output.fd)
    with pytest.raises(EvidenceError, match="the file is empty"):
        open_evidence(output.path)


def test_a_reader_s_probe_never_refuses_a_writer_that_is_starting(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    path.write_bytes(b"old")
    fd = os.open(path, os.O_RDONLY)
    try:
        assert try_lock(fd, shared=True)  # a reader in the middle of its probe
        timer = threading.Timer(0.03, unlock, (fd,))
        timer.start()
        output = claim_output(path, overwrite=True)  # waits the probe out
        timer.join()
        assert output.locked and path.stat().st_size == 0  # truncated once locked
        output.release()
        os.close(output.fd)
    finally:
        os.close(fd)
