"""Reset options as the recorders record them: before the reset, noted when not held."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from episode_audit import RecordEvidence, RecordVectorEvidence, open_evidence
from episode_audit.format import names as fmt
from episode_audit.record.values import recordable_options
from episode_audit.replay import replay
from tests.support.typed_options import NoneOrEmpty, PoppingStart, TypedStart

_CHANGED = (
    "options_unserializable: the env changed its options during reset(): what each sub-env "
    "received is unknown"
)


def _reset_notes(path: Path) -> list[list[str]]:
    notes = open_evidence(path).resets().column(fmt.COL_NOTES).to_pylist()
    return [json.loads(n) if n else [] for n in notes]


def _statuses(path: Path, factory: Any = PoppingStart) -> list[tuple[str, str | None]]:
    return [(e.status, e.reason) for e in replay([path], env_factory=factory).episodes]


def test_a_single_env_that_pops_its_options_replays_with_what_it_was_given(
    tmp_path: Path,
) -> None:
    path = tmp_path / "s.mcap"
    with RecordEvidence(PoppingStart(), path) as env:
        env.reset(seed=1, options={"goal": (0.5, -0.5)})
        env.step(1)
    assert _reset_notes(path)[0][0].endswith("; exact in the options_typed column)")
    assert _statuses(path) == [("identical", None)]


def test_options_a_sync_vector_env_shares_and_its_sub_envs_change_are_not_replayable(
    tmp_path: Path,
) -> None:
    """Sub-env 0 took ``goal`` out of the one dict both were given: sub-env 1 got none."""
    path = tmp_path / "v.mcap"
    with RecordVectorEvidence(gym.vector.SyncVectorEnv([PoppingStart] * 2), path) as envs:
        envs.reset(seed=1, options={"goal": (0.5, -0.5)})
        envs.step(np.ones(2, np.int64))
    assert [notes[-1] for notes in _reset_notes(path)] == [_CHANGED] * 2
    result = _statuses(path)
    assert [status for status, _ in result] == ["not_replayable"] * 2
    assert (result[1][1] or "").startswith(
        "its reset options are not in the file (the env changed its options during reset()"
    )


def test_options_set_on_a_dummy_vec_env_its_sub_envs_change_are_not_replayable(
    tmp_path: Path,
) -> None:
    """``set_options`` gives every sub-env one deep-copied dict."""
    path = tmp_path / "d.mcap"
    vec_env = pytest.importorskip("stable_baselines3.common.vec_env")
    from episode_audit import RecordVecEnvEvidence

    env = RecordVecEnvEvidence(vec_env.DummyVecEnv([PoppingStart] * 2), path)
    env.seed(1)
    env.set_options({"goal": (0.5, -0.5)})
    env.reset()
    env.step(np.ones(2, np.int64))
    env.close()
    assert [status for status, _ in _statuses(path)][:2] == ["not_replayable"] * 2


def test_a_vector_reset_with_empty_options_records_them_empty(tmp_path: Path) -> None:
    """``{}`` (or a ``reset_mask`` alone, which the sub-envs get as ``{}``) is not ``None``."""
    path = tmp_path / "e.mcap"
    with RecordVectorEvidence(gym.vector.SyncVectorEnv([NoneOrEmpty] * 2), path) as envs:
        envs.reset(seed=1, options={})
        envs.reset(options={"reset_mask": np.array([False, True])})
        envs.step(np.ones(2, np.int64))
    assert open_evidence(path).resets().column(fmt.COL_OPTIONS).to_pylist() == ["{}"] * 3
    assert [status for status, _ in _statuses(path, NoneOrEmpty)] == ["identical"] * 2


def test_a_list_held_twice_in_the_options_is_not_replayable(tmp_path: Path) -> None:
    shared = [0.5, -0.5]
    path = tmp_path / "a.mcap"
    with RecordEvidence(TypedStart(), path) as env:
        env.reset(seed=1, options={"goal": shared, "path": shared})
        env.step(1)
    (noted,) = _reset_notes(path)[0]
    assert noted.endswith(
        "(JSON keeps no list twice: the same list is at two places in them, it comes back as "
        "two; options_typed holds no list twice: the same list is at two places in them, it "
        "comes back as two)"
    )
    assert [status for status, _ in _statuses(path, TypedStart)] == ["not_replayable"]


def test_an_int_too_long_for_text_loses_the_options_not_the_reset(tmp_path: Path) -> None:
    path = tmp_path / "i.mcap"
    with RecordEvidence(TypedStart(), path) as env:
        env.reset(seed=1, options={"n": 10**5000})
        env.step(1)
    ev = open_evidence(path)
    assert ev.run_end is not None and int(ev.run_end.get("recorder_trouble", 0)) == 0
    (noted,) = _reset_notes(path)[0]
    assert noted.startswith("options_unserializable: <dict: repr() raised ValueError> (")
    assert [status for status, _ in _statuses(path, TypedStart)] == ["not_replayable"]


def test_plain_options_larger_than_a_reader_parses_are_noted(tmp_path: Path) -> None:
    path = tmp_path / "p.mcap"
    with RecordEvidence(TypedStart(), path) as env:
        env.reset(seed=1, options={"goal": [[0.125, -0.5] for _ in range(100_000)]})
        env.step(1)
    (noted,) = _reset_notes(path)[0]
    assert noted.endswith("(1300010 bytes of JSON, more than the 1048576 a reader parses)")
    assert [status for status, _ in _statuses(path, TypedStart)] == ["not_replayable"]


def test_a_pettingzoo_game_that_pops_its_options_replays_with_what_it_was_given(
    tmp_path: Path,
) -> None:
    """The options are taken before the game's reset, which takes ``start`` out of them."""
    pytest.importorskip("pettingzoo")
    from episode_audit import RecordParallelEvidence
    from tests.support.walk_game import WalkGame

    class PoppingWalk(WalkGame):  # type: ignore[misc]
        def reset(
            self, seed: int | None = None, options: dict[str, Any] | None = None
        ) -> tuple[dict[str, Any], dict[str, Any]]:
            start = (options or {}).pop("start", None)
            obs, infos = super().reset(seed=seed)
            if start is not None:
                self.x = {a: float(x) for a, x in zip(self.agents, start, strict=True)}
                obs = {a: np.array([self.x[a]], np.float32) for a in self.agents}
            return obs, infos

    path = tmp_path / "pz.mcap"
    with RecordParallelEvidence(PoppingWalk(), path) as env:
        env.reset(seed=1, options={"start": (2.0, -2.0)})
        for _ in range(2):
            env.step({a: 1 for a in env.agents})
    options = open_evidence(path).resets().column(fmt.COL_OPTIONS).to_pylist()
    assert {json.loads(o)["start"][0] for o in options} == {2.0}
    result = replay([path], env_factory=PoppingWalk)
    assert [e.status for e in result.episodes] == ["identical"] * 2, result.episodes


@pytest.mark.parametrize(
    "options",
    [
        {"goal": [0.5, 1.0]},
        {"init": (1, 2), "low": np.float32(0.5)},
        {"n": 10**5000},
        {"goal": [[0.125, -0.5] for _ in range(100_000)]},
    ],
    ids=["plain", "typed", "unwritable", "too-large"],
)
def test_the_options_column_is_the_json_text_made_when_the_options_were_read(
    tmp_path: Path, options: dict[str, Any]
) -> None:
    """The recorder makes the options' JSON text once, as it reads them before the reset."""
    recorded = recordable_options(options)
    assert recorded is not None
    assert json.loads(recorded.text) == recorded.plain
    path = tmp_path / "o.mcap"
    with RecordEvidence(TypedStart(), path) as env:
        env.reset(seed=1, options=options)
        env.step(1)
    assert open_evidence(path).resets().column(fmt.COL_OPTIONS).to_pylist() == [recorded.text]
