"""Replay of files whose sub-envs ran in AsyncVectorEnv workers, whose TimeLimits the recorder
could not all read, nor where they sat (format/wrappers.py ``worker_sub_envs``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit import RecordVectorEvidence, open_evidence
from episode_audit.replay import replay
from tests.support.hostile import rewrite

_UNPLACED = (
    "the sub-envs ran in AsyncVectorEnv workers, whose wrapper chains the recorder cannot walk, "
    "and its spec holds MaxAndSkipObservation, which steps the env more than once a step: "
    "whether its TimeLimits sat over it or under it is unknown, so an env rebuilt from the spec "
    "may end an episode at another step; pass --env-factory MODULE:CALLABLE that builds the "
    "sub-env as recorded, or record with SyncVectorEnv"
)
_ASYNC = (
    "the sub-envs ran in AsyncVectorEnv workers, whose wrapper chains the recorder cannot walk: "
    "it read the outermost TimeLimit's limit only (one inside it, or under a frame-skipping "
    "wrapper, it did not); record with SyncVectorEnv to replay such endings"
)


def _skipped(inner: int, outer: int | None = None) -> gym.Env[Any, Any]:
    """Pendulum in a limit of ``inner`` of its steps, in a 2-step frame skip, in ``outer``."""
    env = gym.wrappers.MaxAndSkipObservation(
        gym.make("Pendulum-v1", max_episode_steps=inner), skip=2
    )
    return env if outer is None else gym.wrappers.TimeLimit(env, outer)


def _inner_ends() -> gym.Env[Any, Any]:
    """The limit of 5 under the frame skip ends each episode inside its 3rd step, unseen by the
    recorder, which read the one of 30 over it (as the spec's ``max_episode_steps``)."""
    return _skipped(5, 30)


def _outer_cuts() -> gym.Env[Any, Any]:
    """The limit of 3 over the frame skip (the spec's ``max_episode_steps``, under it)."""
    return _skipped(100, 3)


def _nested() -> gym.Env[Any, Any]:
    """Pendulum's registered 200-step limit inside one of 500: the inner one ends episodes."""
    return gym.wrappers.TimeLimit(gym.make("Pendulum-v1"), 500)


def _record_async(path: Path, make: Any, steps: int) -> Path:
    with RecordVectorEvidence(gym.vector.AsyncVectorEnv([make] * 2), path) as rec:
        rec.action_space.seed(0)
        rec.reset(seed=0)
        for _ in range(steps):
            rec.step(rec.action_space.sample())
    return path


@pytest.mark.parametrize(
    ("make", "steps", "outcomes"),
    [(_inner_ends, 3, ["truncated"] * 2), (_outer_cuts, 2, ["incomplete"] * 2)],
    ids=["complete", "incomplete"],
)
def test_a_frame_skip_in_async_workers_makes_every_episode_not_replayable(
    tmp_path: Path, make: Any, steps: int, outcomes: list[str]
) -> None:
    """Rebuilt from the spec, the limit would sit under the frame skip (wrongly: ending the
    incomplete episodes inside their first step) or miss the one under it: not a divergence."""
    path = _record_async(tmp_path / "async.mcap", make, steps)
    assert [e["outcome"] for e in open_evidence(path).episodes().to_pylist()] == outcomes
    result = replay([path])
    assert {(e.status, e.reason) for e in result.episodes} == {("not_replayable", _UNPLACED)}


def test_an_env_factory_building_the_chain_replays_a_frame_skip_file(tmp_path: Path) -> None:
    """The factory is the user's word on where the limits sat: the recorded 30 is not held
    against its 5, whose endings (recorded external: the recorder did not read it) it repeats
    at the same steps."""
    path = _record_async(tmp_path / "async.mcap", _inner_ends, 4)
    ended = [e for e in open_evidence(path).episodes().to_pylist() if e["length"] == 3]
    assert [e["truncation_reason"] for e in ended] == ["external"] * 2
    result = replay([path], env_factory=_inner_ends)
    assert [(e.status, e.steps) for e in result.episodes] == [("identical", 3)] * 2
    assert result.unstarted == 2


def test_an_env_factory_ending_episodes_before_the_unread_limit_did_is_said(
    tmp_path: Path,
) -> None:
    """Its limit under the frame skip ends them sooner than the recorded one did: the recorder
    did not read that limit, so the file does not say which one it was."""
    path = _record_async(tmp_path / "async.mcap", _inner_ends, 4)
    result = replay([path], env_factory=lambda: _skipped(3, 30))
    why = "the rebuilt env's time limit truncated it at step 1, where the recorded episode"
    assert [(e.status, (e.reason or "")[: len(why)]) for e in result.episodes[:2]] == [
        ("not_replayable", why)
    ] * 2
    assert all((e.reason or "").endswith(_ASYNC) for e in result.episodes[:2])


def test_an_env_factory_with_the_inner_limit_a_worker_hid_is_not_refused(tmp_path: Path) -> None:
    path = _record_async(tmp_path / "nested.mcap", _nested, 202)
    assert open_evidence(path).run.env_spec["max_episode_steps"] == 500  # type: ignore[index]
    result = replay([path], env_factory=_nested)
    assert [(e.status, e.steps, e.reason) for e in result.episodes] == [
        ("identical", 200, None),
        ("identical", 200, None),
        ("identical", 1, None),
        ("identical", 1, None),
    ]


def _relaid(path: Path, out: Path, **changes: str | None) -> Path:
    """``path`` with its layout's keys changed (``None``: removed), as another version wrote it."""

    def edit(meta: dict[str, str]) -> dict[str, str]:
        layout = json.loads(meta["layout"])
        for key, value in changes.items():
            if value is None:
                del layout[key]
            else:
                layout[key] = value
        return {**meta, "layout": json.dumps(layout)}

    return rewrite(path, out, run=edit)


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"unread_time_limits_cause": None},  # a file recorded before the cause code
        {"unread_time_limits": "the AsyncVectorEnv workers hid the limits; reworded"},
    ],
    ids=["as-recorded", "without-cause", "reworded"],
)
def test_a_frame_skip_file_from_workers_is_said_by_its_cause_code_or_else_its_text(
    tmp_path: Path, changes: dict[str, str | None]
) -> None:
    path = _record_async(tmp_path / "async.mcap", _inner_ends, 3)
    layout = open_evidence(path).run.layout
    assert (layout["unread_time_limits"], layout["unread_time_limits_cause"]) == (_ASYNC, "workers")
    edited = _relaid(path, tmp_path / "edited.mcap", **changes)
    result = replay([edited])
    assert {(e.status, e.reason) for e in result.episodes} == {("not_replayable", _UNPLACED)}
