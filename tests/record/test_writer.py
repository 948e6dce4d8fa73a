"""The evidence writer: many JSON messages at once write the bytes one at a time would."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest
from mcap.reader import make_reader

import episode_audit.record.writer as writer_module
from episode_audit.record import native
from episode_audit.record.writer import EvidenceWriter

_SCHEMA = {"type": "object"}
_BLOCK = pa.schema([("x", pa.int64())])


def _write(path: Path, many: bool, *, chunk: bool = True) -> bytes:
    """A file of two JSON channels and an Arrow channel, its messages written one at a time
    or a list at a time (times out of order, a flush between, a channel's first message in a
    list of several)."""
    w = EvidenceWriter(path, library="test")
    if not chunk:
        w._chunk = None  # as with an mcap whose writer keeps its state otherwise
    else:
        assert w._chunk is not None
        assert (w._chunk._frame is not None) == native.compiled()
    w.add_metadata("episode_audit.run", {"format_version": "1.0"})
    a = w.register_json_channel("/a", "a", _SCHEMA)
    b = w.register_json_channel("/b", "b", _SCHEMA)
    blocks = w.register_arrow_channel("/blocks", "block", _BLOCK)
    batches = [
        (a, [b'{"i":1}', b'{"i":2,"s":"x"}', b"{}"], [30, 10, 20]),
        (b, [b'{"j":[1,2]}'], [5]),
        (a, [b'{"i":3}', b'{"i":4}'], [40, 41]),
    ]
    for n, (channel, datas, times) in enumerate(batches):
        if many:
            w.write_json_many(channel, datas, times)
        else:
            for data, t in zip(datas, times, strict=True):
                w.write_json(channel, data, t)
        w.write_batch(blocks, pa.record_batch([pa.array([n])], schema=_BLOCK), 50 + n)
        if n == 1:
            w.flush()
    w.finish({"status": "finished"})
    return path.read_bytes()


@pytest.mark.parametrize("framing", ["compiled", "python"])
def test_a_list_of_messages_is_written_as_the_same_bytes_as_one_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, framing: str
) -> None:
    if framing == "compiled" and native.NATIVE is None:
        pytest.skip("the extension is not built (no C compiler at install)")
    monkeypatch.setenv(native.PURE_PYTHON_ENV, "1" if framing == "python" else "0")
    one = _write(tmp_path / "one.mcap", many=False)
    assert _write(tmp_path / "many.mcap", many=True) == one
    # and without the chunk's internals, through add_message
    assert _write(tmp_path / "fallback.mcap", many=True, chunk=False) == one
    with open(tmp_path / "many.mcap", "rb") as f:
        got = [
            (c.topic, m.log_time, m.sequence, m.data)
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
            if c.topic != "/blocks"
        ]
    assert got[:4] == [
        ("/a", 30, 0, b'{"i":1}'),
        ("/a", 10, 1, b'{"i":2,"s":"x"}'),
        ("/a", 20, 2, b"{}"),
        ("/b", 5, 4, b'{"j":[1,2]}'),
    ]


def test_a_list_that_would_overflow_the_chunk_goes_one_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a chunk closed by size in the middle of a list: add_message decides where
    monkeypatch.setattr(writer_module, "_CHUNK_SIZE", 40)
    one = _write(tmp_path / "one.mcap", many=False)
    assert _write(tmp_path / "many.mcap", many=True) == one


class _Refusing:
    """The evidence file, writing through ``f``; refuses every write while ``full``."""

    def __init__(self, f: object) -> None:
        self.f = f
        self.full = False
        self.threads: set[str] = set()

    def write(self, data: bytes) -> int:
        import errno
        import threading

        self.threads.add(threading.current_thread().name)
        if self.full:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.f.write(data)  # type: ignore[attr-defined,no-any-return]

    def close(self) -> None:
        self.f.close()  # type: ignore[attr-defined]


def test_a_background_flush_is_written_by_the_writer_thread_and_keeps_its_failure(
    tmp_path: Path,
) -> None:
    """Its failure is not raised: the next call waits for it, take_failures() has it once;
    the next flush writes what it could not."""
    path = tmp_path / "run.mcap"
    w = EvidenceWriter(path, library="test")
    disk = _Refusing(w._sink._f)
    w._sink._f = disk  # type: ignore[assignment]
    blocks = w.register_arrow_channel("/blocks", "block", _BLOCK)
    w.write_batch(blocks, pa.record_batch([pa.array([1])], schema=_BLOCK), 1)
    disk.full = True
    w.flush(background=True)  # (refused in the writer thread: not raised here)
    w.write_batch(blocks, pa.record_batch([pa.array([2])], schema=_BLOCK), 2)
    (failure,) = w.take_failures()
    assert isinstance(failure, OSError)
    assert w.take_failures() == []
    with pytest.raises(OSError, match="No space left"):
        w.flush()  # a flush waited for raises its own failure
    disk.full = False
    w.flush(background=True)
    w.drop()  # (waits for the flush: nothing left to drop)
    assert disk.threads == {"episode-audit-writer"}
    w.finish({"status": "finished"})
    with open(path, "rb") as f:
        rows = [
            pa.ipc.open_stream(m.data).read_all()["x"][0].as_py()
            for _, _, m in make_reader(f).iter_messages()
        ]
    assert rows == [1, 2]
    assert w.take_failures() == []


def _new_stream(batch: pa.RecordBatch) -> bytes:
    out = pa.BufferOutputStream()
    with pa.ipc.new_stream(out, batch.schema) as ipc:
        ipc.write_batch(batch)
    return bytes(out.getvalue().to_pybytes())


def _step_batch() -> pa.RecordBatch:
    """Steps as a recorder writes them: field metadata, a fixed-size list, a map, nulls."""
    from episode_audit.format.schemas import step_schema

    obs = pa.field("observation", pa.list_(pa.float32(), 2), metadata={"k": "v"})
    schema = step_schema(pa.field("action", pa.int64()), obs)
    row = {"episode": 0, "time_ns": 5, "reward": 1.0, "terminated": False, "truncated": False}
    rows = [
        {**row, "step": 0, "action": 1, "observation": [0.5, 1.5], "terms": [("a", 1.0)]},
        {**row, "step": 1, "observation": [2.5, 3.5], "outcome": "success", "info": "{}"},
        {**row, "step": 2, "terms": [("a", 2.0), ("b", float("nan"))], "terminated": True},
    ]
    return pa.RecordBatch.from_pylist(rows, schema=schema)


def test_a_batch_is_written_as_the_bytes_of_an_arrow_stream() -> None:
    batch = _step_batch()
    assert writer_module.ipc_stream(batch) == _new_stream(batch)
    empty = batch.slice(0, 0)
    assert writer_module.ipc_stream(empty) == _new_stream(empty)
    # a dictionary column: its stream holds a dictionary batch, so new_stream writes it
    coded = pa.record_batch([pa.array(["x", "y", "x"]).dictionary_encode()], names=["d"])
    assert writer_module.ipc_parts(coded) == (pa.py_buffer(_new_stream(coded)),)


def test_a_batch_of_another_schema_than_its_channel_is_written_with_its_own(
    tmp_path: Path,
) -> None:
    w = EvidenceWriter(tmp_path / "f.mcap", library="test")
    channel = w.register_arrow_channel("/blocks", "block", _BLOCK)
    other = pa.record_batch([pa.array([7])], schema=_BLOCK.with_metadata({"m": "1"}))
    w.write_batch(channel, pa.record_batch([pa.array([1])], schema=_BLOCK), 1)
    w.write_batch(channel, other, 2)
    w.finish({"status": "finished"})
    with open(tmp_path / "f.mcap", "rb") as f:
        datas = [m.data for _, _, m in make_reader(f).iter_messages()]
    assert datas[1] == _new_stream(other)
    assert pa.ipc.open_stream(datas[1]).schema.metadata == {b"m": b"1"}


_FRAMES = pa.schema([("frame", pa.binary(1 << 18)), ("i", pa.int64())])


def _frames(n: int, seed: int) -> pa.RecordBatch:
    """``n`` rows of 256 KiB (camera frames): a block past ``_DIRECT_BYTES`` (but for 0 rows)."""
    data = bytes((seed + k) % 251 for k in range(1 << 18))
    return pa.record_batch([pa.array([data] * n, pa.binary(1 << 18)), pa.array(range(n))], _FRAMES)


def _blocks_written(path: Path, direct: bool, monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """Write big and small blocks, the big ones straight into the chunk or (not ``direct``)
    serialized apart; the messages' data."""
    taken: list[bool] = []
    real = writer_module._OpenChunk.add_stream

    def add_stream(self: object, *args: object) -> bool:
        done = real(self, *args) if direct else False  # type: ignore[arg-type]
        taken.append(done)
        return done

    monkeypatch.setattr(writer_module._OpenChunk, "add_stream", add_stream)
    w = EvidenceWriter(path, library="test")
    channel = w.register_arrow_channel("/frames", "frames", _FRAMES)
    for n, rows in enumerate([8, 1, 12, 0, 5]):
        w.write_batch(channel, _frames(rows, n), 10 + n)
        if n == 2:
            w.flush()
    w.finish({"status": "finished"})
    assert taken == [direct] * 4  # (the blocks of 8, 1, 12 and 5 frames: 128 KiB or more)
    with open(path, "rb") as f:
        return [m.data for _, _, m in make_reader(f).iter_messages()]


