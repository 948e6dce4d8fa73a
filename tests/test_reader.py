from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from mcap.writer import Writer

from episode_audit import (
    CorruptEvidenceError,
    EvidenceError,
    NotEvidenceError,
    RecordEvidence,
    UnsupportedVersionError,
    open_evidence,
)
from episode_audit import format as fmt


def _record(path: Path, episodes: int = 4, block_steps: int = 16) -> Path:
    with RecordEvidence(gym.make("CartPole-v1"), path, block_steps=block_steps) as env:
        env.action_space.seed(0)
        env.reset(seed=0)
        for _ in range(episodes):
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
            env.reset()
    return path


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _record(tmp_path_factory.mktemp("rec") / "run.mcap")


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


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(NotEvidenceError, match=r"empty\.mcap: the file is empty"):
        open_evidence(path)


def test_garbage_file(tmp_path: Path) -> None:
    path = tmp_path / "garbage.mcap"
    path.write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(NotEvidenceError, match=r"garbage\.mcap: not an MCAP file"):
        open_evidence(path)


def test_mcap_that_is_not_evidence(tmp_path: Path) -> None:
    path = tmp_path / "other.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        writer.finish()
    with pytest.raises(NotEvidenceError, match="not evidence"):
        open_evidence(path)


def test_newer_major_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "future.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile=fmt.MCAP_PROFILE, library="future")
        writer.add_metadata(fmt.METADATA_RUN, {"format_version": "2.0"})
        writer.finish()
    with pytest.raises(UnsupportedVersionError, match=r"format 2\.0, newer than this reader"):
        open_evidence(path)


def test_metadata_with_missing_keys(tmp_path: Path) -> None:
    path = tmp_path / "partial.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile=fmt.MCAP_PROFILE, library="x")
        writer.add_metadata(fmt.METADATA_RUN, {"format_version": "1.0"})
        writer.finish()
    with pytest.raises(CorruptEvidenceError, match="run metadata lacks the key"):
        open_evidence(path)


def test_truncated_in_the_middle_of_a_block(recorded: Path, tmp_path: Path) -> None:
    data = recorded.read_bytes()
    ev = open_evidence(recorded)
    total = ev.steps().num_rows
    # cut inside the last chunk: every earlier chunk must survive
    cut = ev._chunks[-2].offset + 20
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[:cut])
    ev2 = open_evidence(torn)
    assert not ev2.finished
    assert ev2.torn is not None and "dropped" in ev2.torn
    kept = ev2.steps().num_rows
    assert 0 < kept < total
    episodes = ev2.episodes()
    ended = episodes.filter(pc.equal(episodes["ended"], True))
    assert ended.num_rows >= 1
    assert sum(episodes["length"].to_pylist()) == kept


@pytest.mark.parametrize("fraction", [0.001, 0.01, 0.3, 0.6, 0.95, 0.999])
def test_any_truncation_raises_only_evidence_errors(
    recorded: Path, tmp_path: Path, fraction: float
) -> None:
    data = recorded.read_bytes()
    torn = tmp_path / "cut.mcap"
    torn.write_bytes(data[: int(len(data) * fraction)])
    try:
        ev = open_evidence(torn)
        ev.episodes()
        ev.steps()
    except EvidenceError as exc:
        assert "cut.mcap" in str(exc)


def test_flipped_byte_inside_a_chunk_is_corruption(recorded: Path, tmp_path: Path) -> None:
    ev = open_evidence(recorded)
    data = bytearray(recorded.read_bytes())
    ref = ev._chunks[1]
    data[ref.offset + 60] ^= 0xFF
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(EvidenceError, match=r"flipped\.mcap: chunk at byte"):
        open_evidence(bad).steps()


def test_tables_are_arrow(recorded: Path) -> None:
    ev = open_evidence(recorded)
    assert isinstance(ev.episodes(), pa.Table)
    assert isinstance(ev.steps(), pa.Table)
    assert isinstance(ev.resets(), pa.Table)
