"""Hostile and broken input: property tests and the fuzz harness over real evidence files.

The mutations and the driver live in ``tests/fuzzing.py``. Invariants, for every input: only
:class:`~episode_audit.errors.EpisodeAuditError` escapes the library; the CLI exits 0, 1 or 2,
and on 2 prints exactly one stderr line naming the file; no input takes longer than its
deadline; the worker's peak memory stays under a bound derived from the reader's caps.

The harness (:func:`run_harness`) runs inputs in a worker subprocess (``tests/fuzzing.py``) with
a per-input deadline (``setitimer``; the parent kills a worker that does not answer in time)
and reports inputs, escapes, hangs, the slowest input and peak RSS. ``make test`` runs a
sample; ``make test-long`` runs ``EPISODE_AUDIT_FUZZ`` inputs (default 10 000).
"""

from __future__ import annotations

import itertools
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from episode_audit import EvidenceError, check, open_evidence
from episode_audit.cli import app
from episode_audit.read import iter_records

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import fuzzing  # noqa: E402

REPO = HERE.parent
DEADLINE_S = float(os.environ.get("EPISODE_AUDIT_FUZZ_DEADLINE", "30"))
"""Per-input time bound (seconds): the worker's alarm; the parent waits a little longer."""
CAP_MIB = 64
"""The reader's chunk cap in the harness's worker (``MAX_RECORD_BYTES``, lowered from 1 GiB)."""
PEAK_RSS_BOUND_MIB = 1024
"""What the worker's peak RSS must stay under: its own ~300 MB plus a few chunks at the cap."""

