"""Evidence files for the read wing's tests: a small CartPole recording, and copies of one."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from episode_audit import RecordEvidence
from episode_audit.format import names as fmt


def record_cartpole(path: Path, episodes: int = 4, block_steps: int = 16) -> Path:
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


def rewrite(
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


def mcap_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message, in file order, as mcap's own reader sees it."""
    with open(path, "rb") as f:
        return [
            (c.topic, m.log_time, m.data)
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def patched(data: bytes, at: int, value: bytes) -> bytearray:
    out = bytearray(data)
    out[at : at + len(value)] = value
    return out
