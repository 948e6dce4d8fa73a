"""The Evidence API: tables, column and episode selection, streaming, one episode."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest

from episode_audit import (
    EvidenceError,
    open_evidence,
)


def test_episodes_steps_and_selection(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert ev.finished and ev.torn is None
    assert ev.run_end is not None and ev.run_end["status"] == "finished"
    episodes = ev.episodes()
    assert episodes.num_rows == 5  # 4 ended + the last reset, closed as incomplete
    assert episodes["outcome"].to_pylist()[:4] == ["failure"] * 4
    assert episodes["outcome"].to_pylist()[4] == "incomplete"
    steps = ev.steps(columns=["episode", "step", "reward"])
    assert steps.column_names == ["episode", "step", "reward"]
    assert steps.num_rows == sum(episodes["length"].to_pylist())
    only = ev.steps(episodes=[2])
    assert set(only["episode"].to_pylist()) == {2}
    assert only["step"].to_pylist() == list(range(only.num_rows))
    assert only.num_rows == episodes["length"].to_pylist()[2]


def test_episode_reads_only_its_own_rows(recorded: Path) -> None:
    ev = open_evidence(recorded)
    for record in ev.episodes().to_pylist():
        episode = ev.episode(record["episode"])
        assert episode.steps.num_rows == record["length"]
        assert episode.reset is not None and episode.reset["episode"] == record["episode"]
    with pytest.raises(EvidenceError, match="no episode 99"):
        ev.episode(99)


def test_iter_step_batches_streams_blocks(recorded: Path) -> None:
    ev = open_evidence(recorded)
    batches = list(ev.iter_step_batches(columns=["reward"]))
    assert len(batches) > 2
    assert all(b.num_rows <= 16 for b in batches)


def test_tables_are_arrow(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert isinstance(ev.episodes(), pa.Table)
    assert isinstance(ev.steps(), pa.Table)
    assert isinstance(ev.resets(), pa.Table)
