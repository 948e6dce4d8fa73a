"""Reset options replay as they were passed: their typed form when plain JSON would change them."""

from __future__ import annotations

import enum
import json
import math
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest

from episode_audit import (
    RecordEvidence,
    RecordParallelEvidence,
    RecordVectorEvidence,
    open_evidence,
)
from episode_audit.format import names as fmt
from episode_audit.replay import replay
from tests.support.hostile import rewrite
from tests.support.stateful import counted_cartpole
from tests.support.typed_options import Logger, TypedStart

with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.classic import rps_v2

_PLAIN = {"cap": 0.5}
"""Options plain JSON holds exactly."""

_TYPED = {
    "float64-array": {"qpos": np.array([0.25, -0.5])},
    "float32-array": {"qpos": np.array([0.1, 0.2], np.float32)},
    "int8-matrix": {"qpos": np.array([[1], [-2]], np.int8)},
    "tuple": {"goal": (1.0, 2.0)},
    "inf": {"cap": math.inf},
    "nan": {"cap": math.nan},
    "int-keys": {"levels": {1: 2.0, 2: 3.0}},
    "float32-scalar": {"scale": np.float32(1.1)},
    "bool-array": {"mask": np.array([True, False])},
}
"""Options plain JSON changes (each read by ``TypedStart`` as the type it was passed)."""


def _record(path: Path, options: list[Any]) -> Path:
    with RecordEvidence(TypedStart(), path) as env:
        for e, passed in enumerate(options):
            env.reset(seed=e, options=passed)
            for _ in range(3):
                env.step(1)
    return path


@pytest.mark.parametrize("options", list(_TYPED.values()), ids=list(_TYPED))
def test_reset_options_replay_as_the_types_they_were_passed(
    tmp_path: Path, options: dict[Any, Any]
) -> None:
    """As lists, ``"inf"`` or ``"1"`` the env would raise or differ: replay resets with them
    exactly, from the ``options_typed`` column."""
    path = _record(tmp_path / "o.mcap", [options, _PLAIN])
    ev = open_evidence(path)
    typed = ev.resets().column(fmt.COL_OPTIONS_TYPED).to_pylist()
    assert typed[0] is not None and typed[1] is None
    assert ev.episodes().column(fmt.COL_OPTIONS_TYPED).to_pylist() == typed
    assert ev.episode(0).record[fmt.COL_OPTIONS_TYPED] == typed[0]
    (noted,) = json.loads(ev.resets().column(fmt.COL_NOTES)[0].as_py())
    assert noted.startswith("options_unserializable: ") and noted.endswith(
        "; exact in the options_typed column)"
    )
    result = replay([path], env_factory=TypedStart)
    assert [(e.status, e.reason) for e in result.episodes] == [("identical", None)] * 2


def test_a_reader_without_the_typed_column_says_not_replayable_never_diverged(
    tmp_path: Path,
) -> None:
    """A file whose reset and episode blocks lack ``options_typed`` (what a reader that does not
    know the column reads) replays the noted episodes as ``not_replayable``: as lists, a
    float64 array, a tuple and a bool array would make this env raise or differ."""
    silent = [_TYPED["float64-array"], _TYPED["tuple"], _TYPED["bool-array"]]
    path = _record(tmp_path / "o.mcap", [*silent, _PLAIN])

    def untyped(batch: pa.RecordBatch) -> pa.RecordBatch:
        names = batch.schema.names
        return (
            batch.drop_columns([fmt.COL_OPTIONS_TYPED]) if fmt.COL_OPTIONS_TYPED in names else batch
        )

    older = rewrite(path, tmp_path / "older.mcap", resets=untyped, episodes=untyped)
    assert fmt.COL_OPTIONS_TYPED not in open_evidence(older).resets().column_names
    result = replay([older], env_factory=TypedStart)
    assert [e.status for e in result.episodes] == ["not_replayable"] * 3 + ["identical"]
    assert result.episodes[1].reason == (
        "its reset options are not in the file ({'goal': (1.0, 2.0)} (JSON keeps no tuples: "
        "they come back as lists; exact in the options_typed column)): replay cannot reset it "
        "as recorded; give reset() options of the types a file holds (None, bools, ints, "
        "floats, text, lists, tuples, dicts, numpy arrays and scalars)"
    )


def test_reset_options_no_form_holds_are_not_replayable(tmp_path: Path) -> None:
    """An object: neither the options' JSON nor their typed form holds it."""
    path = _record(tmp_path / "o.mcap", [{"cap": 1.0, "log": Logger()}, _PLAIN])
    ev = open_evidence(path)
    assert ev.resets().column(fmt.COL_OPTIONS_TYPED).to_pylist() == [None, None]
    assert json.loads(ev.resets()[fmt.COL_OPTIONS][0].as_py()) == {
        "repr": "{'cap': 1.0, 'log': <Logger>}"
    }
    result = replay([path], env_factory=TypedStart)
    assert [e.status for e in result.episodes] == ["not_replayable", "identical"]
    assert result.episodes[0].reason == (
        "its reset options are not in the file ({'cap': 1.0, 'log': <Logger>} (JSON has no "
        "Logger values; options_typed holds no Logger values)): replay cannot reset it as "
        "recorded; give reset() "
        "options of the types a file holds (None, bools, ints, floats, text, lists, tuples, "
        "dicts, numpy arrays and scalars)"
    )