def test_big_blocks_are_written_into_the_chunk_as_the_bytes_of_an_arrow_stream(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    direct = _blocks_written(tmp_path / "direct.mcap", True, monkeypatch)
    apart = _blocks_written(tmp_path / "apart.mcap", False, monkeypatch)
    assert direct == apart == [_new_stream(_frames(r, n)) for n, r in enumerate([8, 1, 12, 0, 5])]
    assert (tmp_path / "direct.mcap").read_bytes() == (tmp_path / "apart.mcap").read_bytes()


def test_a_big_block_whose_stream_is_not_the_size_foreseen_is_written_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the chunk is cut back to where the message began; the block goes in as pieces
    monkeypatch.setattr(pa.ipc, "get_record_batch_size", lambda batch: 1 << 21)
    w = EvidenceWriter(tmp_path / "f.mcap", library="test")
    channel = w.register_arrow_channel("/frames", "frames", _FRAMES)
    w.write_batch(channel, _frames(1, 0), 1)
    w.write_batch(channel, _frames(6, 1), 2)
    w.finish({"status": "finished"})
    with open(tmp_path / "f.mcap", "rb") as f:
        datas = [m.data for _, _, m in make_reader(f).iter_messages()]
    assert datas == [_new_stream(_frames(1, 0)), _new_stream(_frames(6, 1))]


def test_a_ctrl_c_while_a_big_block_is_written_leaves_no_half_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    w = EvidenceWriter(tmp_path / "f.mcap", library="test")
    channel = w.register_arrow_channel("/frames", "frames", _FRAMES)
    w.write_batch(channel, _frames(1, 0), 1)

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(pa.ipc, "new_stream", interrupted)
        with pytest.raises(KeyboardInterrupt):
            w.write_batch(channel, _frames(2, 1), 2)
    w.write_batch(channel, _frames(3, 2), 3)
    w.finish({"status": "finished"})
    with open(tmp_path / "f.mcap", "rb") as f:
        datas = [m.data for _, _, m in make_reader(f).iter_messages()]
    assert datas == [_new_stream(_frames(1, 0)), _new_stream(_frames(3, 2))]