PROFILE = settings(
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@pytest.fixture(scope="session")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return fuzzing.build_corpus(tmp_path_factory.mktemp("fuzz-corpus"))


@pytest.fixture(scope="session")
def bases(corpus: dict[str, Path]) -> dict[str, bytes]:
    return {name: path.read_bytes() for name, path in corpus.items()}


def _drive_bytes(data: bytes, tmp: Path, *, cli: list[str] | None = None) -> fuzzing.Outcome:
    path = tmp / "input.mcap"
    path.write_bytes(data)
    return fuzzing.drive(path, tmp, cli=cli)


# ----------------------------------------------------------------------------- the corpus


def test_the_corpus_is_real_evidence(corpus: dict[str, Path]) -> None:
    """The base files read cleanly, and the layout parser and model agree with the reader."""
    for name, path in corpus.items():
        ev = open_evidence(path)
        assert ev.finished == (not name.endswith("_torn")), name
        assert ev.steps().num_rows > 20
        data = path.read_bytes()
        _, chunks = fuzzing.layout(data)
        assert [c.record.offset for c in chunks] == [r.offset for r in ev._chunks]
        model = fuzzing.read_model(data)
        again = fuzzing.write_model(model)
        copy = path.with_suffix(".copy")
        copy.write_bytes(again)
        assert open_evidence(copy).steps().equals(ev.steps())
        assert open_evidence(copy).episodes().equals(ev.episodes())
        copy.unlink()
        # every record class a truncation or flip aims at is there
        classes = fuzzing._classes(data)
        assert {"magic", "header", "metadata", "chunk_header", "chunk_records"} <= set(classes)
        if ev.finished:
            assert {"message_index", "data_end", "summary", "footer"} <= set(classes)
    terms = open_evidence(corpus["terms"])
    assert terms.run.observation_space["type"] == "Dict"
    assert terms.run.action_space["type"] == "Tuple"
    assert set(terms.episodes().column("outcome").to_pylist()) >= {"success", "failure"}


# ----------------------------------------------------------------------------- properties


@settings(PROFILE, max_examples=60)
@given(data=st.data())
def test_truncation_anywhere_raises_only_library_errors(
    bases: dict[str, bytes], tmp_path: Path, data: st.DataObject
) -> None:
    base = data.draw(st.sampled_from(sorted(bases)), label="base")
    cut = data.draw(st.integers(0, len(bases[base])), label="cut")
    outcome = _drive_bytes(bases[base][:cut], tmp_path, cli=[])
    if cut < 8:
        assert outcome.errors["reading"] == "NotEvidenceError"


@settings(PROFILE, max_examples=60)
@given(data=st.data())
def test_flips_with_valid_crcs_raise_only_library_errors(
    bases: dict[str, bytes], tmp_path: Path, data: st.DataObject
) -> None:
    """Flips inside an uncompressed chunk or the summary, CRCs recomputed: semantics only."""
    base = bases["cartpole_plain"]
    classes = fuzzing._classes(base)
    where = data.draw(st.sampled_from(["chunk_records", "summary"]), label="where")
    start, stop = data.draw(st.sampled_from(classes[where]), label="record")
    out = bytearray(base)
    for _ in range(data.draw(st.integers(1, 3), label="flips")):
        at = data.draw(st.integers(start, stop - 1), label="at")
        out[at] = data.draw(st.integers(0, 255), label="value")
    fuzzing._fix_crcs(out)
    _drive_bytes(bytes(out), tmp_path, cli=[])


@settings(PROFILE, max_examples=40)
@given(noise=st.binary(max_size=2048), magic=st.booleans())
def test_random_bytes_raise_only_library_errors(tmp_path: Path, noise: bytes, magic: bool) -> None:
    outcome = _drive_bytes((fuzzing.MAGIC if magic else b"") + noise, tmp_path, cli=[])
    assert outcome.errors["reading"] in ("NotEvidenceError", "CorruptEvidenceError")


@settings(PROFILE, max_examples=80)
@given(
    kind=st.sampled_from(sorted(fuzzing.MODEL_MUTATIONS)),
    base=st.sampled_from(["cartpole", "terms", "terms_torn", "vector", "agents", "recovered"]),
    seed=st.integers(0, 10**6),
)
def test_semantic_mutations_raise_only_library_errors(
    bases: dict[str, bytes], tmp_path: Path, kind: str, base: str, seed: int
) -> None:
    """Valid MCAP (CRCs, indexes) with wrong content: schemas, blocks, metadata, records."""
    _drive_bytes(fuzzing.mutate(bases[base], kind, seed), tmp_path, cli=[])


# ----------------------------------------------------------------------------- named cases


def _model_case(bases: dict[str, bytes], change: Any, base: str = "cartpole") -> bytes:
    model = fuzzing.read_model(bases[base])
    change(model)
    return fuzzing.write_model(model)


def _replace_block(model: fuzzing.Model, topic: str, data: bytes) -> None:
    model.messages[model.on(topic)[0]].data = data


@pytest.mark.parametrize(
    ("case", "match"),
    [
        ("compressed_ipc", r"uses Arrow IPC body compression"),
        ("ipc_bomb", r"uses Arrow IPC body compression"),
        ("wrong_type", r"does not have the expected columns: 'reward' is string"),
        ("missing_column", r"does not have the expected columns: 'episode' is missing"),
        ("null_giant", r"does not have the expected columns: 'episode' is null"),
        ("garbage", r"is not a valid Arrow stream"),
    ],
)
def test_bad_step_blocks_are_corruption_naming_the_file(
    bases: dict[str, bytes], tmp_path: Path, case: str, match: str
) -> None:
    model = fuzzing.read_model(bases["cartpole"])
    batch = fuzzing._batch_of(model.messages[model.on(fuzzing.fmt.TOPIC_STEPS)[0]].data)
    blocks = {
        "compressed_ipc": lambda: fuzzing._arrow_stream(batch, compression="zstd"),
        "ipc_bomb": fuzzing._ipc_bomb,
        "wrong_type": lambda: fuzzing._arrow_stream(
            batch.set_column(
                batch.schema.get_field_index("reward"),
                "reward",
                batch.column("reward").cast("string"),
            )
        ),
        "missing_column": lambda: fuzzing._arrow_stream(batch.drop_columns(["episode"])),
        "null_giant": lambda: fuzzing._arrow_stream(fuzzing._null_giant(batch)),
        "garbage": lambda: b"\xff\xff\xff\xff" + bytes(100),
    }
    data = _model_case(bases, lambda m: _replace_block(m, fuzzing.fmt.TOPIC_STEPS, blocks[case]()))
    path = tmp_path / f"{case}.mcap"
    path.write_bytes(data)
    with pytest.raises(EvidenceError, match=rf"{case}\.mcap: .*{match}"):
        open_evidence(path).steps()


def test_a_block_with_another_schema_than_the_file_declares_is_corruption(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    model = fuzzing.read_model(bases["terms"])
    steps = model.on(fuzzing.fmt.TOPIC_STEPS)
    batch = fuzzing._batch_of(model.messages[steps[-1]].data)
    extra = batch.append_column("extra", fuzzing.pa.array(range(batch.num_rows)))
    model.messages[steps[-1]].data = fuzzing._arrow_stream(extra)
    path = tmp_path / "drift.mcap"
    fuzzing.write_model(model, path)
    with pytest.raises(EvidenceError, match=r"drift\.mcap: a step block .* schema of the others"):
        for _ in open_evidence(path).iter_step_batches():
            pass


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("recorder", "[]", r"'recorder': expected a JSON dict"),
        ("reward_terms", "1.5", r"'reward_terms': expected a JSON dict"),
        ("reward_terms", '{"constants": "x"}', r"'constants' to map term names to numbers"),
        ("reward_terms", '{"constants": {"a": true}}', r"'constants' to map term names to numbers"),
        ("env_spec", '"CartPole"', r"'env_spec': expected a JSON dict"),
        ("tags", '{"a": 1}', r"'tags': expected string values"),
        ("command_line", "[[1]]", r"'command_line': expected a list of strings"),
        ("versions", "[" * 100_000 + "]" * 100_000, r"nested too deeply"),
        ("command_line", "x" * ((1 << 20) + 1), r"exceeds the 1 MiB limit"),
        ("format_version", "3.1", r"format 3\.1, newer than this reader"),
        ("format_version", "1.0.0", r"'1\.0\.0' is not a version"),
    ],
)
def test_bad_run_metadata_names_the_key(
    bases: dict[str, bytes], tmp_path: Path, key: str, value: str, match: str
) -> None:
    def change(model: fuzzing.Model) -> None:
        model.run()[key] = value

    path = tmp_path / "meta.mcap"
    path.write_bytes(_model_case(bases, change))
    with pytest.raises(EvidenceError, match=rf"meta\.mcap: .*{match}"):
        open_evidence(path)


