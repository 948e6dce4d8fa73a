"""``bench/run.py``'s pieces that hold assertions of their own, on a few episodes.

``make bench`` runs for minutes and is not part of ``make test``; a change to what it measures
(replay refusing the bench's ``Playback`` env) should fail here, not half way through a bench.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from episode_audit import RecordEvidence

BENCH = Path(__file__).resolve().parents[1] / "bench" / "run.py"


def _bench(monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.syspath_prepend(str(BENCH.parent))  # (its sibling modules)
    spec = importlib.util.spec_from_file_location("episode_audit_bench_run", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    return module


def test_replay_s_own_work_replays_every_episode_in_playback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Replay in ``Playback`` must find every episode identical (the bench asserts it)."""
    bench = _bench(monkeypatch)
    bench.TMP = tmp_path
    path = tmp_path / "cartpole.mcap"
    actions: dict[int, list[Any]] = {}
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.action_space.seed(0)
        for episode in range(3):
            env.reset(seed=episode)
            actions[episode] = []
            while True:
                action = env.action_space.sample()
                actions[episode].append(action)
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    break
    assert isinstance(bench.replay_own_seconds(path, "CartPole-v1", 1, actions), float)
