from __future__ import annotations

import importlib
import json
import pkgutil
import random
import struct
import zlib
from pathlib import Path
from types import ModuleType
from typing import Any

import gymnasium as gym
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from episode_audit import (
    CorruptEvidenceError,
    EvidenceError,
    NotEvidenceError,
    RecordEvidence,
    UnsupportedVersionError,
    open_evidence,
    read,
)
from episode_audit.format import names as fmt
from episode_audit.read import blocks, chunks, episodes, passes


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


@pytest.mark.parametrize("cut", [100, 1000, 1400])
def test_a_file_torn_before_its_run_metadata_says_so(tmp_path: Path, cut: int) -> None:
    """Not "not an evidence file": its header names our profile; the recorder died starting."""
    path = tmp_path / "early.mcap"
    path.write_bytes((Path(__file__).parents[2] / "fixtures" / "clean.mcap").read_bytes()[:cut])
    with pytest.raises(
        CorruptEvidenceError,
        match=rf"early\.mcap: an evidence file torn before its run metadata was written "
        rf"\(torn at byte 57 of {cut}: .*\): it holds no evidence",
    ):
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


# --------------------------------------------------------------------------- fast chunk reader


def _rewrite(
    src: Path,
    dst: Path,
    *,
    compression: CompressionType = CompressionType.NONE,
    chunk_size: int = 4096,
    end_records: list[bytes] | None = None,
    replace: dict[tuple[str, int], bytes] | None = None,
) -> Path:
    """Copy an evidence file through mcap's own reader and writer (records kept in order).

    With ``end_records`` the episode records are replaced by those (written after the rest).
    ``replace`` maps (topic, i) to new data for the i-th message on that topic.
    """
    seen: dict[str, int] = {}
    with open(src, "rb") as f:
        mcap = make_reader(f)
        header = mcap.get_header()
        summary = mcap.get_summary()
        assert summary is not None
        metadata = {m.name: dict(m.metadata) for m in mcap.iter_metadata()}
        messages = [(c, m) for _, c, m in mcap.iter_messages(log_time_order=False)]
    with open(dst, "wb") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=compression)
        writer.start(profile=header.profile, library="test")
        for sid in sorted(summary.schemas):
            s = summary.schemas[sid]
            assert writer.register_schema(s.name, s.encoding, s.data) == sid
        for cid in sorted(summary.channels):
            c = summary.channels[cid]
            if end_records is not None and c.topic == fmt.TOPIC_EPISODES:
                continue  # a file of JSON end records only (the Arrow copies would win)
            new = writer.register_channel(c.topic, c.message_encoding, c.schema_id, c.metadata)
            assert new == cid
        writer.add_metadata(fmt.METADATA_RUN, metadata[fmt.METADATA_RUN])
        ends = [cid for cid, c in summary.channels.items() if c.topic == fmt.TOPIC_EPISODE_END]
        last = 0
        for channel, message in messages:
            last = max(last, message.log_time)
            if end_records is not None and channel.topic in (
                fmt.TOPIC_EPISODE_END,
                fmt.TOPIC_EPISODES,
            ):
                continue
            i = seen[channel.topic] = seen.get(channel.topic, -1) + 1
            data = (replace or {}).get((channel.topic, i), message.data)
            writer.add_message(
                channel.id, message.log_time, data, message.publish_time, message.sequence
            )
        for i, data in enumerate(end_records or []):
            writer.add_message(ends[0], last + 1 + i, data, last + 1 + i, 0)
        writer.add_metadata(fmt.METADATA_RUN_END, metadata[fmt.METADATA_RUN_END])
        writer.finish()
    return dst