def test_episode_records_with_huge_numbers_are_corruption(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    def change(model: fuzzing.Model) -> None:
        blocks = model.channel(fuzzing.fmt.TOPIC_EPISODES)
        model.messages = [m for m in model.messages if m.channel_id != blocks]
        del model.channels[blocks]
        end = model.messages[model.on(fuzzing.fmt.TOPIC_EPISODE_END)[0]]
        record = json.loads(end.data)
        record["length"] = 10**30
        end.data = json.dumps(record).encode()

    path = tmp_path / "huge.mcap"
    path.write_bytes(_model_case(bases, change))
    with pytest.raises(EvidenceError, match=r"huge\.mcap: episode records have wrong types"):
        open_evidence(path).episodes()


def test_episode_blocks_with_unknown_outcomes_are_corruption(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    def change(model: fuzzing.Model) -> None:
        block = model.messages[model.on(fuzzing.fmt.TOPIC_EPISODES)[0]]
        batch = fuzzing._batch_of(block.data)
        i = batch.schema.get_field_index("outcome")
        outcome = fuzzing.pa.array(["won"] * batch.num_rows)
        block.data = fuzzing._arrow_stream(batch.set_column(i, "outcome", outcome))

    path = tmp_path / "won.mcap"
    path.write_bytes(_model_case(bases, change))
    with pytest.raises(EvidenceError, match=r"won\.mcap: an episode block has unknown outcome"):
        open_evidence(path).episodes()


@pytest.mark.parametrize("content_size", [True, False])
def test_a_zstd_chunk_that_inflates_to_gigabytes_is_refused(
    bases: dict[str, bytes], tmp_path: Path, corpus: dict[str, Path], content_size: bool
) -> None:
    data = bases["cartpole"]
    _, chunks = fuzzing.layout(data)
    c = chunks[1]
    frame = fuzzing.bomb(content_size=content_size)
    assert len(frame) < 1 << 20  # 4 GiB of zeros in well under a megabyte
    body = bytearray(data[c.record.body : c.records_at - 8])
    body += fuzzing.struct.pack("<Q", len(frame)) + frame  # declares its old size
    bad = data[: c.record.offset] + fuzzing.struct.pack("<BQ", 0x06, len(body)) + bytes(body)
    path = tmp_path / "bomb.mcap"
    path.write_bytes(bad)  # torn after the bomb: read by a linear scan
    with pytest.raises(EvidenceError, match=r"bomb\.mcap: chunk at byte \d+ is damaged"):
        open_evidence(path).steps()


def test_a_fifo_is_not_evidence_and_does_not_block(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    with pytest.raises(EvidenceError, match=r"pipe\.mcap: not a regular file"):
        open_evidence(fifo)
    with pytest.raises(EvidenceError, match=r"pipe\.mcap: not a regular file"):
        next(iter_records(fifo))  # (what recovery walks)


# ----------------------------------------------------------------------------- mixed directory


def test_a_directory_of_mixed_files(corpus: dict[str, Path], tmp_path: Path) -> None:
    """Good files are processed; each bad one gets its own stderr line; exit 2."""
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in ("cartpole", "terms_torn"):
        (mixed / f"{name}.mcap").write_bytes(corpus[name].read_bytes())
    (mixed / "empty.mcap").write_bytes(b"")
    (mixed / "garbage.mcap").write_bytes(b"garbage" * 100)
    (mixed / "cut.mcap").write_bytes(corpus["cartpole"].read_bytes()[:30])
    (mixed / "notes.txt").write_text("not evidence, not *.mcap: ignored")
    (mixed / "sub.mcap").mkdir()  # a directory named like a file: ignored
    bad = ["cut.mcap", "empty.mcap", "garbage.mcap"]
    runner = CliRunner()
    for argv in (
        ["check", str(mixed), "--format", "json"],
        ["report", str(mixed), "--format", "json"],
        ["replay", str(mixed), "--format", "json"],
        ["export", str(mixed), "--out", str(tmp_path / "out")],
    ):
        result = runner.invoke(app, argv)
        assert result.exit_code == 2, (argv, result.output)
        lines = [x for x in result.stderr.splitlines() if not x.startswith("episode-audit: note:")]
        assert len(lines) == len(bad), (argv, lines)
        for line, name in zip(lines, bad):
            assert line.startswith("episode-audit: error: ") and name in line, (argv, line)
        if argv[0] != "export":
            assert "cartpole.mcap" in result.stdout and "terms_torn.mcap" in result.stdout
    exported = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert exported == ["cartpole.steps.parquet", "episodes.parquet", "terms_torn.steps.parquet"]


# ----------------------------------------------------------------------------- the harness


@dataclass
class Summary:
    inputs: int = 0
    escaped: list[dict[str, Any]] = field(default_factory=list)
    hangs: list[str] = field(default_factory=list)
    max_seconds: float = 0.0
    slowest: str = ""
    peak_rss_mib: float = 0.0
    by_kind: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)

    def line(self) -> str:
        return (
            f"fuzz: {self.inputs} inputs, {len(self.escaped)} escaped, {len(self.hangs)} hangs, "
            f"slowest {self.max_seconds:.2f} s ({self.slowest}), "
            f"peak RSS {self.peak_rss_mib:.0f} MiB"
        )


class _Worker:
    """``tests/fuzzing.py`` in a subprocess; answers one JSON line per input.

    Its temporary directory is a folder of ours, removed by :meth:`stop`: a worker killed (a
    hang) cannot remove its scratch files itself.
    """

    def __init__(self, corpus: Path) -> None:
        self.temp = Path(tempfile.mkdtemp(prefix="fuzz-worker-"))
        env = dict(os.environ, PYTHONPATH=str(REPO), EPISODE_AUDIT_FUZZ_CAP_MIB=str(CAP_MIB))
        env.setdefault("MUJOCO_GL", "egl")
        env["TMPDIR"] = str(self.temp)
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE / "fuzzing.py"), str(corpus), str(DEADLINE_S)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            cwd=REPO,
            env=env,
        )
        self.answers: queue.Queue[str | None] = queue.Queue()
        self.pump = threading.Thread(target=self._pump, daemon=True)
        self.pump.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.answers.put(line)
        self.answers.put(None)

    def ask(self, job: str, timeout: float) -> dict[str, Any] | None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(job + "\n")
        self.proc.stdin.flush()
        try:
            line = self.answers.get(timeout=timeout)
        except queue.Empty:
            return None
        return None if line is None else json.loads(line)

    def stop(self) -> None:
        """End the worker (at the end of its input if it answers, else killed); remove its files."""
        try:
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # the worker's loop ends
            self.proc.wait(timeout=10)
        except (BrokenPipeError, subprocess.TimeoutExpired):
            self.proc.kill()  # hung
            self.proc.wait()
        self.pump.join()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        shutil.rmtree(self.temp, ignore_errors=True)


