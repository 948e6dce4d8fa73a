"""`check` on files whose sub-envs ran in AsyncVectorEnv workers under a frame skip: replay
cannot rebuild them from the spec (format/wrappers.py ``unplaced_limits``), and check says so."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym

from episode_audit import RecordVectorEvidence, check
from episode_audit.replay import replay


def _skipped() -> gym.Env[Any, Any]:
    """Pendulum in a 2-step frame skip, in a limit of 3 of its steps."""
    env = gym.wrappers.MaxAndSkipObservation(gym.make("Pendulum-v1"), skip=2)
    return gym.wrappers.TimeLimit(env, 3)


def _record(path: Path, vector: Any) -> Path:
    with RecordVectorEvidence(vector([_skipped] * 2), path) as rec:
        rec.reset(seed=0)
        for _ in range(4):
            rec.step(rec.action_space.sample())
    return path


def test_a_worker_file_under_a_frame_skip_is_not_replayable_by_check_as_by_replay(
    tmp_path: Path,
) -> None:
    path = _record(tmp_path / "async.mcap", gym.vector.AsyncVectorEnv)
    found = [f for f in check([path]).findings if f.code == "not_replayable"]
    assert len(found) == 1 and found[0].severity == "warning"
    assert found[0].message.startswith(
        "no episode can be replayed from the spec: the sub-envs ran in AsyncVectorEnv workers"
    )
    reasons = {e.reason for e in replay([path]).episodes}
    assert len(reasons) == 1 and found[0].message.endswith(str(reasons.pop()))


def test_the_same_sub_envs_in_this_process_are_replayable(tmp_path: Path) -> None:
    path = _record(tmp_path / "sync.mcap", gym.vector.SyncVectorEnv)
    assert "not_replayable" not in {f.code for f in check([path]).findings}
    assert {e.status for e in replay([path]).episodes} == {"identical"}