def _mcap_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message, in file order, as mcap's own reader sees it."""
    with open(path, "rb") as f:
        return [
            (c.topic, m.log_time, m.data)
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def _split_file(path: Path) -> list[tuple[str, int, bytes]]:
    """The same, from the fast chunk reader and splitter."""
    ev = open_evidence(path)
    topic_of = {0: fmt.TOPIC_STEPS, 1: fmt.TOPIC_RESETS, 2: fmt.TOPIC_EPISODE_END}
    route = {cid: chunks._SLOTS.get(c.topic, -1) for cid, c in ev._channels.items()}
    out = []
    with open(path, "rb") as f:
        for ref in ev._chunks:
            raw = chunks._read_chunk_record(f, ref, path)
            data = chunks._decompress(raw, path, ref.offset)
            messages = chunks._split(data, path, ref.offset, route, (True,) * 3, [], None)
            out.extend((topic_of[slot], t, view.tobytes()) for slot, t, view, _ in messages)
    return out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_splitter_equals_mcaps_own_reader(recorded: Path, tmp_path: Path, compression: str) -> None:
    path = recorded
    if compression != "zstd":
        kind = CompressionType.LZ4 if compression == "lz4" else CompressionType.NONE
        path = _rewrite(recorded, tmp_path / f"{compression}.mcap", compression=kind)
    expected = _mcap_messages(path)
    assert len(expected) > 10
    assert _split_file(path) == [m for m in expected if m[0] in chunks._SLOTS]
    # and the public single pass yields the same blocks and records, chunk by chunk
    ev = open_evidence(path)
    contents = list(ev.scan())
    assert len(contents) == len(ev._chunks)
    steps = [b for c in contents for b in c.steps]
    assert pa.Table.from_batches(steps).equals(open_evidence(recorded).steps())
    assert pa.Table.from_batches([b for c in contents for b in c.resets]).equals(
        open_evidence(recorded).resets()
    )
    records = [r for c in contents for r in c.episode_records]
    # files with Arrow episode blocks: those are the records a pass reads
    assert records == [d for t, _, d in expected if t == fmt.TOPIC_EPISODES]
    assert ev.episodes().equals(open_evidence(recorded).episodes())


def _patched(data: bytes, at: int, value: bytes) -> bytearray:
    out = bytearray(data)
    out[at : at + len(value)] = value
    return out


def _uncompressed_chunk(path: Path, index: int) -> tuple[int, int, int]:
    """(chunk offset, offset of its records in the file, their length) of an uncompressed file."""
    ref = open_evidence(path)._chunks[index]
    data = path.read_bytes()
    name_length = struct.unpack_from("<I", data, ref.offset + 9 + 28)[0]
    at = ref.offset + 9 + 32 + name_length
    (length,) = struct.unpack_from("<Q", data, at)
    return ref.offset, at + 8, length


@pytest.mark.parametrize("fix_crc", [True, False])
@pytest.mark.parametrize(
    ("which", "new_length", "why"),
    [
        (1, 1 << 40, "overruns"),  # a record claims more bytes than the chunk holds
        (0, 5, "is 5 bytes"),  # a message too short for its own header
    ],
)
def test_corrupted_record_length_is_corruption(
    recorded: Path, tmp_path: Path, fix_crc: bool, which: int, new_length: int, why: str
) -> None:
    plain = _rewrite(recorded, tmp_path / "plain.mcap")
    offset, records_at, records_length = _uncompressed_chunk(plain, 1)
    data = plain.read_bytes()
    # find the message records of the chunk and corrupt the length of the chosen one
    steps_channel = next(
        cid for cid, c in open_evidence(plain)._channels.items() if c.topic == fmt.TOPIC_STEPS
    )
    pos, found, on_steps = records_at, [], []
    while pos < records_at + records_length:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x05:
            found.append(pos)
            if struct.unpack_from("<H", data, pos + 9)[0] == steps_channel:
                on_steps.append(pos)
        pos += 9 + length
    # the damaged message is one a read needs (a step block), or the chunk's first message
    target = on_steps[0] if which == 1 else found[which]
    bad = _patched(data, target + 1, struct.pack("<Q", new_length))
    crc_at = offset + 9 + 24
    crc = zlib.crc32(bad[records_at : records_at + records_length]) if fix_crc else 0
    bad[crc_at : crc_at + 4] = struct.pack("<I", crc)
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(bad))
    ev = open_evidence(path)
    with pytest.raises(CorruptEvidenceError, match=rf"bad\.mcap: chunk at byte {offset} .*{why}"):
        ev.steps()
    # episodes() of a finished file reads only what its message index points at: a damaged
    # step block it does not need is not its business (check still finds it through steps)
    try:
        open_evidence(path).episodes()
    except CorruptEvidenceError as exc:
        assert f"chunk at byte {offset}" in str(exc)