def test_an_episode_after_one_whose_options_are_not_held_is_no_verdict(tmp_path: Path) -> None:
    """Replay skips episode 0, so its env counts one reset less in episode 1: no divergence."""
    path = tmp_path / "c.mcap"
    with RecordEvidence(counted_cartpole(), path) as env:
        env.reset(seed=1, options={"low": -0.05, "high": 0.05, "log": Logger()})
        env.step(0)
        env.reset(seed=2)
        env.step(0)
    result = replay([path], env_factory=counted_cartpole)
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2
    assert (result.episodes[1].reason or "").startswith(
        "differed at the reset (reset_observation) after calls to this env that replay does not "
        "repeat (episode 0's reset and steps (its reset options are not in the file))"
    ), result.episodes[1].reason


def test_a_vector_envs_reset_options_replay_as_passed(tmp_path: Path) -> None:
    """Each sub-env was reset with the tuple (a point, not a path): so is its replay."""
    path = tmp_path / "v.mcap"
    with RecordVectorEvidence(gym.vector.SyncVectorEnv([TypedStart] * 2), path) as envs:
        envs.reset(seed=3, options={"goal": (0.5, -0.5)})
        for _ in range(5):
            envs.step(np.ones(2, np.int64))
    result = replay([path], env_factory=TypedStart)
    assert [e.status for e in result.episodes] == ["identical"] * 4


def _game(path: Path, options: dict[str, Any], **kwargs: Any) -> Path:
    with RecordParallelEvidence(rps_v2.parallel_env(**kwargs), path, env_kwargs=kwargs) as env:
        for seed, passed in [(0, options), (1, None)]:
            env.reset(seed=seed, options=passed)
            for _ in range(2):
                env.step(dict.fromkeys(env.agents, 1))
    return path


def test_a_game_reset_with_options_json_would_change_replays_them_as_passed(
    tmp_path: Path,
) -> None:
    path = _game(tmp_path / "o.mcap", {"limit": -math.inf, "start": (1, 2)}, max_cycles=2)
    resets = open_evidence(path).resets()
    typed = '{"limit":{"$float":"-inf"},"start":{"$tuple":[1,2]}}'
    assert sorted(
        zip(
            resets[fmt.COL_GAME].to_pylist(), resets[fmt.COL_OPTIONS_TYPED].to_pylist(), strict=True
        ),
        key=str,
    ) == [(0, typed), (0, typed), (1, None), (1, None)]
    assert replay([path]).count("identical") == 4


def test_a_game_reset_with_options_no_form_holds_is_not_replayable(tmp_path: Path) -> None:
    path = _game(tmp_path / "o.mcap", {"log": Logger()}, max_cycles=2)
    result = replay([path])
    assert [e.status for e in result.episodes] == ["not_replayable"] * 2 + ["identical"] * 2
    assert (result.episodes[0].reason or "").startswith(
        "its reset options are not in the file ({'log': <Logger>} (JSON has no Logger values; "
        "options_typed holds no Logger values)): replay cannot reset it as recorded"
    )


def test_game_env_kwargs_json_would_change_build_the_env_as_recorded(tmp_path: Path) -> None:
    """``max_cycles=inf`` (a game with no cut-off) made with ``"inf"`` would raise at its first
    step; an older reader refuses the placeholder JSON keeps in its place."""
    path = _game(tmp_path / "k.mcap", None, max_cycles=math.inf)
    layout = open_evidence(path).run.layout
    assert layout["env_kwargs"] == {
        "max_cycles": {"episode_audit.unrecorded": "float (exact in env_kwargs_typed)"}
    }
    assert layout["env_kwargs_typed"] == '{"max_cycles":{"$float":"inf"}}'
    assert replay([path]).count("identical") == 4

    def untyped(meta: dict[str, str]) -> dict[str, str]:
        older = json.loads(meta["layout"])
        del older["env_kwargs_typed"]
        return {**meta, "layout": json.dumps(older)}

    result = replay([rewrite(path, tmp_path / "older.mcap", run=untyped)])
    assert {(e.status, e.reason) for e in result.episodes} == {
        (
            "not_replayable",
            "the recorded env kwarg 'max_cycles' is not in the file (float (exact in "
            "env_kwargs_typed): JSON cannot hold it); pass --env-factory MODULE:CALLABLE that "
            "builds the env",
        )
    }


class _Cycles(enum.IntEnum):
    SHORT = 2


def test_game_env_kwargs_no_form_holds_need_an_env_factory(tmp_path: Path) -> None:
    """An ``IntEnum`` kwarg: JSON keeps a plain int, the typed form nothing; no reader builds
    the env from another value than it had."""
    path = _game(tmp_path / "k.mcap", None, max_cycles=_Cycles.SHORT)
    layout = open_evidence(path).run.layout
    assert "env_kwargs_typed" not in layout
    assert layout["notes"] == [
        "env_kwargs max_cycles: JSON has no _Cycles values; options_typed holds no _Cycles "
        "values: replay needs an env factory"
    ]
    result = replay([path])
    assert {(e.status, e.reason) for e in result.episodes} == {
        (
            "not_replayable",
            "the recorded env kwarg 'max_cycles' is not in the file (_Cycles (options_typed "
            "holds no _Cycles values: replay needs an env factory): JSON cannot hold it); pass "
            "--env-factory MODULE:CALLABLE that builds the env",
        )
    }
    assert replay([path], env_factory=lambda: rps_v2.parallel_env(max_cycles=2)).ok
