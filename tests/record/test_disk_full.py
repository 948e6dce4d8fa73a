"""A full disk in the middle of a run, for real: a file size limit (``RLIMIT_FSIZE``) in a child.

The child records CartPole-v1, flushes, then its file size limit is set just above the file's
size (the OS refuses the next flushes, as on a full disk), then lifted ("space returns"); it
records more, flushes and dies by SIGKILL, or closes. What the file holds afterwards is read
by the library, as ``check`` reads it: no ``recover`` needed, and nothing lost but what the
refused flushes held, when they could not be held for a retry.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from episode_audit import check, open_evidence, recover
from tests.support.disk import fill_disk

pytestmark = pytest.mark.skipif(
    not hasattr(signal, "SIGXFSZ"), reason="needs RLIMIT_FSIZE and SIGXFSZ (POSIX)"
)

REPO = Path(__file__).resolve().parents[2]

CHILD = r"""
import json, os, resource, signal, sys
import gymnasium as gym
import episode_audit.record.writer as writer
from episode_audit import RecordEvidence

cfg = json.loads(sys.argv[1])
if cfg["retry_limit"] is not None:
    writer.RETRY_LIMIT_BYTES = cfg["retry_limit"]
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit: EFBIG, not a signal
_, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
path = cfg["path"]
env = RecordEvidence(gym.make("CartPole-v1"), path, block_steps=cfg["rows"], flush_every_s=3600)
env.action_space.seed(0)
env.reset(seed=0)
episode = 0

def run(n):
    global episode
    for _ in range(n):
        if any(env.step(env.action_space.sample())[2:4]):
            episode += 1
            env.reset(seed=episode)

if not cfg["refuse_first"]:
    run(cfg["rows"])  # (each block of `rows` rows is flushed by the loop's own step)
    env.flush()  # (nothing left to write: the size limit comes after a completed flush)
resource.setrlimit(resource.RLIMIT_FSIZE, (os.path.getsize(path) + cfg["slack"], hard))
run(cfg["refused"] * cfg["rows"])
env.flush()  # (refused too, before space returns)
if cfg["end"] != "close_full":
    resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))
    run(cfg["rows"])
    env.flush()
file = env._file
lost = getattr(file.writer, "lost", {}).get(env._stream.channels.steps, 0)
print(json.dumps({"steps": file.counts["steps"], "lost": lost}), flush=True)
if cfg["end"] == "kill":
    os.kill(os.getpid(), signal.SIGKILL)