def test_crc_mismatch_and_bad_sizes_are_corruption(recorded: Path, tmp_path: Path) -> None:
    plain = _rewrite(recorded, tmp_path / "plain.mcap")
    offset, records_at, _ = _uncompressed_chunk(plain, 1)
    data = plain.read_bytes()
    cases = {
        "crc.mcap": (_patched(data, records_at + 40, b"\xff"), "CRC mismatch"),
        "size.mcap": (
            _patched(data, offset + 9 + 16, struct.pack("<Q", 7)),
            "holds .* bytes, not the declared 7",
        ),
        "huge.mcap": (
            _patched(data, offset + 9 + 16, struct.pack("<Q", 1 << 50)),
            "declares 1125899906842624 uncompressed bytes",
        ),
    }
    for name, (bad, why) in cases.items():
        path = tmp_path / name
        path.write_bytes(bytes(bad))
        with pytest.raises(CorruptEvidenceError, match=rf"{name}: chunk at byte {offset} .*{why}"):
            open_evidence(path).steps()


def test_zstd_frame_larger_than_the_chunk_says_is_refused_before_decompressing(
    recorded: Path, tmp_path: Path
) -> None:
    ev = open_evidence(recorded)
    ref = ev._chunks[1]
    bad = _patched(recorded.read_bytes(), ref.offset + 9 + 16, struct.pack("<Q", 100))
    path = tmp_path / "frame.mcap"
    path.write_bytes(bytes(bad))
    with pytest.raises(CorruptEvidenceError, match=r"zstd frame declares \d+ bytes, the chunk 100"):
        open_evidence(path).steps()


@pytest.mark.parametrize("arrow", [True, False])
def test_zstd_chunks_read_the_same_with_either_decompressor(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, arrow: bool
) -> None:
    """Arrow's zstd (into its memory pool) where pyarrow has it, else ``zstandard``."""
    expected = open_evidence(recorded).steps()
    monkeypatch.setattr(chunks, "_ARROW_ZSTD", arrow)
    assert open_evidence(recorded).steps().equals(expected)
    bad = _patched(recorded.read_bytes(), open_evidence(recorded)._chunks[1].offset + 200, b"\x00")
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(bad))
    with pytest.raises(
        CorruptEvidenceError, match=r"flipped.mcap: chunk at byte \d+ .*(CRC|ZSTD|zstd|Zstd)"
    ):
        open_evidence(path).steps()


def test_split_raises_only_corruption_on_garbage(recorded: Path) -> None:
    path = recorded
    ev = open_evidence(path)
    with open(path, "rb") as f:
        ref = ev._chunks[0]
        data = chunks._decompress(chunks._read_chunk_record(f, ref, path), path, ref.offset)
    route = {cid: chunks._SLOTS.get(c.topic, -1) for cid, c in ev._channels.items()}
    rng = random.Random(0)
    outcomes = set()
    for case in range(400):
        mutated = bytearray(data[: rng.randrange(len(data) + 1)] if case % 2 else data)
        for _ in range(rng.randrange(1, 4)):
            at = rng.randrange(len(mutated)) if mutated else 0
            mutated[at : at + 1] = bytes([rng.randrange(256)])
        try:
            chunks._split(bytes(mutated), path, 7, dict(route), (True,) * 3, [], [])
            outcomes.add("ok")
        except CorruptEvidenceError as exc:
            assert "chunk at byte 7" in str(exc) and "run.mcap" in str(exc)
            outcomes.add("corrupt")
    assert outcomes == {"ok", "corrupt"}
    for garbage in (b"\x05", b"\x05\x00\x00", b"\x05" + struct.pack("<Q", 3) + b"abc"):
        with pytest.raises(CorruptEvidenceError, match="chunk at byte 7 is damaged"):
            chunks._split(garbage, path, 7, dict(route), (True,) * 3, [], [])


# --------------------------------------------------------------------------- one pass, caches


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
    bad = _rewrite(recorded, tmp_path / "bad.mcap", replace={(topic, 1): b"not arrow"})
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


# --------------------------------------------------------------------------- episode records


