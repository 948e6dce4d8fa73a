"""Counting a block at flush (block.py): the common case of the same term names on every row
writes what the general case writes, byte for byte."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from mcap.reader import make_reader

import episode_audit.record.block as block_module
import episode_audit.record.counting as counting_module
from episode_audit import RecordEvidence, open_evidence
from episode_audit.format.columns import text_array
from episode_audit.record import native
from episode_audit.record.counting import repeated_text, uniform_names
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
    monkeypatch.setattr(counting_module, "uniform_names", lambda keys, counts: None)
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
@pytest.mark.parametrize("compiled", [False, True], ids=["Python", "compiled"])
def test_repeated_text_is_the_text_array_of_the_repeated_names(
    names: list[str], times: int, compiled: bool
) -> None:
    if compiled and native.NATIVE is None:
        pytest.skip("the extension is not built")
    got = repeated_text(names, times, native.NATIVE if compiled else None)
    want = text_array(names * times)
    got.validate(full=True)
    assert got.equals(want)
    assert [b is None for b in got.buffers()] == [b is None for b in want.buffers()]
    batches = [pa.RecordBatch.from_arrays([a], names=["k"]) for a in (got, want)]
    assert batches[0].serialize().to_pybytes() == batches[1].serialize().to_pybytes()


def test_totals_sum_each_episodes_counted_values_in_the_order_names_first_appear() -> None:
    class Running:
        def __init__(self) -> None:
            self.totals: dict[str, float] = {"earlier": 1.0}

    episodes = {3: Running(), 4: Running()}
    # episode 3: b, then a; episode 4: a, b, c (c's row not counted)
    names = ["a", "b", "c"]
    episode_of = np.array([3, 3, 3, 4, 4, 4, 4], dtype=np.int64)
    code_of = np.array([1, 0, 1, 0, 1, 0, 2], dtype=np.int64)
    counted = np.array([True, True, True, True, True, False, False])
    values = np.array([0.5, 2.0, 0.25, 4.0, 8.0, 16.0, 32.0])
    counting_module._add_totals(episodes, names, episode_of, code_of, counted, values)
    assert list(episodes[3].totals.items()) == [("earlier", 1.0), ("b", 0.75), ("a", 2.0)]
    assert list(episodes[4].totals.items()) == [("earlier", 1.0), ("a", 4.0), ("b", 8.0)]


def test_totals_of_many_rows_agree_with_an_exact_sum() -> None:
    class Running:
        def __init__(self) -> None:
            self.totals: dict[str, float] = {}

    rng = np.random.default_rng(7)
    rows = 5_000
    episode_of = np.sort(rng.integers(0, 40, rows)).astype(np.int64)
    values = rng.standard_normal(rows) * 10.0 ** rng.integers(-3, 4, rows)
    episodes = {int(e): Running() for e in episode_of}
    zeros = np.zeros(rows, dtype=np.int64)
    counting_module._add_totals(
        episodes, ["r"], episode_of, zeros, np.ones(rows, dtype=np.bool_), values
    )
    for index, episode in episodes.items():
        exact = math.fsum(values[episode_of == index].tolist())
        assert episode.totals["r"] == pytest.approx(exact, rel=1e-12, abs=1e-9)


# ---------------------------------------------------------------------- compiled counting


def _random_block(rng: np.random.Generator) -> tuple[Any, dict[int, Any]]:
    """A block of random segments (rows before any reset, rows after an ending, empty ones),
    rewards and terms (the same names on every row, or not; odd names), and its episodes with
    running totals."""
    from array import array

    from gymnasium import spaces

    from episode_audit.format.spaces import codec_for
    from episode_audit.record.block import Block, Episode

    codec = codec_for(spaces.Discrete(2))
    block = Block(codec, codec, None)
    n = int(rng.integers(1, 60))
    starts = sorted(rng.integers(0, n + 1, int(rng.integers(0, 6))).tolist())
    episodes: dict[int, Any] = {}
    for i, start in enumerate(starts):
        episode = episodes.get(i - 1) if rng.random() < 0.2 else None
        if episode is None:
            episode = Episode(10 + i, None, None, None, 0)
            episode.ret = float(rng.normal() * 10.0 ** rng.integers(-3, 4))
            episode.totals = {"a": 0.5} if rng.random() < 0.5 else {}
            episodes[i] = episode
        block.add_segment(start, episode, int(rng.integers(0, 9)), bool(rng.random() < 0.8))
    block.times = array("q", sorted(rng.integers(0, 10**12, n).tolist()))
    block.rewards = array("d", (rng.normal(size=n) * 10.0 ** rng.integers(-8, 8, n)).tolist())
    names = [["a", "b"], ["b", "a", "c"], ["a"], ["é", "x\udcff"], ["a", "a"], [b"a", "a"]]
    uniform = names[int(rng.integers(0, len(names)))]
    for row in sorted(set(rng.integers(0, n, int(rng.integers(0, n + 1))).tolist())):
        keys = uniform if rng.random() < 0.9 else names[int(rng.integers(0, 3))]
        block.add_terms(row, keys, rng.normal(size=len(keys)).tolist())
    block.raw_names = bool(rng.random() < 0.5)
    return block, {ep.index: ep for ep in episodes.values()}


def _state(episodes: dict[int, Any]) -> list[Any]:
    return [
        (
            i,
            ep.steps,
            ep.after_end,
            ep.end_ns,
            repr(ep.ret),
            [(k, repr(v)) for k, v in ep.totals.items()],
        )
        for i, ep in sorted(episodes.items())
    ]


@pytest.mark.skipif(native.NATIVE is None, reason="the extension is not built")
def test_the_compiled_counting_is_the_python_counting() -> None:
    """Over random blocks: the same columns, terms column and episode counts, bit for bit."""
    taken = 0
    for seed in range(600):
        (block, _), (twin, _), (probe, _) = (
            _random_block(np.random.default_rng(seed)) for _ in range(3)
        )
        n = len(block.times)
        taken += native.NATIVE.count_rows(probe, n) is not None
        got = counting_module.count_block(block, n, native.NATIVE)
        want = counting_module.count_block(twin, n)
        assert got[0].tolist() == want[0].tolist() and got[1].tolist() == want[1].tolist()
        a, b = (pa.RecordBatch.from_arrays([t[2]], names=["t"]) for t in (got, want))
        assert a.serialize().to_pybytes() == b.serialize().to_pybytes()
        assert _state(block.episodes) == _state(twin.episodes)
    assert taken > 400  # (most blocks are counted in C)


@pytest.mark.parametrize("pure", [False, True], ids=["compiled", "pure Python"])
def test_returns_and_totals_do_not_depend_on_where_flushes_cut_episodes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pure: bool
) -> None:
    """Running sums: the same return and totals, to the bit, whatever the blocks, and the sum
    a loop adds up itself."""
    if pure:
        monkeypatch.setenv(native.PURE_PYTHON_ENV, "1")

    def step(env: ScriptedEnv, action: Any) -> Any:
        a, b = env.np_random.normal(size=2) * 10.0 ** env.np_random.integers(-6, 6, 2)
        return np.zeros(2, np.float32), float(a + b), env.t >= 40, False, {"x": a, "y": b}

    records = []
    for block_steps in (1, 3, 7, 64):
        path = tmp_path / f"{block_steps}.mcap"
        sums = []
        with RecordEvidence(
            ScriptedEnv(step), path, block_steps=block_steps, flush_every_s=3600
        ) as env:
            for episode in range(3):
                env.reset(seed=episode)
                total, done = 0.0, False
                while not done:
                    _, reward, terminated, truncated, _ = env.step(0)
                    total += reward
                    done = terminated or truncated
                sums.append(total)
        table = open_evidence(path).episodes()
        returns = table.column("return").to_pylist()
        assert [repr(r) for r in returns] == [repr(s) for s in sums]
        records.append((returns, table.column("term_totals").to_pylist()))
    assert all(r == records[0] for r in records)


@pytest.mark.parametrize("compiled", [False, True], ids=["Python", "compiled"])
def test_sparse_text_is_the_text_array_of_the_rows(compiled: bool) -> None:
    """The same array and IPC bytes as the dense list, for rows in any order and any texts."""
    if compiled and native.NATIVE is None:
        pytest.skip("the extension is not built")
    rng = np.random.default_rng(5)
    texts = ["truncated", "", "é", "x\udcff", None, 'q"\\', 7]
    for _ in range(400):
        n = int(rng.integers(1, 150))
        rows = rng.integers(0, n, int(rng.integers(0, n + 1))).tolist()
        if rng.random() < 0.8:
            rows = sorted(set(rows))
        values = {row: texts[int(rng.integers(0, len(texts)))] for row in rows}
        got = block_module.sparse_text(n, values, native.NATIVE if compiled else None)
        want = text_array([values.get(row) for row in range(n)])
        got.validate(full=True)
        batches = [pa.RecordBatch.from_arrays([a], names=["t"]) for a in (got, want)]
        assert batches[0].serialize().to_pybytes() == batches[1].serialize().to_pybytes()


@pytest.mark.skipif(native.NATIVE is None, reason="the extension is not built")
@pytest.mark.parametrize(
    "odd",
    ["int return", "list segment", "int total", "rows past the block", "episode missing"],
)
def test_the_compiled_counting_declines_what_it_does_not_take(odd: str) -> None:
    """An odd block is declined untouched (None), and counted by the Python as ever."""
    seed = next(
        s
        for s in range(200)
        if len(_random_block(np.random.default_rng(s))[0].segments) >= 2
        and _random_block(np.random.default_rng(s))[0].term_rows
    )
    (block, _), (twin, _) = (_random_block(np.random.default_rng(seed)) for _ in range(2))
    n = len(block.times)
    for b in (block, twin):
        first = next(iter(b.episodes.values()))
        if odd == "int return":
            first.ret = 3
        elif odd == "list segment":
            b.segments[0] = list(b.segments[0])  # type: ignore[call-overload]
        elif odd == "int total":
            first.totals = {"a": 1}
        elif odd == "episode missing":
            b.episodes.clear()
    before = _state(block.episodes)
    rows = n + 1 if odd == "rows past the block" else n
    assert native.NATIVE.count_rows(block, rows) is None
    assert _state(block.episodes) == before  # (nothing changed)
    if odd in ("rows past the block", "episode missing"):
        return
    got = counting_module.count_block(block, n, native.NATIVE)
    want = counting_module.count_block(twin, n)
    assert got[0].tolist() == want[0].tolist() and got[1].tolist() == want[1].tolist()
    assert _state(block.episodes) == _state(twin.episodes)
