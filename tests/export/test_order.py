"""A Foxglove export's messages are in log-time order, in the file as in each chunk."""

from __future__ import annotations

import itertools
from functools import partial
from pathlib import Path

import pytest
from mcap.reader import make_reader

from episode_audit import open_evidence
from episode_audit.export import export
from tests.support.viewer_files import VIEWER_FILES, random_cartpole_file

MAKERS = {
    "flushed_often": partial(random_cartpole_file, steps=3_000, block_steps=64),  # many chunks
    **VIEWER_FILES,
}


@pytest.mark.parametrize("name", list(MAKERS))
def test_messages_are_written_in_log_time_order(tmp_path: Path, name: str) -> None:
    """Each chunk's resets were written before its steps, and every episode's event and log
    after all the steps: out of order in the file, and the SDK's chunks overlapped in time."""
    pytest.importorskip("foxglove")
    source = MAKERS[name](tmp_path / f"{name}.mcap")
    out = tmp_path / f"{name}.foxglove.mcap"
    result = export([source], out, to="foxglove")
    with open(out, "rb") as f:
        reader = make_reader(f)
        written = [
            (channel.topic, m.log_time)
            for _, channel, m in reader.iter_messages(log_time_order=False)
        ]
        summary = reader.get_summary()
    assert summary is not None
    times = [t for _, t in written]
    assert times == sorted(times)
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    for before, after in itertools.pairwise(chunks):
        assert before.message_end_time <= after.message_start_time
    ev = open_evidence(source)
    episodes = ev.episodes().num_rows
    topics = [topic for topic, _ in written]
    assert topics.count("/episodes") == topics.count("/log") == episodes == result.episodes
    steps = sum(1 for topic in topics if topic.endswith("/steps"))
    assert (
        steps
        == result.steps + result.resets
        == ev.steps(columns=["episode"]).num_rows + len(ev.resets())
    )
    if name == "flushed_often":
        assert len(list(ev.scan(steps=True, resets=True, episode_records=False))) > 10