def _reference_episodes(records: list[bytes]) -> pa.Table:
    """The episodes table of a finished file, row by row, as the reader always built it."""
    ended: dict[int, dict[str, Any]] = {}
    for data in records:
        record = json.loads(data)
        ended[record["episode"]] = record

    def number(v: Any) -> float | None:
        return None if v is None else float(v)

    def text(v: Any) -> str | None:
        return None if v is None else json.dumps(v, separators=(",", ":"))

    rows = []
    for index in sorted(ended):
        rec = ended[index]
        error = rec.get("error") or {}
        rows.append(
            {
                "episode": index,
                "env_index": rec.get("env_index", 0),
                "agent": rec.get("agent"),
                "seed": rec.get("seed"),
                "rng_state": text(rec.get("rng_state")),
                "options": text(rec.get("options")),
                "outcome": rec["outcome"],
                "failure_label": rec.get("failure_label"),
                "truncation_reason": rec.get("truncation_reason"),
                "terminated": bool(rec.get("terminated", False)),
                "truncated": bool(rec.get("truncated", False)),
                "length": int(rec["length"]),
                "return": number(rec.get("return")),
                "term_totals": [
                    (str(k), number(v)) for k, v in (rec.get("term_totals") or {}).items()
                ],
                "start_time_ns": rec.get("start_time_ns"),
                "end_time_ns": rec.get("end_time_ns"),
                "error_type": error.get("type"),
                "error_message": error.get("message"),
                "error_during": error.get("during"),
                "notes": rec.get("notes", 0),
                "ended": True,
            }
        )
    return pa.Table.from_pylist(rows, schema=episodes.EPISODE_SCHEMA)


def _odd_records(count: int) -> list[bytes]:
    """Episode records the fast path must hand over to the record-by-record one, and others."""
    sentinel = episodes._SPLIT_VALUE
    records = []
    for i in range(count):
        record: dict[str, Any] = {
            "episode": i,
            "env_index": 0,
            "seed": None if i % 2 else i,
            "outcome": ["success", "failure", "truncated", "incomplete", "error"][i % 5],
            "terminated": i % 3 == 0,
            "truncated": i % 4 == 0,
            "length": i,
            "return": [1.5, "nan", "-inf", 2, None][i % 5],
            "term_totals": {} if i % 2 else {"a": 0.25, "b": "nan", "c": None},
            "start_time_ns": 10 * i,
            "end_time_ns": 10 * i + 5,
            "error": {"type": "ValueError", "message": 'bad "x"\n', "during": "step"}
            if i % 5 == 4
            else None,
            "notes": i % 2,
            "rng_state": {"state": {"state": 2**127 + i, "inc": 3}, "f": [0.1, 1e300]}
            if i % 3
            else None,
        }
        if i % 7 == 0:
            record["options"] = {"x": [1, sentinel, 2], "y": "é"}  # sentinel, non-ASCII
        if i % 11 == 0:
            del record["env_index"], record["notes"]
        data = json.dumps(record, separators=(",", ":")).encode()
        if i == 40:
            data = b" " + data + b"\n"  # whitespace json.loads accepts
        if i == 49:
            data = json.dumps(record, ensure_ascii=False).encode()  # UTF-8, spaces
        records.append(data)
    # a duplicate (the later one wins), out of order
    records.insert(30, records[60].replace(b'"length":60', b'"length":61'))
    records.append(records[5].replace(b'"length":5', b'"length":6'))
    return records


