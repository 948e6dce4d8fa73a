"""Mutation library for the fuzz tests: real evidence files, mutated structurally.

:func:`build_corpus` records real evidence files with :class:`~episode_audit.RecordEvidence`
(CartPole, an env with Dict / Tuple spaces and reward terms, finished and torn, zstd and
uncompressed). :func:`layout` parses a file's MCAP record layout by hand, so mutations can aim at
every record class: the magic, the header, metadata, a chunk's header and its (compressed)
records, a message inside a chunk and the Arrow block or JSON it carries, message indexes, the
summary, the footer.

Two kinds of mutation:

- **raw**: truncation, byte flips, random bytes, huge declared record lengths, zstd bombs. On
  uncompressed files, flips inside a chunk or the summary can be made with the CRC recomputed,
  so what is tested is the reader's validation, not the CRC.
- **model**: the file is parsed into schemas, channels, messages (with their chunk groups) and
  metadata, one of those is changed (an Arrow block with the wrong schema or garbage bytes,
  metadata with wrong JSON types, missing keys or huge values, a newer format version, JSON
  episode records of wrong shapes, ...), and the file is written again with ``mcap.writer``:
  every CRC, index and offset is valid.

:func:`mutate` picks a mutation by name from a seed (deterministic). :func:`drive` runs a file
through every entry point a user can reach (library and CLI) and returns what happened; only
:class:`~episode_audit.errors.EpisodeAuditError` may escape the library. Run as a script
(``python tests/fuzzing.py``), it is the harness's worker: it reads ``BASE KIND SEED`` lines on
stdin, mutates, drives, and answers one JSON line each (see :func:`worker`).
"""

from __future__ import annotations

import functools
import importlib.util
import io
import json
import random
import resource
import shutil
import signal
import struct
import sys
import tempfile
import time
import traceback
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import zstandard
from mcap.writer import CompressionType, Writer

if __name__ == "__main__":  # the worker: import the package from this checkout
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from episode_audit import EpisodeAuditError, RecordEvidence, open_evidence, recover
from episode_audit.format import names as fmt

MAGIC = b"\x89MCAP0\r\n"
OP = {
    0x01: "header",
    0x02: "footer",
    0x03: "schema",
    0x04: "channel",
    0x05: "message",
    0x06: "chunk",
    0x07: "message_index",
    0x08: "chunk_index",
    0x09: "attachment",
    0x0A: "attachment_index",
    0x0B: "statistics",
    0x0C: "metadata",
    0x0D: "metadata_index",
    0x0E: "summary_offset",
    0x0F: "data_end",
}

# ----------------------------------------------------------------------------- the corpus


class _TermsEnv(gym.Env[Any, Any]):
    """Dict observations, Tuple actions, named reward terms, success and labelled failures."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Dict(
            {
                "pos": gym.spaces.Box(-5.0, 5.0, (3,), np.float32),
                "mode": gym.spaces.Discrete(4),
            }
        )
        self.action_space = gym.spaces.Tuple(
            (gym.spaces.Discrete(3), gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        )
        self.t = 0

    def _obs(self) -> dict[str, Any]:
        return {
            "pos": self.np_random.uniform(-1, 1, 3).astype(np.float32),
            "mode": int(self.np_random.integers(4)),
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        self.t += 1
        progress = float(self.np_random.uniform(0, 1))
        cost = 0.1 * float(np.square(action[1]).sum())
        info: dict[str, Any] = {"reward_terms": {"progress": progress, "ctrl_cost": -cost}}
        end = self.np_random.uniform() < 0.08
        if end:
            if self.np_random.uniform() < 0.5:
                info["success"] = True
            else:
                info["failure"] = "collision"
        return self._obs(), progress - cost, bool(end), False, info


def _run(env: gym.Env[Any, Any], episodes: int, *, seed: int = 0) -> None:
    env.action_space.seed(seed)
    for e in range(episodes):
        env.reset(seed=seed + e)
        done = False
        while not done:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            done = term or trunc


def _terms_env() -> gym.Env[Any, Any]:
    return gym.wrappers.TimeLimit(_TermsEnv(), max_episode_steps=40)


def build_corpus(directory: Path) -> dict[str, Path]:
    """Record the base files into ``directory`` (once; reused when they exist)."""
    global BOMB_DIR
    directory.mkdir(parents=True, exist_ok=True)
    BOMB_DIR = directory
    out = {
        name: directory / f"{name}.mcap"
        for name in (
            "cartpole",
            "terms",
            "cartpole_plain",
            "terms_torn",
            "cartpole_torn",
            "vector",
            "agents",
            "recovered",
        )
    }
    if all(p.exists() for p in out.values()):
        return out
    for p in directory.glob("*.mcap"):
        p.unlink()
    with RecordEvidence(
        gym.make("CartPole-v1"), out["cartpole"], block_steps=24, command_line=["fuzz"]
    ) as env:
        _run(env, 4)
    with RecordEvidence(_terms_env(), out["terms"], block_steps=16, command_line=["fuzz"]) as env:
        _run(env, 6)
    write_model(read_model(out["cartpole"].read_bytes()), out["cartpole_plain"], compressed=False)
    # torn: the bytes on disk after flushes, while the recorder still runs (as after SIGKILL)
    for name, make, n in (("terms_torn", _terms_env, 5), ("cartpole_torn", None, 3)):
        scratch = directory / f"{name}.recording"
        env = RecordEvidence(
            make() if make else gym.make("CartPole-v1"),
            scratch,
            block_steps=16,
            command_line=["fuzz"],
        )
        _run(env, n)
        env.reset(seed=99)
        for _ in range(5):
            env.step(env.action_space.sample())
        env.flush()
        env.step(env.action_space.sample())  # unflushed: lost with the tear
        shutil.copyfile(scratch, out[name])
        env.close()
        scratch.unlink()
    _record_multi_stream(out["vector"], out["agents"])
    # a recovery's run-end record: its keys (cut-off and damaged episodes) for mutations to hit;
    # where from and when made fixed, so that a (base, kind, seed) names the same input again
    recover(out["cartpole_torn"], out["recovered"])
    model = read_model(out["recovered"].read_bytes())
    for name, values in model.metadata:
        if name == fmt.METADATA_RUN_END:
            values.update(recovered_from="fuzz", recovered_time="2026-01-01T00:00:00+00:00")
    write_model(model, out["recovered"])
    return out


def _record_multi_stream(vector: Path, agents: Path) -> None:
    """A vector-env file (3 sub-envs, autoresets) and a PettingZoo AEC file (6 games)."""
    import warnings

    from episode_audit import RecordAECEvidence, RecordVectorEvidence

    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import tictactoe_v3

    envs = gym.make_vec("CartPole-v1", 3, vectorization_mode="sync")
    with RecordVectorEvidence(envs, vector, block_steps=16, command_line=["fuzz"]) as envs:
        envs.reset(seed=0)
        envs.action_space.seed(0)
        for _ in range(60):
            envs.step(envs.action_space.sample())
    with RecordAECEvidence(tictactoe_v3.env(), agents, block_steps=4, command_line=["fuzz"]) as env:
        for game in range(6):
            env.reset(seed=game)
            for agent in env.agent_iter():
                obs, _, terminated, truncated, _ = env.last()
                mask = obs["action_mask"]
                env.step(None if terminated or truncated else env.action_space(agent).sample(mask))


# ----------------------------------------------------------------------------- layout


@dataclass(frozen=True)
class Record:
    """One top-level MCAP record: ``data[offset]`` is its opcode, the body follows 9 bytes on."""

    offset: int
    opcode: int
    length: int

    @property
    def kind(self) -> str:
        return OP.get(self.opcode, f"op{self.opcode:#x}")

    @property
    def body(self) -> int:
        return self.offset + 9

    @property
    def end(self) -> int:
        return self.offset + 9 + self.length


@dataclass(frozen=True)
class ChunkInfo:
    """A chunk record's fields and where its records are in the file."""

    record: Record
    compression: str
    uncompressed_size: int
    crc_at: int  # file offset of the uncompressed CRC field
    size_at: int  # file offset of the uncompressed size field
    records_at: int  # file offset of the (compressed) records
    records_length: int


