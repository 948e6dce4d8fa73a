"""Counting a block at flush (block.py): the common case of the same term names on every row
writes what the general case writes, byte for byte."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

import episode_audit.record.block as block_module
from episode_audit import RecordEvidence, open_evidence
from episode_audit.format.columns import text_array
from episode_audit.record.block import repeated_text, uniform_names
from tests.support.envs import ScriptedEnv


def _terms_step(changing: bool) -> Any:
    """A step with reward terms: the same names every time, or (``changing``) other names, in
    another order, on every third step."""

    def step(env: ScriptedEnv, action: Any) -> Any:
        a, b = env.np_random.uniform(-1, 1, 2)
        terms = {"reward_dist": a, "reward_ctrl": b}
        if changing and env.t % 3 == 0:
            terms = {"reward_ctrl": b, "reward_extra": a}
        obs = np.full(2, env.t / 100, np.float32)
        return obs, float(sum(terms.values())), env.t >= 7, False, terms

    return step


def _record(path: Path, changing: bool) -> None:
    with RecordEvidence(
        ScriptedEnv(_terms_step(changing)), path, block_steps=16, flush_every_s=3600
    ) as env:
        for episode in range(9):
            env.reset(seed=episode)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(0)
                done = terminated or truncated


def _contents(path: Path) -> list[tuple[str, bytes]]:
    """Every message's topic and bytes, in the file's order (their times differ: left out)."""
    with path.open("rb") as f:
        reader = make_reader(f)
        return [(c.topic, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]


@pytest.mark.parametrize("changing", [False, True], ids=["same names", "names change"])
def test_the_same_names_on_every_row_write_what_the_general_case_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, changing: bool
) -> None:
    fast, general = tmp_path / "fast.mcap", tmp_path / "general.mcap"
    _record(fast, changing)
    monkeypatch.setattr(block_module, "uniform_names", lambda keys, counts: None)
    _record(general, changing)
    ev = open_evidence(fast)
    assert ev.episodes().num_rows == 9
    totals = ev.episodes().column("term_totals").to_pylist()
    assert all(dict(t) for t in totals)  # (the terms were counted)
    fast_msgs, general_msgs = _contents(fast), _contents(general)
    assert [t for t, _ in fast_msgs] == [t for t, _ in general_msgs]
    for (topic, a), (_, b) in zip(fast_msgs, general_msgs, strict=True):
        if topic.endswith(("steps", "episodes", "episode_end")):
            # (time columns differ between two runs: compare the rows without them)
            assert _without_times(topic, a) == _without_times(topic, b), topic


def _without_times(topic: str, data: bytes) -> Any:
    if topic.endswith("episode_end"):
        import json

        record = json.loads(data)
        return {k: v for k, v in record.items() if not k.endswith("time_ns")}
    import pyarrow as pa

    table = pa.ipc.open_stream(data).read_all()
    return table.drop_columns([n for n in table.column_names if n.endswith("time_ns")])


def test_uniform_names_are_told_only_when_every_row_has_them_in_order() -> None:
    assert uniform_names(["a", "b"] * 3, np.array([2, 2, 2])) == ["a", "b"]
    assert uniform_names(["a", "b", "a"], np.array([2, 1])) is None
    assert uniform_names(["a", "b", "b", "a"], np.array([2, 2])) is None
    assert uniform_names([], np.array([], dtype=np.int64)) is None
    assert uniform_names([], np.array([0, 0])) is None


@pytest.mark.parametrize(
    "names", [["reward_dist", "reward_ctrl"], ["é", "x\udcff"], ["", "b"], ["one"]]
)
@pytest.mark.parametrize("times", [1, 2, 1000])
def test_repeated_text_is_the_text_array_of_the_repeated_names(
    names: list[str], times: int
) -> None:
    got, want = repeated_text(names, times), text_array(names * times)
    got.validate(full=True)
    assert got.equals(want)
    assert [b is None for b in got.buffers()] == [b is None for b in want.buffers()]