def test_episode_records_match_the_row_by_row_reading(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ev = open_evidence(recorded)
    # the Arrow episode blocks and the JSON end records of the same file agree
    records = [d for t, _, d in _mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    assert ev.episodes().equals(_reference_episodes(records))
    odd = _odd_records(300)
    path = _rewrite(recorded, tmp_path / "odd.mcap", end_records=odd)
    one_by_one: list[bytes] = []
    original = episodes._episode_record

    def counting(data: bytes, path: Path) -> Any:
        one_by_one.append(data)
        return original(data, path)

    monkeypatch.setattr(episodes, "_episode_record", counting)
    table = open_evidence(path).episodes()
    assert 0 < len(one_by_one) < len(odd)  # the groups with odd records only
    assert repr(table.to_pylist()) == repr(_reference_episodes(odd).to_pylist())
    lengths = table.column("length").to_pylist()
    assert (lengths[5], lengths[60]) == (6, 60)  # the later of two records of an episode wins


@pytest.mark.parametrize(
    ("record", "message"),
    [
        (b'{"episode":1,"outcome":"success"', "episode record is not valid JSON"),
        (b'{"episode":1,"outcome":"success","length":1}{}', "episode record is not valid JSON"),
        (b'[{"episode":1}]', "episode record is not a JSON object"),
        (b'{"episode":true,"outcome":"success","length":1}', "lacks 'episode' of type int"),
        (b'{"episode":1,"outcome":"success"}', "lacks 'length' of type int"),
        (b'{"episode":1,"outcome":"won","length":1}', "unknown outcome 'won'"),
        (b'{"episode":1,"outcome":"success","length":1,"seed":"s"}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"return":"x"}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"error":[1]}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"x":"' + b"y" * (1 << 20) + b'"}', "1 MiB"),
    ],
)
def test_bad_episode_records_are_corruption(
    recorded: Path, tmp_path: Path, record: bytes, message: str
) -> None:
    good = [d for t, _, d in _mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    record = record.replace(b'"episode":1,', b'"episode":99,')
    path = _rewrite(recorded, tmp_path / "bad.mcap", end_records=[*good, record, *good])
    with pytest.raises(CorruptEvidenceError, match=rf"bad\.mcap: .*{message}"):
        open_evidence(path).episodes()


def test_a_replaced_record_with_wrong_types_is_no_error(recorded: Path, tmp_path: Path) -> None:
    good = [d for t, _, d in _mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    bad = b'{"episode":0,"outcome":"success","length":1,"return":"x","error":[1]}'
    path = _rewrite(recorded, tmp_path / "replaced.mcap", end_records=[bad, *good])
    assert open_evidence(path).episodes().equals(open_evidence(recorded).episodes())


def test_json_column_splits_one_encoding_and_falls_back() -> None:
    values = [None, {"a": [1, 2.5]}, "s", None, [1, episodes._SPLIT_VALUE, 2], 3]
    assert episodes._json_column(values) == [
        None if v is None else json.dumps(v, separators=(",", ":")) for v in values
    ]
    assert episodes._json_column([None, None]) == [None, None]
    assert episodes._json_column([{"x": 1}]) == ['{"x":1}']


def test_a_known_schema_message_still_has_its_batch_checked(recorded: Path) -> None:
    """The block after a good one shares its schema message bytes; its batch is still walked."""
    batch = open_evidence(recorded).steps().to_batches()[0]

    def stream(**options: Any) -> bytes:
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, batch.schema, options=pa.ipc.IpcWriteOptions(**options)) as w:
            w.write_batch(batch)
        return bytes(sink.getvalue())

    good, compressed = stream(), stream(compression="zstd")
    known = blocks._first_message_end(good)
    assert known is not None and good[:known] == compressed[:known]  # the same schema message
    where = Path("x.mcap")
    assert blocks._arrow_batch(good, where, fmt.TOPIC_STEPS).equals(batch)
    assert blocks._GOOD_SCHEMA_MESSAGES[fmt.TOPIC_STEPS] == good[:known]
    with pytest.raises(CorruptEvidenceError, match="uses Arrow IPC body compression"):
        blocks._arrow_batch(compressed, where, fmt.TOPIC_STEPS)
    # a stream cut inside its schema message is not taken for the known one
    with pytest.raises(CorruptEvidenceError, match="not a valid Arrow stream"):
        blocks._arrow_batch(good[: known - 1], where, fmt.TOPIC_STEPS)


def _summary_start(data: bytes) -> int:
    """The footer's summary_start (a finished file ends with footer + magic)."""
    _, _, start, _, _ = struct.unpack("<BQQQI", data[-8 - 29 : -8])
    return int(start)


def _same_evidence(a: Any, b: Any) -> bool:
    return bool(
        a.steps().equals(b.steps())
        and a.episodes().equals(b.episodes())
        and a.resets().equals(b.resets())
    )


def test_a_damaged_summary_is_read_around(recorded: Path, tmp_path: Path) -> None:
    """A flipped byte anywhere from the summary to the closing magic changes nothing that is
    read: a summary whose CRC does not match is ignored and the data section is scanned."""
    data = recorded.read_bytes()
    intact = open_evidence(recorded)
    start = _summary_start(data)
    damaged = tmp_path / "damaged.mcap"
    flagged = 0
    for at in range(start, len(data), 13):
        damaged.write_bytes(_patched(data, at, bytes([data[at] ^ 0xFF])))
        ev = open_evidence(damaged)
        assert ev.finished, at
        assert _same_evidence(ev, intact), at
        flagged += ev.summary_damage is not None
    assert flagged > (len(data) - start) // 13 // 2  # most flips are caught by the CRC


@pytest.mark.parametrize(
    ("where", "why"),
    [
        (-1, "the closing magic bytes are damaged"),
        (-8 - 29, "the footer record before the closing magic is damaged"),  # its opcode
        (-8 - 29 + 1, "the footer record before the closing magic is damaged"),  # its length
    ],
)
def test_a_damaged_footer_or_magic_is_named_and_the_file_still_reads(
    recorded: Path, tmp_path: Path, where: int, why: str
) -> None:
    data = recorded.read_bytes()
    damaged = tmp_path / "damaged.mcap"
    at = len(data) + where
    damaged.write_bytes(_patched(data, at, bytes([data[at] ^ 0xFF])))
    ev = open_evidence(damaged)
    assert ev.summary_damage == why
    assert ev.finished and _same_evidence(ev, open_evidence(recorded))


def test_a_damaged_summary_schema_is_reported_and_recover_writes_a_new_one(
    recorded: Path, tmp_path: Path
) -> None:
    from episode_audit import check, recover

    data = recorded.read_bytes()
    start = _summary_start(data)
    at = data.index(b"episode_audit/steps", start)  # the summary's copy of a channel topic
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(_patched(data, at + 3, b"X"))
    ev = open_evidence(damaged)
    assert ev.summary_damage is not None
    assert ev.summary_damage.startswith(f"the summary section at bytes {start}-")
    assert _same_evidence(ev, open_evidence(recorded))
    found = [f for f in check([damaged]).findings if f.code == "summary_damaged"]
    assert len(found) == 1 and found[0].severity == "warning"
    out = tmp_path / "out.mcap"
    result = recover(damaged, out)
    assert not result.already_finished and not result.lost
    assert "does not match the footer's CRC: a new summary was written" in result.summary()
    fixed = open_evidence(out)
    assert fixed.summary_damage is None and fixed.finished
    assert fixed.steps().equals(ev.steps())
    assert not [f for f in check([out]).findings if f.code == "summary_damaged"]


def _metadata_offset(path: Path, name: str) -> tuple[int, int]:
    """(offset, length) of the metadata record ``name`` the file's summary locates."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (index,) = [m for m in summary.metadata_indexes if m.name == name]
    return index.offset, index.length


def test_a_garbled_run_end_record_is_named_and_the_file_is_still_finished(
    recorded: Path, tmp_path: Path
) -> None:
    """Before: "the writer did not finish the file", and recover said the recorder was killed
    before close(). The summary and footer behind the record say the writer finished."""
    data = recorded.read_bytes()
    offset, length = _metadata_offset(recorded, "episode_audit.run_end")
    intact = open_evidence(recorded)
    damaged = tmp_path / "damaged.mcap"
    # the opcode, the length field, the name, a key and a value of the record
    for at in (offset, offset + 1, offset + 9 + 4 + 3, offset + length - 3):
        damaged.write_bytes(_patched(data, at, bytes([data[at] ^ 0xFF])))
        ev = open_evidence(damaged)
        assert ev.finished and ev.torn is None and ev.run_end is None, at
        assert ev.run_end_damage is not None
        assert ev.run_end_damage.startswith(
            f"the episode_audit.run_end metadata record at byte {offset} "
        ), at
        assert _same_evidence(ev, intact), at


def test_a_garbled_run_end_record_is_reported_and_recover_writes_a_new_one(
    recorded: Path, tmp_path: Path
) -> None:
    from episode_audit import check, recover

    data = recorded.read_bytes()
    offset, _ = _metadata_offset(recorded, "episode_audit.run_end")
    at = data.index(b"status", offset)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(_patched(data, at, b"\xff"))  # not UTF-8 any more
    codes = [f.code for f in check([damaged]).findings]
    assert "run_end_damaged" in codes and "file_unfinished" not in codes
    out = tmp_path / "out.mcap"
    result = recover(damaged, out)
    assert not result.already_finished and not result.lost and result.closing
    assert result.summary().endswith(
        f"; no evidence lost (the episode_audit.run_end metadata record at byte {offset} is "
        "garbled: its status and counts were lost, a new run-end record was written)"
    )
    fixed = open_evidence(out)
    assert fixed.finished and fixed.run_end_damage is None
    assert fixed.run_end is not None and fixed.run_end["status"] == "recovered"
    assert _same_evidence(fixed, open_evidence(recorded))
    assert "run_end_damaged" not in [f.code for f in check([out]).findings]


def test_a_garbled_run_metadata_record_is_named(recorded: Path, tmp_path: Path) -> None:
    """Without the run record (spaces, env, settings) nothing can be read as evidence."""
    data = recorded.read_bytes()
    offset, _ = _metadata_offset(recorded, "episode_audit.run")
    at = data.index(b"format_version", offset)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(_patched(data, at, b"\xff"))
    with pytest.raises(
        CorruptEvidenceError,
        match=rf"the episode_audit.run metadata record at byte {offset} is garbled: the "
        "spaces, env and settings of the run it held are lost",
    ):
        open_evidence(damaged)
