"""One pass over a file: each chunk read once, what a pass keeps, and its caches."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from types import ModuleType
from typing import Any

import pyarrow.compute as pc
import pytest

from episode_audit import (
    CorruptEvidenceError,
    open_evidence,
    read,
)
from episode_audit.format import names as fmt
from episode_audit.read import blocks, chunks, evidence, passes
from tests.read.helpers import rewrite


def _count_chunk_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    reads: list[int] = []
    original = chunks._read_chunk_record

    def counting(f: Any, ref: Any, path: Path) -> Any:
        reads.append(ref.offset)
        return original(f, ref, path)

    monkeypatch.setattr(chunks, "_read_chunk_record", counting)
    return reads


def _count_decodes(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    topics: list[str] = []
    original = blocks._arrow_batch

    def counting(data: Any, path: Path, topic: str) -> Any:
        topics.append(topic)
        return original(data, path, topic)

    for module in _wing_modules_with("_arrow_batch"):  # blocks, and passes (step blocks)
        monkeypatch.setattr(module, "_arrow_batch", counting)
    return topics


def _wing_modules_with(name: str) -> list[ModuleType]:
    """The read wing's modules that look ``name`` up in their own namespace."""
    wing = "episode_audit.read"
    found = [
        importlib.import_module(f"{wing}.{m.name}") for m in pkgutil.iter_modules(read.__path__)
    ]
    modules = [module for module in found if name in vars(module)]
    assert {m.__name__ for m in modules} >= {f"{wing}.blocks", f"{wing}.passes"}
    return modules


def test_check_reads_each_chunk_once(recorded: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from episode_audit import check

    expected = check([recorded]).to_dict()
    reads = _count_chunk_reads(monkeypatch)
    assert check([recorded]).to_dict() == expected
    assert sorted(reads) == sorted(r.offset for r in open_evidence(recorded)._chunks)


def test_episodes_and_resets_are_cached(recorded: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ev = open_evidence(recorded)
    reads = _count_chunk_reads(monkeypatch)
    episodes, resets = ev.episodes(), ev.resets()
    n = len(reads)
    assert n == len(ev._chunks)  # one pass for both
    assert ev.episodes() is episodes and ev.resets() is resets
    assert len(reads) == n


def test_past_a_size_episodes_keeps_the_resets_without_their_observations(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An image observation is ~100 kB a reset: episodes() (report, compare, show) keeps the
    # reset rows it needs without them; resets() reads them again, observations and all.
    whole = open_evidence(recorded)
    expected_episodes, expected_resets = whole.episodes(), whole.resets()
    assert not whole._gathered.slim  # (under SLIM_ABOVE: one pass for both, as above)
    monkeypatch.setattr(evidence, "SLIM_ABOVE", 100)
    ev = open_evidence(recorded)
    assert ev.episodes().equals(expected_episodes)
    gathered = ev._gathered
    assert gathered is not None and gathered.slim
    kept = [b for b in gathered.resets if not isinstance(b, (bytes, memoryview))]
    assert kept and all(fmt.COL_OBSERVATION not in b.schema.names for b in kept)
    reads = _count_chunk_reads(monkeypatch)
    assert ev.resets().equals(expected_resets)
    assert 0 < len(reads) <= len(ev._chunks)


def test_episodes_of_a_finished_file_decode_no_step_block(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    expected = open_evidence(recorded).episodes()
    topics = _count_decodes(monkeypatch)
    ev = open_evidence(recorded)
    assert ev.episodes().equals(expected)
    assert fmt.TOPIC_STEPS not in topics
    assert 0 < topics.count(fmt.TOPIC_RESETS) <= len(ev._chunks)


def test_a_pass_decodes_reset_and_episode_blocks_as_they_come(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ev = open_evidence(recorded)
    topics = _count_decodes(monkeypatch)
    for _ in ev.iter_step_batches():
        assert topics.count(fmt.TOPIC_RESETS) <= topics.count(fmt.TOPIC_STEPS)
    during = len(topics)
    assert topics.count(fmt.TOPIC_RESETS) > 0 and topics.count(fmt.TOPIC_EPISODES) > 0
    ev.resets()
    ev.episodes()
    assert len(topics) == during  # nothing left to decode at the end


@pytest.mark.parametrize("topic", [fmt.TOPIC_RESETS, fmt.TOPIC_EPISODES])
def test_a_bad_reset_or_episode_block_fails_where_it_is_asked_for(
    recorded: Path, tmp_path: Path, topic: str
) -> None:
    bad = rewrite(recorded, tmp_path / "bad.mcap", replace={(topic, 1): b"not arrow"})
    ev = open_evidence(bad)
    assert sum(b.num_rows for b in ev.iter_step_batches()) == ev.steps().num_rows > 0
    asked = ev.resets if topic == fmt.TOPIC_RESETS else ev.episodes
    with pytest.raises(CorruptEvidenceError, match=f"a block on {topic} is not a valid Arrow"):
        asked()
    # the same error as a reader that never streamed the steps
    with pytest.raises(CorruptEvidenceError, match=f"a block on {topic} is not a valid Arrow"):
        (open_evidence(bad).resets if topic == fmt.TOPIC_RESETS else open_evidence(bad).episodes)()


def test_a_pass_over_the_steps_keeps_resets_and_episodes_within_a_limit(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ev = open_evidence(recorded)
    reads = _count_chunk_reads(monkeypatch)
    list(ev.iter_step_batches())
    ev.resets()
    ev.episodes()
    assert len(reads) == len(ev._chunks)
    monkeypatch.setattr(passes, "KEEP_LIMIT", 100)
    reads.clear()
    ev = open_evidence(recorded)
    for _ in ev._pass(steps=True):  # what iter_step_batches does, with the limit patched
        pass
    assert ev._gathered is None
    ev.episodes()
    assert len(reads) == 2 * len(ev._chunks)


def test_torn_file_episodes_are_counted_from_steps_in_one_pass(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    full = open_evidence(recorded)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(recorded.read_bytes()[: full._chunks[-3].offset + 20])
    ev = open_evidence(torn)
    assert not ev.finished
    reads = _count_chunk_reads(monkeypatch)
    steps = ev.steps()
    episodes = ev.episodes()
    assert len(reads) == len(ev._chunks)  # counted during the pass over the steps
    resets = {r["episode"]: r for r in ev.resets().to_pylist()}
    full_rows = {r["episode"]: r for r in full.episodes().to_pylist()}
    cut = 0
    for row in episodes.to_pylist():
        mine = steps.filter(pc.equal(steps["episode"], row["episode"]))
        if row["ended"]:
            assert row == full_rows[row["episode"]]
            continue
        cut += 1
        reset = resets[row["episode"]]
        assert row["outcome"] == "incomplete" and row["term_totals"] is None
        assert row["length"] == mine.num_rows
        assert row["return"] == sum(mine["reward"].to_pylist())
        assert row["start_time_ns"] == reset["time_ns"]
        assert row["end_time_ns"] == max(mine["time_ns"].to_pylist(), default=reset["time_ns"])
        assert (row["seed"], row["rng_state"]) == (reset["seed"], reset["rng_state"])
    assert cut == 1
    # and the same without a pass over the steps first (one pass of its own)
    reads.clear()
    assert open_evidence(torn).episodes().equals(episodes)
    assert len(reads) == len(ev._chunks)