def layout(data: bytes) -> tuple[list[Record], list[ChunkInfo]]:
    """The top-level records of a well-formed file (stops quietly at a torn end)."""
    records: list[Record] = []
    chunks: list[ChunkInfo] = []
    pos = len(MAGIC)
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if pos + 9 + length > len(data):
            break
        rec = Record(pos, opcode, length)
        records.append(rec)
        if opcode == 0x06:
            (name_length,) = struct.unpack_from("<I", data, rec.body + 28)
            name = data[rec.body + 32 : rec.body + 32 + name_length].decode()
            at = rec.body + 32 + name_length
            (n,) = struct.unpack_from("<Q", data, at)
            (size,) = struct.unpack_from("<Q", data, rec.body + 16)
            chunks.append(ChunkInfo(rec, name, size, rec.body + 24, rec.body + 16, at + 8, n))
        pos = rec.end
        if opcode == 0x02:
            break
    return records, chunks


def decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    return bytes(data)


def inner_records(chunk: bytes) -> list[Record]:
    """The records inside a decompressed chunk (offsets relative to it)."""
    out = []
    pos = 0
    while pos + 9 <= len(chunk):
        opcode, length = struct.unpack_from("<BQ", chunk, pos)
        out.append(Record(pos, opcode, length))
        pos += 9 + length
    return out


# ----------------------------------------------------------------------------- the model


@dataclass
class Message:
    channel_id: int
    log_time: int
    data: bytes
    chunk: int  # index of the chunk it was in


@dataclass
class Model:
    """What a file holds, as ``mcap.writer`` would be asked to write it again."""

    profile: str
    library: str
    schemas: dict[int, tuple[str, str, bytes]]
    channels: dict[int, tuple[str, str, int, dict[str, str]]]
    metadata: list[tuple[str, dict[str, str]]]
    messages: list[Message]
    finished: bool

    def channel(self, topic: str) -> int:
        return next(cid for cid, c in self.channels.items() if c[0] == topic)

    def on(self, topic: str) -> list[int]:
        """Indices of the messages on ``topic``."""
        ids = {cid for cid, c in self.channels.items() if c[0] == topic}
        return [i for i, m in enumerate(self.messages) if m.channel_id in ids]

    def run(self) -> dict[str, str]:
        return next(m for name, m in self.metadata if name == fmt.METADATA_RUN)


