"""ALE Pong in worker sub-envs without ``ResetRngInfo``: its emulator state is not snapshot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit import check, replay

UNSAVED_WARNING = (
    r"^episode-audit: Record\w+: episodes an unseeded reset begins cannot be replayed: the "
    r"sub-envs' AtariEnv keeps state a seed does not set \(ale_py.AtariEnv\), and no "
    r"ResetRngInfo in them snapshot it"
)


def short_pong() -> gym.Env[Any, Any]:
    """ALE Pong (RAM), 4 steps an episode."""
    ale_py = pytest.importorskip("ale_py")
    gym.register_envs(ale_py)
    return gym.make("ALE/Pong-v5", obs_type="ram", max_episode_steps=4)


def assert_unseeded_episodes_are_not_replayable(path: Path) -> None:
    """Episodes 0 and 1 (seeded) replay; 2 and 3 (an explicit unseeded reset) are flagged."""
    (found,) = [f for f in check([path]).findings if f.code == "not_replayable"]
    assert found.message.startswith(
        "2 episode(s) began with an unseeded reset and cannot be replayed (episodes 2, 3): the "
        "sub-envs' AtariEnv keeps state a seed does not set (ale_py.AtariEnv)"
    ), found.message
    gym.register_envs(pytest.importorskip("ale_py"))  # (a SubprocVecEnv's workers registered it)
    results = {e.episode: (e.status, e.reason) for e in replay([path]).episodes}
    assert results[0] == results[1] == ("identical", None), results
    for episode in (2, 3):
        status, reason = results[episode]
        assert status == "not_replayable" and "no ale_py.AtariEnv snapshot" in str(reason)