env.close()
print(json.dumps({"closed": True}), flush=True)
"""


def record(tmp_path: Path, **cfg: Any) -> tuple[dict[str, Any], list[str], int]:
    cfg = {"path": str(tmp_path / "run.mcap"), "rows": 3000, "slack": 0, "refused": 2,
           "retry_limit": None, "end": "kill", "refuse_first": False, **cfg}  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(cfg)],
        capture_output=True, text=True, env=env, timeout=300, check=False,
    )  # fmt: skip
    lines = done.stdout.splitlines()
    assert lines, done.stderr
    return json.loads(lines[0]), done.stderr.splitlines(), done.returncode


# slack: bytes the OS still takes of the first refused flush (a partial chunk) before refusing
PARTIAL = pytest.mark.parametrize("slack", [0, 1000], ids=["refused_whole", "partial_write"])


@PARTIAL
def test_rows_refused_by_a_brief_full_disk_are_written_when_space_returns(
    tmp_path: Path, slack: int
) -> None:
    """Held and retried: after SIGKILL every row reads, without recover."""
    report, stderr, code = record(tmp_path, slack=slack)
    assert code == -signal.SIGKILL
    assert report == {"steps": 4 * 3000, "lost": 0}
    ev = open_evidence(tmp_path / "run.mcap")
    assert not ev.finished and ev.steps(columns=["episode"]).num_rows == 4 * 3000
    codes = {f.code for f in check([tmp_path / "run.mcap"]).findings if f.severity == "error"}
    assert codes <= {"file_unfinished"}, codes
    # the recorder's trouble: one line naming the file, no source line under it
    assert len(stderr) == 1, stderr
    assert (
        "recording to " + str(tmp_path / "run.mcap") + " failed (OSError: [Errno 27]" in stderr[0]
    )


@PARTIAL
def test_rows_dropped_past_the_retry_limit_are_the_refused_flushes_rows_only(
    tmp_path: Path, slack: int
) -> None:
    """Every row flushed after space returned reads without recover; lost = refused rows."""
    report, stderr, code = record(tmp_path, retry_limit=0, slack=slack)
    assert code == -signal.SIGKILL
    assert report == {"steps": 4 * 3000, "lost": 2 * 3000}
    ev = open_evidence(tmp_path / "run.mcap")
    steps = ev.steps(columns=["episode", "step"])
    assert steps.num_rows == 2 * 3000
    assert len(stderr) == 1, stderr
    # the rows kept are the first flush's and the last one's, whole
    result = recover(tmp_path / "run.mcap", tmp_path / "fixed.mcap")
    assert not result.data_dropped and not result.damaged


def test_a_dropped_first_flush_leaves_what_follows_readable(tmp_path: Path) -> None:
    """The first chunk holds the Schema and Channel records: dropped, they come again."""
    report, stderr, code = record(tmp_path, retry_limit=0, refuse_first=True)
    assert code == -signal.SIGKILL
    assert report == {"steps": 3 * 3000, "lost": 2 * 3000}
    ev = open_evidence(tmp_path / "run.mcap")
    assert ev.steps(columns=["episode"]).num_rows == 3000
    assert len(stderr) == 1, stderr
    # (an episode cut by the dropped rows is a length_mismatch: the file reads, as it is)
    codes = {f.code for f in check([tmp_path / "run.mcap"]).findings if f.severity == "error"}
    assert codes <= {"file_unfinished", "length_mismatch"}, codes


@pytest.mark.parametrize("slack", [0, 64 << 10], ids=["no_room", "room_for_the_end"])
def test_close_on_a_full_disk_does_not_raise_and_the_file_says_what_was_lost(
    tmp_path: Path, slack: int
) -> None:
    _, stderr, code = record(tmp_path, end="close_full", slack=slack)
    assert code == 0, stderr
    ev = open_evidence(tmp_path / "run.mcap")
    if slack:  # the refused rows dropped, then the run-end record and the summary fit
        assert ev.finished and ev.run_end is not None
        assert ev.steps(columns=["episode"]).num_rows == 3000
        assert ev.run_end["steps"] == "3000"
        assert ev.run_end["recorder_lost_steps"] == str(2 * 3000)
        assert ev.run_end["recorder_lost_episode_records"] != "0"
        assert int(ev.run_end["recorder_trouble"]) >= 2
        assert len(stderr) == 1, stderr
        # the summary indexes what the file holds (mcap's own reader, through it)
        with open(tmp_path / "run.mcap", "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            read = sum(1 for _ in reader.iter_messages())
            assert read == summary.statistics.message_count
            assert len(summary.chunk_indexes) == summary.statistics.chunk_count
    else:  # nothing fits: the file ends after its last good flush; recover finishes it
        assert not ev.finished and ev.steps(columns=["episode"]).num_rows == 3000
        assert len(stderr) == 2, stderr
        assert "could not be finished" in stderr[1] and "episode-audit recover" in stderr[1]
        result = recover(tmp_path / "run.mcap", tmp_path / "fixed.mcap")
        assert open_evidence(tmp_path / "fixed.mcap").finished
        assert "the recorder never finished the file (killed, or its close() could not write)" in (
            result.dropped
        )
    assert all(line.startswith("<episode-audit>:0: RecorderTroubleWarning: ") for line in stderr)


def test_record_on_a_full_disk_says_one_line_naming_the_file(tmp_path: Path) -> None:
    """``episode-audit record``: one error line (no warning, no source line), exit 2."""
    import resource

    out = tmp_path / "cli.mcap"

    def full_at_40_kib() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (40 << 10, resource.RLIM_INFINITY))

    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "episode_audit", "record", "CartPole-v1", "--out", str(out),
         "--episodes", "400"],
        capture_output=True, text=True, env=env, timeout=300, check=False,
        preexec_fn=full_at_40_kib,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"episode-audit: error: {out}: recording failed (OSError: [Errno 27]")
    # the file reads, and says what it could not hold
    findings = {f.code for f in check([out]).findings}
    ev = open_evidence(out)
    if ev.finished:
        assert "recorder_trouble" in findings
        assert ev.run_end is not None and int(ev.run_end["recorder_lost_steps"]) > 0
    else:  # a time-based flush (a loaded host) left less room than the summary needs
        assert "file_unfinished" in findings
        assert recover(out, tmp_path / "recovered.mcap").episodes > 0


def test_record_that_cannot_finish_the_file_says_how_to_recover_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The run-end record and summary do not fit: the error names ``recover``, which works."""
    import errno

    from episode_audit.errors import RecorderError
    from episode_audit.record.writer import EvidenceWriter
    from episode_audit.rollout import record_episodes

    def full(self: EvidenceWriter, run_end: Any) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(EvidenceWriter, "finish", full)
    out = tmp_path / "unfinished.mcap"
    with pytest.raises(
        RecorderError,
        match=r"unfinished\.mcap: recording failed \(OSError: \[Errno 28\] No space left on "
        r"device\); the file ends after its last good flush and could not be finished: "
        r"`episode-audit recover .*unfinished\.mcap OUT\.mcap` finishes a copy",
    ):
        record_episodes("CartPole-v1", out, episodes=3)
    monkeypatch.undo()
    assert not open_evidence(out).finished
    assert recover(out, tmp_path / "fixed.mcap").episodes == 3


def test_a_real_full_disk_then_space_again_loses_no_row(small_disk: Path, tmp_path: Path) -> None:
    """ENOSPC from a full tmpfs (partial writes included): held, retried, every row reads."""
    import gymnasium as gym

    from episode_audit import RecordEvidence

    path = small_disk / "run.mcap"
    env = RecordEvidence(gym.make("CartPole-v1"), path, block_steps=2000, flush_every_s=3600)
    env.action_space.seed(0)
    env.reset(seed=0)
    episode, steps = 0, 0

    def run(n: int) -> None:
        nonlocal episode, steps
        for _ in range(n):
            steps += 1
            if any(env.step(env.action_space.sample())[2:4]):
                episode += 1
                env.reset(seed=episode)

    run(2000)
    filler = fill_disk(small_disk)  # (a few bytes may be left)
    with pytest.warns(RuntimeWarning, match=r"run\.mcap failed \(OSError: \[Errno 28\] No space"):
        run(6000)
    filler.unlink()  # space returns
    run(2000)
    env.flush()
    shutil.copyfile(path, tmp_path / "killed.mcap")  # what a SIGKILL now leaves on disk
    env.close()
    killed = open_evidence(tmp_path / "killed.mcap")
    assert killed.steps(columns=["episode"]).num_rows == steps == 10_000
    assert check([tmp_path / "killed.mcap"]).steps == steps
    ev = open_evidence(path)
    assert ev.finished and ev.steps(columns=["episode"]).num_rows == steps
    assert ev.run_end is not None and "recorder_lost_steps" not in ev.run_end