def _prefixed(data: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", data, pos)
    return data[pos + 4 : pos + 4 + n].decode(), pos + 4 + n


def _string_map(data: bytes, pos: int) -> tuple[dict[str, str], int]:
    (n,) = struct.unpack_from("<I", data, pos)
    pos += 4
    stop = pos + n
    out = {}
    while pos < stop:
        key, pos = _prefixed(data, pos)
        value, pos = _prefixed(data, pos)
        out[key] = value
    return out, pos


def read_model(data: bytes) -> Model:
    """Parse a well-formed evidence file (finished or torn) into a :class:`Model`."""
    records, chunks = layout(data)
    header = next(r for r in records if r.opcode == 0x01)
    profile, pos = _prefixed(data, header.body)
    library, _ = _prefixed(data, pos)
    model = Model(profile, library, {}, {}, [], [], any(r.opcode == 0x02 for r in records))
    chunk_of = {c.record.offset: c for c in chunks}
    n_chunk = 0
    for rec in records:
        if rec.opcode == 0x0C:
            name, pos = _prefixed(data, rec.body)
            values, _ = _string_map(data, pos)
            model.metadata.append((name, values))
        elif rec.opcode == 0x06:
            info = chunk_of[rec.offset]
            raw = data[info.records_at : info.records_at + info.records_length]
            inner = decompress(raw, info.compression, info.uncompressed_size)
            for r in inner_records(inner):
                body = inner[r.offset + 9 : r.end]
                if r.opcode == 0x03:
                    sid, name_pos = struct.unpack_from("<H", body, 0)[0], 2
                    name, p = _prefixed(body, name_pos)
                    encoding, p = _prefixed(body, p)
                    (n,) = struct.unpack_from("<I", body, p)
                    model.schemas[sid] = (name, encoding, bytes(body[p + 4 : p + 4 + n]))
                elif r.opcode == 0x04:
                    cid, sid = struct.unpack_from("<HH", body, 0)
                    topic, p = _prefixed(body, 4)
                    encoding, p = _prefixed(body, p)
                    meta, _ = _string_map(body, p)
                    model.channels[cid] = (topic, encoding, sid, meta)
                elif r.opcode == 0x05:
                    cid, _, log_time, _ = struct.unpack_from("<HIQQ", body, 0)
                    model.messages.append(Message(cid, log_time, bytes(body[22:]), n_chunk))
            n_chunk += 1
    return model


def write_model(
    model: Model,
    path: Path | None = None,
    *,
    compressed: bool = True,
    finished: bool | None = None,
) -> bytes:
    """Write ``model`` with ``mcap.writer`` (a chunk per original chunk); return the bytes.

    ``finished=False`` leaves the file as a killed writer would: no run-end, summary or footer.
    """
    finished = model.finished if finished is None else finished
    buf = io.BytesIO()
    writer = Writer(
        buf,
        chunk_size=1 << 40,
        compression=CompressionType.ZSTD if compressed else CompressionType.NONE,
    )
    writer.start(profile=model.profile, library=model.library)
    for sid in sorted(model.schemas):
        name, encoding, data = model.schemas[sid]
        # mcap numbers schemas and channels 1, 2, ... itself, as our writer did
        assert writer.register_schema(name, encoding, data) == sid
    for cid in sorted(model.channels):
        topic, encoding, sid, meta = model.channels[cid]
        assert writer.register_channel(topic, encoding, sid, meta) == cid
    ends = [(n, m) for n, m in model.metadata if n == fmt.METADATA_RUN_END]
    for name, values in model.metadata:
        if name != fmt.METADATA_RUN_END:
            writer.add_metadata(name, values)
    chunk = None
    for i, m in enumerate(model.messages):
        if chunk is not None and m.chunk != chunk:
            writer.flush()
        chunk = m.chunk
        writer.add_message(m.channel_id, m.log_time, m.data, m.log_time, i & 0xFFFFFFFF)
    if finished:
        for name, values in ends:
            writer.add_metadata(name, values)
        writer.finish()
    else:
        writer.flush()
    out = buf.getvalue()
    if path is not None:
        path.write_bytes(out)
    return out


# ----------------------------------------------------------------------------- raw mutations

HUGE = (1 << 63) - 1


def _offset_in(rng: random.Random, rec: Record) -> int:
    return rng.randrange(rec.offset, rec.end)


def _classes(data: bytes) -> dict[str, list[tuple[int, int]]]:
    """Byte ranges [start, stop) of each record class (chunks split into header / records)."""
    records, chunks = layout(data)
    out: dict[str, list[tuple[int, int]]] = {"magic": [(0, len(MAGIC))]}
    for rec in records:
        out.setdefault(rec.kind, []).append((rec.offset, rec.end))
    for c in chunks:
        out.setdefault("chunk_header", []).append((c.record.offset, c.records_at))
        out.setdefault("chunk_records", []).append((c.records_at, c.records_at + c.records_length))
    footer = next((r for r in records if r.opcode == 0x02), None)
    if footer is not None:
        (summary_start,) = struct.unpack_from("<Q", data, footer.body)
        if summary_start:
            out["summary"] = [(summary_start, footer.offset)]
        out["trailing_magic"] = [(footer.end, len(data))]
    return out


def _pick(rng: random.Random, data: bytes, wanted: str | None = None) -> tuple[str, int]:
    """A record class (``wanted`` or a random one) and an offset inside it."""
    classes = _classes(data)
    name = wanted if wanted in classes else rng.choice(sorted(classes))
    start, stop = rng.choice(classes[name])
    return name, rng.randrange(start, max(stop, start + 1))


def truncate(data: bytes, rng: random.Random) -> bytes:
    _, at = _pick(rng, data)
    return data[:at]


def flip(data: bytes, rng: random.Random) -> bytes:
    out = bytearray(data)
    for _ in range(rng.choice([1, 1, 2, 8])):
        _, at = _pick(rng, data)
        if at < len(out):
            out[at] ^= rng.randrange(1, 256)
    return bytes(out)


def _fix_crcs(out: bytearray) -> None:
    """Recompute the CRC of every uncompressed chunk and of the summary (sizes unchanged)."""
    records, chunks = layout(bytes(out))
    for c in chunks:
        if c.compression == "":
            crc = zlib.crc32(out[c.records_at : c.records_at + c.records_length])
            out[c.crc_at : c.crc_at + 4] = struct.pack("<I", crc)
    footer = next((r for r in records if r.opcode == 0x02), None)
    if footer is not None:
        (start,) = struct.unpack_from("<Q", out, footer.body)
        if 0 < start <= footer.offset:
            crc = zlib.crc32(out[start : footer.body + 16])
            out[footer.body + 16 : footer.body + 20] = struct.pack("<I", crc)


def flip_crc_fixed(data: bytes, rng: random.Random) -> bytes:
    """Flip bytes inside the records of an uncompressed chunk or the summary, then fix CRCs."""
    classes = _classes(data)
    targets = [c for c in ("chunk_records", "summary") if c in classes]
    out = bytearray(data)
    for _ in range(rng.choice([1, 1, 2, 4])):
        _, at = _pick(rng, data, rng.choice(targets))
        out[at] ^= rng.randrange(1, 256)
    _fix_crcs(out)
    return bytes(out)


def inner_length(data: bytes, rng: random.Random) -> bytes:
    """An uncompressed chunk's inner record declares a wrong (often huge) length; CRC fixed."""
    _, chunks = layout(data)
    c = rng.choice([c for c in chunks if c.compression == ""])
    inner = inner_records(data[c.records_at : c.records_at + c.records_length])
    rec = rng.choice(inner)
    value = rng.choice([HUGE, 1 << 32, 0, rec.length + 1, rec.length - 1, rng.randrange(1 << 20)])
    out = bytearray(data)
    out[c.records_at + rec.offset + 1 : c.records_at + rec.offset + 9] = struct.pack(
        "<Q", max(value, 0)
    )
    _fix_crcs(out)
    return bytes(out)


def huge_length(data: bytes, rng: random.Random) -> bytes:
    """A top-level record declares a huge length (or the chunk a huge uncompressed size)."""
    records, chunks = layout(data)
    out = bytearray(data)
    value = rng.choice([HUGE, 1 << 40, 1 << 31, (1 << 30) + 1, len(data)])
    if chunks and rng.random() < 0.4:
        c = rng.choice(chunks)
        at = rng.choice([c.size_at, c.records_at - 8])
        out[at : at + 8] = struct.pack("<Q", value)
    else:
        rec = rng.choice(records)
        out[rec.offset + 1 : rec.offset + 9] = struct.pack("<Q", value)
    if rng.random() < 0.5:
        _fix_crcs(out)
    return bytes(out)


_BOMBS: dict[str, bytes] = {}
BOMB_DIR: Path | None = None
"""Where :func:`bomb` keeps its frames between processes (set by :func:`build_corpus`)."""
BOMB_GIB = 4


def bomb(*, content_size: bool) -> bytes:
    """A zstd frame of 4 GiB of zeros, with or without its content size in the frame header.

    Made once (streaming, a few MB of memory, a few seconds) and kept in :data:`BOMB_DIR`.
    """
    key = f"bomb-{BOMB_GIB}g-{'sized' if content_size else 'unsized'}.zst"
    if key in _BOMBS:
        return _BOMBS[key]
    cached = BOMB_DIR / key if BOMB_DIR is not None else None
    if cached is not None and cached.exists():
        _BOMBS[key] = cached.read_bytes()
        return _BOMBS[key]
    size = BOMB_GIB << 30
    cctx = zstandard.ZstdCompressor(level=1, write_content_size=content_size)
    obj = cctx.compressobj(size=size if content_size else -1)
    block = bytes(16 << 20)
    parts = [obj.compress(block) for _ in range(size // len(block))]
    parts.append(obj.flush())
    _BOMBS[key] = b"".join(parts)
    if cached is not None:
        cached.write_bytes(_BOMBS[key])
    return _BOMBS[key]


def zstd_bomb(data: bytes, rng: random.Random) -> bytes:
    """Replace a chunk's records with a zstd frame that inflates to 4 GiB.

    The chunk declares its old size, the frame's size, the reader's cap, 4 GiB or 2**63 - 1
    uncompressed bytes; the frame header has the real size or none.
    """
    from episode_audit.read import chunks as read_chunks

    _, chunks = layout(data)
    c = rng.choice([c for c in chunks if c.compression == "zstd"])
    frame = bomb(content_size=rng.random() < 0.5)
    cap = read_chunks.MAX_RECORD_BYTES
    declared = rng.choice([c.uncompressed_size, len(frame), cap, cap + 1, 4 << 30, HUGE])
    body = bytearray(data[c.record.body : c.records_at - 8])
    struct.pack_into("<Q", body, 16, declared)
    body += struct.pack("<Q", len(frame)) + frame
    head = struct.pack("<BQ", 0x06, len(body))
    # the chunk is rewritten in place: what follows keeps its bytes (its offsets are off, so
    # a finished file falls back to a linear scan, or the summary points into the bomb)
    return data[: c.record.offset] + head + bytes(body) + data[c.record.end :]


def chunks(data: bytes, rng: random.Random) -> bytes:
    """Whole chunk records (each with its message indexes) duplicated, spliced or moved; or a
    partial chunk left in the middle, as a failed write leaves one before a writer that went
    on (the file then torn where it stopped, or finished)."""
    records, infos = layout(data)
    if not infos:
        return truncate(data, rng)
    spans = []  # each chunk with the message indexes after it
    for info in infos:
        start = info.record.offset
        after = [r for r in records if r.offset >= info.record.end]
        end = info.record.end
        for r in after:
            if r.opcode != 0x07:
                break
            end = r.end
        spans.append((start, end))
    start, end = rng.choice(spans)
    piece = data[start:end]
    kind = rng.randrange(4)
    if kind == 0:  # the same chunk twice
        return data[:end] + piece + data[end:]
    if kind == 1:  # a partial chunk, the writer going on after it
        return data[:start] + piece[: rng.randrange(1, len(piece))] + data[start:]
    if kind == 2:  # a chunk moved after another
        other_start, other_end = rng.choice(spans)
        rest = data[:start] + data[end:]
        at = other_end - (end - start if other_start > start else 0)
        return rest[:at] + piece + rest[at:]
    # a chunk from one place spliced into the middle of another's records
    other_start, other_end = rng.choice(spans)
    at = rng.randrange(other_start, other_end)
    return data[:at] + piece + data[at:]


def random_bytes(data: bytes, rng: random.Random) -> bytes:
    n = rng.choice([1, 7, 8, 9, 100, 4096, 65536])
    noise = rng.randbytes(n)
    return rng.choice([noise, MAGIC + noise, MAGIC + noise + MAGIC, data[: rng.randrange(64)]])


def special(data: bytes, rng: random.Random) -> bytes:
    header_end = len(MAGIC) + 9 + struct.unpack_from("<Q", data, len(MAGIC) + 1)[0]
    return rng.choice(
        [
            b"",
            MAGIC,
            MAGIC + MAGIC,
            b"\x89MCAP1\r\n" + data[8:],  # wrong magic
            b"\x00" * 8 + data[8:],
            data[:header_end],  # header only
            data[: len(data) - 8],  # no trailing magic
            data + data,  # two files back to back
            data[:header_end] + data[:header_end] + data[header_end:],  # two headers
        ]
    )


# ----------------------------------------------------------------------------- model mutations


def _arrow_stream(batch: pa.RecordBatch, **options: Any) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema, options=pa.ipc.IpcWriteOptions(**options)) as w:
        w.write_batch(batch)
    return bytes(sink.getvalue().to_pybytes())


def _batch_of(data: bytes) -> pa.RecordBatch:
    return pa.ipc.open_stream(data).read_next_batch()


def _wrong_schema(batch: pa.RecordBatch, rng: random.Random) -> pa.RecordBatch:
    names = batch.schema.names
    name = rng.choice(names)
    i = names.index(name)
    n = batch.num_rows
    choice = rng.randrange(7)
    if choice == 0:  # a column missing
        return batch.drop_columns([name])
    if choice == 1:  # a column as text
        return batch.set_column(i, name, pa.array([str(v) for v in batch.column(i).to_pylist()]))
    if choice == 2:  # a column of nulls (the null type has no buffers)
        return batch.set_column(i, pa.field(name, pa.null()), pa.nulls(n))
    if choice == 3:  # an extra column
        return batch.append_column("extra", pa.array(range(n)))
    if choice == 4:  # a narrower or other numeric type
        kind = rng.choice([pa.int8(), pa.float32(), pa.uint64(), pa.bool_()])
        try:
            return batch.set_column(i, name, batch.column(i).cast(kind, safe=False))
        except (pa.ArrowException, TypeError):
            return batch.set_column(i, pa.field(name, kind), pa.nulls(n, kind))
    if choice == 5:  # columns renamed
        return batch.rename_columns([f"c{k}" for k in range(len(names))])
    return pa.record_batch({"x": pa.array(range(n))})  # another table altogether


def _null_giant(batch: pa.RecordBatch) -> pa.RecordBatch:
    """A batch that claims 2**31 - 1 rows, with null-type columns (no buffers to check)."""
    n = (1 << 31) - 1
    return pa.RecordBatch.from_arrays(
        [pa.Array.from_buffers(pa.null(), n, [None]) for _ in batch.schema.names],
        names=batch.schema.names,
    )


def _ipc_bomb() -> bytes:
    """An Arrow stream of 8 zstd-compressed columns of 128 MiB of zeros each (made once)."""
    if "ipc" not in _BOMBS:
        zeros = pa.array(np.zeros(1 << 24))
        giant = pa.record_batch([zeros] * 8, names=[f"c{i}" for i in range(8)])
        _BOMBS["ipc"] = _arrow_stream(giant, compression="zstd")
    return _BOMBS["ipc"]


def arrow_block(model: Model, rng: random.Random) -> Model:
    """An Arrow block (steps, resets or episodes) with wrong schema or garbage bytes."""
    topic = rng.choice([fmt.TOPIC_STEPS, fmt.TOPIC_RESETS, fmt.TOPIC_EPISODES])
    picked = model.on(topic) or model.on(fmt.TOPIC_STEPS)
    m = model.messages[rng.choice(picked)]
    batch = _batch_of(m.data)
    kind = rng.randrange(8)
    if kind == 0:
        m.data = _arrow_stream(_wrong_schema(batch, rng))
    elif kind == 1:
        m.data = rng.randbytes(rng.randrange(0, 400))
    elif kind == 2:
        out = bytearray(m.data)
        for _ in range(rng.randrange(1, 6)):
            out[rng.randrange(len(out))] ^= rng.randrange(1, 256)
        m.data = bytes(out)
    elif kind == 3:
        m.data = m.data[: rng.randrange(len(m.data))]
    elif kind == 4:  # compressed IPC buffers (our writer never writes them)
        m.data = _arrow_stream(batch, compression=rng.choice(["zstd", "lz4"]))
    elif kind == 5:  # an IPC body bomb: 1 GiB of zeros in zstd-compressed buffers
        m.data = _ipc_bomb()
    elif kind == 6:
        m.data = _arrow_stream(_null_giant(batch))
    else:  # two batches, or none
        schema_only = pa.BufferOutputStream()
        with pa.ipc.new_stream(schema_only, batch.schema):
            pass
        m.data = rng.choice([m.data + m.data, schema_only.getvalue().to_pybytes()])
    return model


def _with_nulls(array: pa.Array, rng: random.Random) -> pa.Array:
    """``array`` with a new validity bitmap (some rows null), its values buffers untouched."""
    n = len(array)
    valid = [rng.random() < 0.7 for _ in range(n)]
    valid[rng.randrange(n)] = False
    bitmap = pa.array(valid, pa.bool_()).buffers()[1]
    buffers = array.buffers()
    return pa.Array.from_buffers(
        array.type, n, [bitmap, *buffers[1:]], null_count=valid.count(False), offset=0
    )


def null_block(model: Model, rng: random.Random) -> Model:
    """Nulls in a column the format declares never null (the block's validity bitmap
    rewritten), in a step, reset or episode block."""
    from episode_audit.format.schemas import EPISODE_BLOCK_SCHEMA, not_null_columns

    never = {
        fmt.TOPIC_STEPS: not_null_columns(fmt.TOPIC_STEPS),
        fmt.TOPIC_RESETS: not_null_columns(fmt.TOPIC_RESETS),
        fmt.TOPIC_EPISODES: tuple(f.name for f in EPISODE_BLOCK_SCHEMA if not f.nullable),
    }
    topic = rng.choice([t for t in never if model.on(t)])
    m = model.messages[rng.choice(model.on(topic))]
    batch = _batch_of(m.data)
    names = [c for c in never[topic] if c in batch.schema.names]
    if batch.num_rows == 0 or not names:
        return model
    i = batch.schema.get_field_index(rng.choice(names))
    m.data = _arrow_stream(batch.set_column(i, batch.schema.field(i), _with_nulls(batch[i], rng)))
    return model


_WRONG_JSON: list[Any] = [
    None,
    0,
    -1,
    1.5,
    "x",
    "",
    [],
    {},
    [1, 2],
    {"a": "b"},
    True,
    1 << 70,
    -(1 << 70),
    "nan",
    {"type": "Box"},
]


def _deep(depth: int) -> str:
    return "[" * depth + "]" * depth


def metadata(model: Model, rng: random.Random) -> Model:
    """Run (or run-end) metadata with wrong JSON types, missing keys, huge or deep values."""
    name, values = rng.choice(
        [(n, v) for n, v in model.metadata] + [(fmt.METADATA_RUN, model.run())] * 3
    )
    key = rng.choice([*sorted(values), "format_version", "format_version"])
    kind = rng.randrange(7)
    if kind == 0:
        values.pop(key, None)
    elif kind == 1:
        values[key] = json.dumps(rng.choice(_WRONG_JSON))
    elif kind == 2:
        values[key] = rng.choice(["", "{", "nul", "\x00", "[1,", "\ud7ff"])
    elif kind == 3:
        values[key] = "x" * rng.choice([(1 << 20) + 1, 4 << 20])
    elif kind == 4:
        values[key] = _deep(rng.choice([100, 5000, 200000]))
    elif kind == 5:
        values["format_version"] = rng.choice(
            ["2.0", "1.9", "99.0", "1", "1.0.0", "v1", "-1.0", "1e3", "9" * 50 + ".0", "\u0661.0"]
        )
    else:  # a structured value with members of the wrong types
        try:
            doc = json.loads(values.get(key, "null"))
        except ValueError:
            doc = None
        if isinstance(doc, dict) and doc:
            member = rng.choice(sorted(doc))
            doc[member] = rng.choice(_WRONG_JSON)
        elif isinstance(doc, list) and doc:
            doc[rng.randrange(len(doc))] = rng.choice(_WRONG_JSON)
        else:
            doc = rng.choice(_WRONG_JSON)
        values[key] = json.dumps(doc)
    if rng.random() < 0.1:  # the metadata record missing, or twice
        model.metadata = [(n, v) for n, v in model.metadata if n != name] + (
            [(name, values), (name, {})] if rng.random() < 0.5 else []
        )
    return model


def episode_json(model: Model, rng: random.Random) -> Model:
    """JSON episode records of wrong shapes (the Arrow episode blocks dropped, so they count)."""
    blocks = {cid for cid, c in model.channels.items() if c[0] == fmt.TOPIC_EPISODES}
    if rng.random() < 0.8:
        model.messages = [m for m in model.messages if m.channel_id not in blocks]
        model.channels = {k: v for k, v in model.channels.items() if k not in blocks}
    ends = model.on(fmt.TOPIC_EPISODE_END)
    m = model.messages[rng.choice(ends)]
    record = json.loads(m.data)
    kind = rng.randrange(6)
    if kind == 0:
        record.pop(rng.choice(sorted(record)))
    elif kind == 1:
        record[rng.choice([*sorted(record), "error", "term_totals", "rng_state", "options"])] = (
            rng.choice(_WRONG_JSON)
        )
    elif kind == 2:
        m.data = rng.choice(
            [b"", b"[]", b"null", b"1", b'"x"', b"{", b"\xff\xfe", _deep(100000).encode()]
        )
        return model
    elif kind == 3:
        record["term_totals"] = {str(i): rng.choice(_WRONG_JSON) for i in range(3)}
    elif kind == 4:
        record["episode"] = rng.choice([record["episode"], 0, -5, 1 << 62, 10**30])
        record["length"] = rng.choice([0, -1, 1 << 62, 10**30])
    else:
        record["failure_label"] = "x" * rng.choice([10, (1 << 20) + 10])
    m.data = json.dumps(record).encode()
    return model


def schema_channel(model: Model, rng: random.Random) -> Model:
    """Schema and channel records that say something else than the file holds."""
    kind = rng.randrange(6)
    cid = rng.choice(sorted(model.channels))
    topic, encoding, sid, meta = model.channels[cid]
    if kind == 0 and model.schemas:
        s = rng.choice(sorted(model.schemas))
        name, enc, data = model.schemas[s]
        model.schemas[s] = (name, enc, rng.choice([b"", rng.randbytes(64), data[: len(data) // 2]]))
    elif kind == 1 and model.schemas:
        s = rng.choice(sorted(model.schemas))
        name, enc, _ = model.schemas[s]
        other = pa.schema([("episode", pa.string()), ("reward", pa.int8())])
        model.schemas[s] = (name, enc, other.serialize().to_pybytes())
    elif kind == 2:  # two channels swap topics
        other = rng.choice(sorted(model.channels))
        t2, e2, s2, m2 = model.channels[other]
        model.channels[cid] = (t2, encoding, sid, meta)
        model.channels[other] = (topic, e2, s2, m2)
    elif kind == 3:
        model.channels[cid] = (topic, rng.choice(["json", "cdr", ""]), sid, meta)
    elif kind == 4:  # messages on a channel that was never registered
        rng.choice(model.messages).channel_id = 999
    else:
        model.channels[cid] = (topic, encoding, rng.choice([0, 77]), meta)
    return model


_WRONG_FIELD_META = {
    b"episode_audit.shape": [b"5", b'["a"]', b"[-1]", b"[3]", b"[1e3]", b"{}", b"", b"[" * 5000],
    b"episode_audit.dtype": [b"no such dtype", b"\xff", b"O", b"uint8", b"<U5", b"float64"],
    b"episode_audit.kind": [b"array", b"discrete", b"dict", b"json", b"text", b""],
}


def field_metadata(model: Model, rng: random.Random) -> Model:
    """An observation or action column whose metadata (shape, dtype, kind) does not describe
    it, in the channel's schema and every block alike (as a writer of its own might)."""
    ids = model.on(rng.choice([fmt.TOPIC_STEPS, fmt.TOPIC_RESETS]))
    if not ids:
        return model
    schema = _batch_of(model.messages[ids[0]].data).schema
    names = [n for n in (fmt.COL_OBSERVATION, fmt.COL_ACTION) if n in schema.names]
    i = schema.get_field_index(rng.choice(names))
    key = rng.choice(sorted(_WRONG_FIELD_META))
    meta = {**(schema.field(i).metadata or {}), key: rng.choice(_WRONG_FIELD_META[key])}
    schema = schema.set(i, schema.field(i).with_metadata(meta))
    for k in ids:
        columns = _batch_of(model.messages[k].data).columns
        model.messages[k].data = _arrow_stream(pa.RecordBatch.from_arrays(columns, schema=schema))
    _, _, sid, _ = model.channels[model.messages[ids[0]].channel_id]
    if sid in model.schemas:
        name, encoding, _ = model.schemas[sid]
        model.schemas[sid] = (name, encoding, schema.serialize().to_pybytes())
    return model


def messages(model: Model, rng: random.Random) -> Model:
    """Messages dropped, duplicated, reordered or with other times."""
    ms = model.messages
    kind = rng.randrange(4)
    i = rng.randrange(len(ms))
    if kind == 0:
        del ms[i]
    elif kind == 1:
        ms.insert(i, Message(ms[i].channel_id, ms[i].log_time, ms[i].data, ms[i].chunk))
    elif kind == 2:
        j = rng.randrange(len(ms))
        ms[i].data, ms[j].data = ms[j].data, ms[i].data
    else:
        ms[i].log_time = rng.choice([0, HUGE, ms[i].log_time - (1 << 40)]) & HUGE
    return model


MODEL_MUTATIONS: dict[str, Callable[[Model, random.Random], Model]] = {
    "arrow_block": arrow_block,
    "metadata": metadata,
    "episode_json": episode_json,
    "schema_channel": schema_channel,
    "messages": messages,
    "null_block": null_block,
    "field_metadata": field_metadata,
}
RAW_MUTATIONS: dict[str, Callable[[bytes, random.Random], bytes]] = {
    "truncate": truncate,
    "flip": flip,
    "chunks": chunks,
    "flip_crc_fixed": flip_crc_fixed,
    "inner_length": inner_length,
    "huge_length": huge_length,
    "random_bytes": random_bytes,
    "special": special,
    "zstd_bomb": zstd_bomb,
}
KINDS = sorted(MODEL_MUTATIONS) + sorted(RAW_MUTATIONS)
"""Every mutation, by name."""


def mutate(base: bytes, kind: str, seed: int, *, plain: bool = False) -> bytes:
    """Mutate ``base`` by the mutation ``kind``, deterministically from ``seed``.

    ``plain`` base files are uncompressed (raw CRC-fixed mutations need that).
    """
    rng = random.Random(f"{kind}:{seed}")
    if kind in MODEL_MUTATIONS:
        model = MODEL_MUTATIONS[kind](read_model(base), rng)
        return write_model(
            model,
            compressed=not plain and rng.random() < 0.8,
            finished=model.finished and rng.random() < 0.85,
        )
    if kind in ("flip_crc_fixed", "inner_length") and not plain:
        base = write_model(read_model(base), compressed=False)
    if kind == "zstd_bomb" and plain:
        base = write_model(read_model(base), compressed=True)
    return RAW_MUTATIONS[kind](base, rng)


# ----------------------------------------------------------------------------- driving


@dataclass
class Outcome:
    """What driving one file did: the library errors raised (by entry point) and CLI results."""

    errors: dict[str, str] = field(default_factory=dict)
    cli: dict[str, int] = field(default_factory=dict)


class Escaped(AssertionError):
    """An exception outside the library's tree, or a CLI answer out of contract."""


_RERUN = importlib.util.find_spec("rerun") is not None


def _call(outcome: Outcome, name: str, fn: Callable[[], Any]) -> Any:
    try:
        return fn()
    except EpisodeAuditError as exc:
        outcome.errors[name] = type(exc).__name__
        return None
    except Exception as exc:
        raise Escaped(
            f"{name}: {type(exc).__name__} escaped: {exc!s:.300}\n{traceback.format_exc()}"
        ) from exc


def drive_library(path: Path, scratch: Path, outcome: Outcome) -> None:
    """Every library entry point a user can reach with a file."""
    from episode_audit import check, export, recover, replay, report
    from episode_audit.cli.render.show import episode_output, summary_output

    def reading() -> None:
        ev = open_evidence(path)
        ev.episodes()
        ev.resets()
        ev.steps(columns=["episode", "reward"])
        ev.observation_codec  # noqa: B018
        ev.action_codec  # noqa: B018

    def streaming() -> None:
        ev = open_evidence(path)
        for _ in ev.iter_step_batches():
            pass
        for _ in ev.scan():
            pass
        ev.steps()

    def episodes() -> None:
        ev = open_evidence(path)
        for n, episode in enumerate(ev.iter_episodes()):
            if n >= 3:
                break
            ev.episode(episode.index)

    def show() -> None:
        ev = open_evidence(path)
        for output in ("json", "table", "markdown"):
            summary_output(ev, output)  # type: ignore[arg-type]
        first = ev.episodes().column("episode").to_pylist()[:1]
        for index in first:
            episode_output(ev, index, 0, 5, "table")
            episode_output(ev, index, None, None, "json")

    _call(outcome, "reading", reading)
    _call(outcome, "streaming", streaming)
    _call(outcome, "episodes", episodes)
    _call(outcome, "check", lambda: check([path]))
    _call(outcome, "report", lambda: report([path], by="all"))
    _call(outcome, "show", show)
    _call(outcome, "export", lambda: export([path], scratch / "export", overwrite=True))
    _call(
        outcome,
        "export_foxglove",
        lambda: export([path], scratch / "foxglove", to="foxglove", overwrite=True),
    )
    if _RERUN:  # (an extra: ``pip install 'episode-audit[rerun]'``; the dev install has it)
        _call(
            outcome,
            "export_rerun",
            lambda: export([path], scratch / "rerun", to="rerun", overwrite=True),
        )
    _call(outcome, "replay", lambda: replay([path]))

    # a file the audit refuses is never "already finished: copied unchanged"
    refused = sorted({"reading", "streaming", "check"} & set(outcome.errors))

    def recovering() -> None:
        # what recover writes is finished evidence the audit reads (it skips damaged chunks)
        out = scratch / "recovered.mcap"
        result = recover(path, out, overwrite=True)
        if result.already_finished and refused:
            raise Escaped(f"recover copied unchanged a file that {refused} refused")
        if not open_evidence(out).finished:
            raise Escaped("recover wrote an unfinished file")
        check([out])
        replay([out])

    _call(outcome, "recover", recovering)


def drive_cli(path: Path, scratch: Path, outcome: Outcome, commands: list[str]) -> None:
    """The CLI on one file: exit 0, 1 or 2; on 2 exactly one stderr line naming the file."""
    from typer import testing

    from episode_audit.cli import app

    if not hasattr(testing, "_uncached_get_command"):
        # Building the click command from the Typer app costs ~40 ms, more than most inputs
        # take: the fuzzer builds it once (invoke() calls this module-level name).
        testing._uncached_get_command = testing._get_command  # type: ignore[attr-defined]
        testing._get_command = functools.cache(testing._get_command)  # type: ignore[attr-defined]
    runner = testing.CliRunner()
    argv = {
        "check": ["check", str(path)],
        "report": ["report", str(path), "--format", "json"],
        "show": ["show", str(path)],
        "show-episode": ["show", str(path), "--episode", "0", "--steps", "0:3"],
        "export": ["export", str(path), "--out", str(scratch / "cli-export"), "--overwrite"],
        "replay": ["replay", str(path)],
    }
    for command in commands:
        result = runner.invoke(app, argv[command])
        outcome.cli[command] = result.exit_code
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            exc = result.exception
            raise Escaped(
                f"cli {command}: {type(exc).__name__} escaped: {exc!s:.300}\n"
                + "".join(traceback.format_exception(exc))
            )
        if result.exit_code not in (0, 1, 2):
            raise Escaped(f"cli {command}: exit {result.exit_code}")
        lines = result.stderr.splitlines()
        if result.exit_code == 2:
            if len(lines) != 1 or str(path) not in lines[0] or "Traceback" in result.stderr:
                raise Escaped(f"cli {command}: exit 2 with stderr {result.stderr[:600]!r}")
        elif "Traceback" in result.stderr:
            raise Escaped(f"cli {command}: traceback on stderr {result.stderr[:600]!r}")


CLI_ROTATION = ["report", "show", "show-episode", "export", "replay"]


def drive(path: Path, scratch: Path, *, cli: list[str] | None = None) -> Outcome:
    """Drive ``path`` through the library and the CLI; raises :class:`Escaped` on a breach."""
    outcome = Outcome()
    drive_library(path, scratch, outcome)
    drive_cli(path, scratch, outcome, ["check"] if cli is None else cli)
    return outcome


# ----------------------------------------------------------------------------- the worker


class Deadline(Exception):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise Deadline


def _peak_rss_kib() -> int:
    """This process's peak resident set since its exec (``VmHWM``), in KiB."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # no /proc: an upper bound


def worker(corpus: Path, deadline_s: float) -> None:
    """Answer ``BASE KIND SEED`` lines on stdin with one JSON line each on stdout.

    The answer: ``status`` (``ok``, ``escaped``, ``timeout``), the error names, seconds taken,
    and the worker's peak RSS so far (``VmHWM``, KiB: ``ru_maxrss`` would count the parent's
    memory, which Linux carries across the fork and exec that start the worker). A hang inside
    C code that the alarm cannot interrupt is the parent's to catch (it kills the worker after
    its own deadline).
    """
    global BOMB_DIR
    bases = {p.stem: p.read_bytes() for p in corpus.glob("*.mcap")}
    BOMB_DIR = corpus
    signal.signal(signal.SIGALRM, _alarm)
    scratch = Path(tempfile.mkdtemp(prefix="fuzz-worker-"))
    out = sys.stdout
    sys.stdout = sys.stderr  # anything printed by accident must not garble the answers
    try:
        for line in sys.stdin:
            base, kind, seed_text = line.split()
            seed = int(seed_text)
            answer: dict[str, Any] = {"base": base, "kind": kind, "seed": seed}
            start = time.perf_counter()
            signal.setitimer(signal.ITIMER_REAL, deadline_s)
            try:
                data = mutate(bases[base], kind, seed, plain=base.endswith("_plain"))
                path = scratch / f"{base}-{kind}-{seed}.mcap"
                path.write_bytes(data)
                outcome = drive(path, scratch, cli=["check", CLI_ROTATION[seed % 5]])
                answer.update(status="ok", errors=outcome.errors, cli=outcome.cli)
                path.unlink()
            except Deadline:
                answer.update(status="timeout")
            except Escaped as exc:
                answer.update(status="escaped", detail=str(exc)[:4000])
            except BaseException as exc:
                answer.update(status="escaped", detail=f"harness: {type(exc).__name__}: {exc}")
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            answer["seconds"] = round(time.perf_counter() - start, 4)
            answer["maxrss_kib"] = _peak_rss_kib()
            out.write(json.dumps(answer) + "\n")
            out.flush()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    import os

    from episode_audit.read import chunks as _chunks

    # The harness runs with a lower cap than the library's 1 GiB default, so that inputs at
    # the cap stay cheap; the bound checked is peak memory against the cap.
    _chunks.MAX_RECORD_BYTES = int(os.environ.get("EPISODE_AUDIT_FUZZ_CAP_MIB", "64")) << 20
    limit = int(os.environ.get("EPISODE_AUDIT_FUZZ_AS_GIB", "4")) << 30
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))  # a safety net on shared machines
    worker(Path(sys.argv[1]), float(sys.argv[2]))