def jobs(bases: list[str], count: int, first_seed: int = 0) -> list[str]:
    """``count`` inputs: every (base, kind) pair in turn, seeds counting up."""
    pairs = [(b, k) for k in fuzzing.KINDS for b in bases]
    cycle = itertools.cycle(pairs)
    return [f"{b} {k} {first_seed + i}" for i, (b, k) in zip(range(count), cycle)]


def run_harness(corpus: Path, work: list[str], workers: int = 1) -> Summary:
    """Run ``work`` in ``workers`` worker processes; a silent worker is a hang, then replaced."""
    summary = Summary()
    lock = threading.Lock()
    pending = queue.Queue[str]()
    for job in work:
        pending.put(job)

    def loop() -> None:
        worker = _Worker(corpus)
        try:
            while True:
                try:
                    job = pending.get_nowait()
                except queue.Empty:
                    return
                answer = worker.ask(job, DEADLINE_S + 30)
                with lock:
                    summary.inputs += 1
                    if answer is None or answer["status"] == "timeout":
                        summary.hangs.append(job)
                        if answer is None:
                            worker.stop()
                            worker = _Worker(corpus)
                        continue
                    if answer["status"] != "ok":
                        summary.escaped.append(answer)
                    kind = answer["kind"]
                    summary.by_kind[kind] = summary.by_kind.get(kind, 0) + 1
                    for name in answer.get("errors", {}).values():
                        summary.errors[name] = summary.errors.get(name, 0) + 1
                    if answer["seconds"] > summary.max_seconds:
                        summary.max_seconds, summary.slowest = answer["seconds"], job
                    summary.peak_rss_mib = max(summary.peak_rss_mib, answer["maxrss_kib"] / 1024)
        finally:
            worker.stop()

    threads = [threading.Thread(target=loop) for _ in range(workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return summary


def _assert_clean(summary: Summary, expected: int) -> None:
    print(summary.line())
    print("fuzz: library errors raised:", json.dumps(summary.errors, sort_keys=True))
    assert summary.inputs == expected
    assert summary.escaped == [], summary.escaped[0].get("detail")
    assert summary.hangs == []
    assert summary.max_seconds < DEADLINE_S
    assert summary.peak_rss_mib < PEAK_RSS_BOUND_MIB
    assert set(summary.by_kind) == set(fuzzing.KINDS)


def test_fuzz_sample(corpus: dict[str, Path]) -> None:
    """A sample of every mutation on every base file, in a worker, under the deadline."""
    count = int(os.environ.get("EPISODE_AUDIT_FUZZ_SAMPLE", "130"))
    summary = run_harness(corpus["cartpole"].parent, jobs(sorted(corpus), count))
    _assert_clean(summary, count)


@pytest.mark.parametrize("seed", range(6))
def test_nulls_where_the_format_allows_none_are_refused_everywhere(
    bases: dict[str, bytes], tmp_path: Path, seed: int
) -> None:
    """The mutation class that found them: a block's validity bitmap rewritten."""
    data = fuzzing.mutate(bases["terms"], "null_block", seed)
    outcome = _drive_bytes(data, tmp_path, cli=["check"])
    assert "CorruptEvidenceError" in (
        outcome.errors.get("reading"),
        outcome.errors.get("streaming"),
    )
    assert outcome.errors.get("recover") == "CorruptEvidenceError"  # refused, never copied
    assert outcome.cli["check"] == 2


@pytest.mark.parametrize("base", ["cartpole", "cartpole_torn"])
@pytest.mark.parametrize("seed", range(4))
def test_duplicated_spliced_and_partial_chunks_raise_only_library_errors(
    bases: dict[str, bytes], tmp_path: Path, base: str, seed: int
) -> None:
    _drive_bytes(fuzzing.mutate(bases[base], "chunks", seed), tmp_path, cli=["check"])


@pytest.mark.slow
def test_fuzz_long(corpus: dict[str, Path]) -> None:
    """``EPISODE_AUDIT_FUZZ`` (default 10 000) inputs, seeds apart from the quick sample's."""
    count = int(os.environ.get("EPISODE_AUDIT_FUZZ", "10000"))
    workers = int(os.environ.get("EPISODE_AUDIT_FUZZ_WORKERS", "2"))
    start = time.monotonic()
    summary = run_harness(
        corpus["cartpole"].parent, jobs(sorted(corpus), count, first_seed=10**6), workers
    )
    print(f"fuzz: {time.monotonic() - start:.0f} s with {workers} workers")
    _assert_clean(summary, count)


def test_column_names_that_are_not_utf8_are_corruption(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    def change(model: fuzzing.Model) -> None:
        block = model.messages[model.on(fuzzing.fmt.TOPIC_EPISODES)[0]]
        data = bytearray(block.data)
        at = data.find(b"failure_label")
        data[at : at + 2] = b"\xd8A"  # same length, not UTF-8
        block.data = bytes(data)

    path = tmp_path / "names.mcap"
    path.write_bytes(_model_case(bases, change))
    with pytest.raises(EvidenceError, match=r"names\.mcap: .* column names that are not UTF-8"):
        open_evidence(path).episodes()


def test_a_recorded_env_spec_of_wrong_shape_is_not_replayable(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    from episode_audit import replay

    def change(model: fuzzing.Model) -> None:
        spec = json.loads(model.run()["env_spec"])
        spec["kwargs"] = 5
        model.run()["env_spec"] = json.dumps(spec)

    path = tmp_path / "spec.mcap"
    path.write_bytes(_model_case(bases, change))
    result = replay([path])
    assert {e.status for e in result.episodes} == {"not_replayable"}
    assert result.episodes[0].reason == (
        "the recorded env kwargs are not a mapping (int); pass --env-factory MODULE:CALLABLE "
        "that builds the env"
    )


def test_a_space_description_that_does_not_fit_its_column_is_not_decoded(
    bases: dict[str, bytes], tmp_path: Path
) -> None:
    """Found by the long harness: a Tuple description with no spaces over a Tuple column."""

    def change(model: fuzzing.Model) -> None:
        model.run()["action_space"] = '{"type": "Tuple", "spaces": []}'

    path = tmp_path / "misfit.mcap"
    path.write_bytes(_model_case(bases, change, base="terms"))
    ev = open_evidence(path)
    assert ev.action_codec is None
    result = check([path])
    assert "action_space_unchecked" in {f.code for f in result.findings}


@pytest.mark.parametrize(
    ("base", "kind", "seed"),
    [
        ("vector", "flip", 1003681),  # a message-index offset past ssize_t: OverflowError
        ("agents", "metadata", 1004207),  # reward_terms.constants not a dict: AttributeError
        ("terms", "metadata", 1000116),  # a Tuple description over another column: TypeError
        # a recovery's run-end value nested 5 000 deep: RecursionError (check, replay)
        ("recovered", "metadata", 1000307),  # damaged_episodes
        ("recovered", "metadata", 1000537),  # damaged
    ],
)
def test_inputs_the_long_harness_found(
    bases: dict[str, bytes], tmp_path: Path, base: str, kind: str, seed: int
) -> None:
    _drive_bytes(fuzzing.mutate(bases[base], kind, seed), tmp_path, cli=["check", "show"])
