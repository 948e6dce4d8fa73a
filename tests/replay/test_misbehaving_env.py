"""Replay in an env whose returned values raise when read: one outcome per episode, no traceback.

The env is the user's (``env_factory``); the recorded file had plain values at every step, so a
value the replay cannot read where the recording had a number is a difference at that step,
naming the field (the file holds no spec to verify the factory's env against: the episode is
``not_replayable``, its difference kept).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, replay
from episode_audit.cli import app
from tests.support.envs import ScriptedEnv


class Unreadable:
    """A value every read of which raises (its float, truth, repr, str, index, array)."""

    def _no(self, *_: Any, **__: Any) -> Any:
        raise RuntimeError("cannot read me")

    __float__ = __bool__ = __repr__ = __str__ = __index__ = __len__ = __iter__ = _no
    __array__ = __int__ = _no


class UnprintableError(Exception):
    """An exception whose message raises."""

    def __str__(self) -> str:
        raise RuntimeError("no message")


def _plain(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
    return np.full(2, env.t / 10, np.float32), 1.0, env.t >= 3, False, {}


def _spoiled(field: str) -> ScriptedEnv:
    """The recorded env, but its second step returns an unreadable ``field`` (or raises); its
    last step's ``terminated``."""

    def step(env: ScriptedEnv, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        obs, reward, term, trunc, info = _plain(env, action)
        if env.t == 2:
            if field == "raise":
                raise UnprintableError
            obs = Unreadable() if field == "observation" else obs
            reward = Unreadable() if field == "reward" else reward
            info = {"x": Unreadable()} if field == "info" else info
        if env.t == 3 and field == "terminated":  # (recorded: True)
            term = Unreadable()
        return obs, reward, term, trunc, info

    return ScriptedEnv(step)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("plain") / "plain.mcap"
    with RecordEvidence(ScriptedEnv(_plain), path) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)
    return path


@pytest.mark.parametrize(
    ("field", "described"),
    [
        (
            "reward",
            "step 1: reward expected 1.0, got a reward that is not a number (float() raised "
            "RuntimeError: cannot read me)",
        ),
        (
            "raise",
            "step 1: step expected a step, got UnprintableError: <str() raised RuntimeError>",
        ),
        ("observation", "step 1: observation expected [0.20000000298023224, 0.2000000029802322"),
        ("terminated", "step 2: terminated expected True, got False"),
        ("info", None),
    ],
)
def test_a_value_the_replayed_env_returns_that_raises_is_a_divergence_not_a_traceback(
    recorded: Path, field: str, described: str | None
) -> None:
    """(A flag with no truth value is False, as the recorder takes it. An info value is not
    compared.)"""
    (episode,) = replay([recorded], env_factory=lambda: _spoiled(field)).episodes
    if described is None:
        assert episode.status == "identical"
        return
    assert episode.status == "not_replayable" and episode.divergence is not None
    assert episode.divergence.describe().startswith(described)


def spoiled_reward() -> ScriptedEnv:
    return _spoiled("reward")


def test_the_cli_says_so_in_one_row(recorded: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "replay",
            str(recorded),
            "--env-factory",
            f"{__name__}:spoiled_reward",
            "--format",
            "json",
        ],
    )
    assert result.exit_code == 1, result.output
    assert "float() raised RuntimeError: cannot read me" in result.stdout
