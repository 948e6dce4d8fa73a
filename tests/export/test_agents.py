"""PettingZoo agents in the viewer exports: one stream each, whatever their names."""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from mcap.reader import make_reader
from pettingzoo import ParallelEnv

from episode_audit import RecordParallelEvidence, open_evidence
from episode_audit.export import export

AGENTS = ["a/b", "a b", "a_b"]
"""Three names that are one once cleaned for a topic (``a_b``)."""
PREFIXES = {"a_b": "/a_b", "a b": "/a_b-2", "a/b": "/a_b-3"}


class _Alike(ParallelEnv):  # type: ignore[misc]
    metadata = {"name": "alike_v0"}
    possible_agents = AGENTS

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return spaces.Box(-1, 1, (2,), np.float32)

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return spaces.Discrete(2)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.agents, self.t = list(self.possible_agents), 0
        return {a: np.zeros(2, np.float32) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> Any:
        self.t += 1
        obs = {a: np.full(2, self.t / 10, np.float32) for a in self.agents}
        # each agent its own reward, so that a stream mixing agents shows
        rewards = {a: float(self.possible_agents.index(a) + self.t / 10) for a in self.agents}
        done = self.t >= 3
        flags = {a: False for a in self.agents}
        ends = {a: done for a in self.agents}
        if done:
            self.agents = []
        return obs, rewards, flags, ends, {a: {} for a in obs}


@pytest.fixture(scope="module")
def alike(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("agents") / "alike.mcap"
    with RecordParallelEvidence(_Alike(), path) as env:
        for seed in (0, 1):
            env.reset(seed=seed)
            while env.agents:
                env.step({a: 0 for a in env.agents})
    return path


def _agent_of(path: Path) -> dict[int, str]:
    episodes = open_evidence(path).episodes()
    return dict(
        zip(
            episodes.column("episode").to_pylist(),
            episodes.column("agent").to_pylist(),
            strict=True,
        )
    )


def test_foxglove_topics_are_one_per_agent_and_keep_its_name(alike: Path, tmp_path: Path) -> None:
    """``a/b``, ``a b`` and ``a_b`` were one ``/a_b/steps`` channel, and ``/episodes`` and
    ``/log`` said ``a_b`` of all three."""
    pytest.importorskip("foxglove")
    from mcap_protobuf.decoder import DecoderFactory

    out = tmp_path / "alike.foxglove.mcap"
    result = export([alike], out, to="foxglove")
    agent_of = _agent_of(alike)
    ev = open_evidence(alike)
    steps = ev.steps().to_pylist()
    rewards = {(s["episode"], s["step"]): s["reward"] for s in steps}
    expected = Counter(PREFIXES[agent_of[s["episode"]]] for s in steps)
    expected.update(PREFIXES[agent_of[r["episode"]]] for r in ev.resets().to_pylist())
    assert sorted(result.paths) == sorted(
        [f"{p}/steps" for p in PREFIXES.values()] + ["/episodes", "/log"]
    )
    decode = DecoderFactory()
    seen: Counter[str] = Counter()
    events, logs = [], []
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/steps"):
                prefix = channel.topic.removesuffix("/steps")
                data = json.loads(message.data)
                agent = agent_of[data["episode"]]
                assert PREFIXES[agent] == prefix and channel.metadata == {"agent": agent}
                if data["step"] >= 0:  # the values are the evidence file's
                    assert data["reward"] == rewards[(data["episode"], data["step"])]
                seen[prefix] += 1
            elif channel.topic == "/episodes":
                events.append(decode.decoder_for("protobuf", schema)(message.data))
            elif channel.topic == "/log":
                logs.append(decode.decoder_for("protobuf", schema)(message.data))
    assert seen == expected
    assert len(events) == len(logs) == len(agent_of) == 6
    for event in events:
        pairs = {kv.key: kv.value for kv in event.metadata}
        agent = agent_of[int(pairs["episode"])]
        assert (pairs["agent"], "/" + pairs["stream"]) == (agent, PREFIXES[agent])
    assert sorted(log.name for log in logs) == sorted(agent_of.values())
    assert all(log.message.startswith(f"{log.name} episode ") for log in logs)


def test_rerun_entities_are_one_per_agent(alike: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    out = tmp_path / "alike.rrd"
    result = export([alike], out, to="rerun")
    agent_of = _agent_of(alike)
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(out).stream():
        rows[chunk.entity_path].extend(chunk.to_record_batch().to_pylist())
    ev = open_evidence(alike)
    for step in ev.steps().to_pylist():
        prefix = PREFIXES[agent_of[step["episode"]]]
        (row,) = [
            r
            for r in rows[f"{prefix}/steps/reward"]
            if (r["episode"], r["step"]) == (step["episode"], step["step"])
        ]
        assert row["Scalars:scalars"] == [step["reward"]]
    for prefix in PREFIXES.values():
        assert len(rows[f"{prefix}/steps/reward"]) == 6  # 2 games of 3 steps
    assert {p for p in result.paths if p.endswith("/reward")} == {
        f"{p}/steps/reward" for p in PREFIXES.values()
    }
    texts = sorted(r["TextLog:text"][0] for r in rows["/log"])
    assert [t.split(" episode ")[0] for t in texts] == sorted(agent_of.values())
