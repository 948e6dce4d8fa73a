from __future__ import annotations

import io
import json
import logging
import os
import re
import shutil
import subprocess
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from PIL import Image
from typer.testing import CliRunner

from episode_audit import ConfigurationError, EvidenceError, NotEvidenceError, open_evidence
from episode_audit.cli import app
from episode_audit.export import export
from episode_audit.export._values import NONFINITE_NULL
from tests.support.disk import export_stderr, fill_disk
from tests.support.viewer_files import (
    aec_file,
    camera_file,
    leaves,
    random_cartpole_file,
    recorded_resets,
    vector_file,
)

foxglove = pytest.importorskip("foxglove")

ROOT = Path(__file__).resolve().parents[1]
JS = ROOT / "tests" / "js"
MAKERS = {"camera": camera_file, "vector": vector_file, "aec": aec_file}


def _foxglove_schema_names() -> set[str]:
    """The schemas Foxglove publishes (foxglove-sdk ships each as a message class)."""
    names = set()
    for name in dir(foxglove.messages):
        schema = getattr(getattr(foxglove.messages, name), "get_schema", None)
        if schema is not None:
            names.add(schema().name)
    return names


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """Each kind of evidence file and its Foxglove export."""
    tmp = tmp_path_factory.mktemp("foxglove")
    files = {"clean": ROOT / "fixtures" / "clean.mcap"}
    files.update({name: make(tmp / f"{name}.mcap") for name, make in MAKERS.items()})
    out = {}
    for name, source in files.items():
        target = tmp / f"{name}.foxglove.mcap"
        export([source], target, to="foxglove")
        out[name] = (source, target)
    return out


@pytest.fixture(scope="module")
def mcap_core(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/js installed (``npm ci``) in a temporary directory; its reader script's path."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("Node.js and npm are not installed: the @mcap/core reader test needs them")
    where = tmp_path_factory.mktemp("mcap-core")
    for name in ("package.json", "package-lock.json", "list_mcap.mjs"):
        shutil.copy(JS / name, where / name)
    done = subprocess.run(
        ["npm", "ci", "--no-audit", "--no-fund"], cwd=where, capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.skip(f"npm ci of tests/js failed (no registry?): {done.stderr.strip()[-300:]}")
    return where / "list_mcap.mjs"


def _read_with_mcap_core(script: Path, path: Path, limit: int) -> dict[str, Any]:
    done = subprocess.run(
        ["node", str(script), str(path), str(limit)], capture_output=True, text=True, check=True
    )
    result: dict[str, Any] = json.loads(done.stdout)
    return result


@pytest.mark.parametrize("name", ["clean", "camera", "vector", "aec"])
def test_mcap_core_reads_the_export(
    exported: dict[str, tuple[Path, Path]], mcap_core: Path, name: str
) -> None:
    """The TypeScript reader lists Foxglove schemas only, and a step's reward is the file's;
    an episode's reset (step -1) has none."""
    source, target = exported[name]
    ev = open_evidence(source)
    read = _read_with_mcap_core(mcap_core, target, limit=1000)
    channels = {c["topic"]: c for c in read["channels"]}
    published = _foxglove_schema_names()
    for channel in channels.values():
        if channel["schemaEncoding"] == "protobuf":  # Foxglove's own schemas
            assert channel["schemaName"] in published, channel
            assert channel["messageEncoding"] == "protobuf"
        else:  # plottable numbers: JSON with a JSON Schema, as Foxglove reads them
            assert (channel["schemaEncoding"], channel["messageEncoding"]) == ("jsonschema", "json")
            assert channel["schemaName"] == "episode_audit.Step"
    episodes = ev.episodes().num_rows
    assert channels["/log"]["schemaName"] == "foxglove.Log"
    assert channels["/log"]["messages"] == episodes
    assert channels["/episodes"]["schemaName"] == "foxglove.Event"
    assert channels["/episodes"]["messages"] == episodes
    steps = ev.steps(columns=["episode", "step", "reward"]).to_pylist()
    resets = ev.resets().num_rows
    step_topics = [t for t in channels if t.endswith("/steps")]
    assert sum(channels[t]["messages"] for t in step_topics) == len(steps) + resets
    recorded = {(s["episode"], s["step"]): s["reward"] for s in steps}
    recorded.update({(e, -1): None for e in ev.resets().column("episode").to_pylist()})
    seen = [m for t in step_topics for m in read["first"][t]]
    assert seen and all(recorded[(m["episode"], m["step"])] == m.get("reward") for m in seen)
    if name == "camera":
        assert channels["/camera/observation.camera"]["schemaName"] == "foxglove.CompressedImage"
        assert channels["/camera/observation.camera"]["messages"] == len(steps) + resets


@pytest.mark.parametrize("name", ["clean", "camera"])
def test_mcap_core_reads_the_evidence_file_itself(
    exported: dict[str, tuple[Path, Path]], mcap_core: Path, name: str
) -> None:
    """Its chunks (zstd with long-distance matching: record/chunks.py) decode in @mcap/core."""
    source, _ = exported[name]
    read = _read_with_mcap_core(mcap_core, source, limit=1)
    counts = {c["topic"]: c["messages"] for c in read["channels"]}
    with open(source, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert counts == {
        channel.topic: summary.statistics.channel_message_counts.get(channel_id, 0)
        for channel_id, channel in summary.channels.items()
    }
    assert counts["episode_audit/episode_end"] == open_evidence(source).episodes().num_rows


def test_streams_get_their_own_topics(exported: dict[str, tuple[Path, Path]]) -> None:
    with open(exported["vector"][1], "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {"/env_0/steps", "/env_1/steps", "/env_2/steps", "/episodes", "/log"}
    with open(exported["aec"][1], "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {"/player_1/steps", "/player_2/steps", "/episodes", "/log"}


def _decoded(path: Path, topic: str) -> list[Any]:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [m for *_, m in reader.iter_decoded_messages(topics=[topic])]


def test_endings_are_logs_by_outcome_and_episodes_are_events(
    exported: dict[str, tuple[Path, Path]],
) -> None:
    source, target = exported["camera"]
    logs = _decoded(target, "/log")
    assert [(log.level, log.message) for log in logs] == [
        (4, "episode 0: failure (collision) after 4 steps, return 1"),  # ERROR
        (3, "episode 1: truncated (time_limit) after 6 steps, return 1.5"),  # WARNING
    ]
    ends = open_evidence(source).episodes().column("end_time_ns").to_pylist()
    assert [log.timestamp.ToNanoseconds() for log in logs] == ends
    events = _decoded(target, "/episodes")
    first = {kv.key: kv.value for kv in events[0].metadata}
    assert first["outcome"] == "failure" and first["label"] == "collision"
    assert first["seed"] == "0"
    assert events[0].end_time.ToNanoseconds() == ends[0]


@pytest.mark.parametrize("name", ["camera", "vector", "aec"])
def test_each_episode_starts_with_its_reset_observation(
    exported: dict[str, tuple[Path, Path]], name: str
) -> None:
    """An episode's first message on its stream's ``steps`` topic is its reset: step -1, the
    observation ``Evidence.resets()`` holds and nothing else, at the reset's time; then its
    steps, from step 0. An episode reset and never stepped (vector) has its reset alone."""
    source, target = exported[name]
    messages: dict[tuple[str, int], list[tuple[int, dict[str, Any]]]] = defaultdict(list)
    with open(target, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.topic.endswith("/steps"):
                data = json.loads(message.data)
                messages[channel.topic, data["episode"]].append((message.log_time, data))
    resets = recorded_resets(source)
    assert len(resets) == open_evidence(source).episodes().num_rows
    assert sum(len(m) for m in messages.values()) == len(resets) + len(
        open_evidence(source).steps(columns=["step"])
    )
    never_stepped = 0
    for reset in resets:
        (time, first), *steps = messages[f"{reset['prefix']}/steps", reset["episode"]]
        assert (time, first["step"]) == (reset["time_ns"], -1)
        assert set(first) == {"episode", "step", "observation"}  # no action, reward, flags
        plotted = leaves(first["observation"])
        recorded = leaves(reset["observation"])
        for path, values in plotted.items():
            np.testing.assert_array_equal(np.ravel(values), np.ravel(recorded[path]))
        if not steps:
            never_stepped += 1
            continue
        assert steps[0][0] > time and steps[0][1]["step"] == 0
        assert set(leaves(steps[0][1]["observation"])) == set(plotted)
    assert never_stepped == (1 if name == "vector" else 0)


def test_camera_frames_are_lossless_png_each_episode_s_reset_first(
    exported: dict[str, tuple[Path, Path]],
) -> None:
    """The camera topic holds every step's and every reset's frame, each at its time."""
    source, target = exported["camera"]
    with open(target, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [
            (message.log_time, frame)
            for _, _, message, frame in reader.iter_decoded_messages(
                topics=["/camera/observation.camera"], log_time_order=True
            )
        ]
    assert {frame.format for _, frame in decoded} == {"png"}
    frames = [(t, np.asarray(Image.open(io.BytesIO(frame.data)))) for t, frame in decoded]
    ev = open_evidence(source)
    assert ev.observation_codec is not None
    steps = ev.steps(columns=["time_ns", "observation"])
    observations = ev.observation_codec.decode(steps.column("observation"))
    expected = sorted(
        [(r["time_ns"], r["observation"]["camera"]) for r in recorded_resets(source)]
        + [(t, o["camera"]) for t, o in zip(steps.column("time_ns").to_pylist(), observations)],
        key=lambda frame: frame[0],
    )
    assert [t for t, _ in frames] == [t for t, _ in expected] and len(frames) == 12
    for (_, frame), (_, pixels) in zip(frames, expected, strict=True):
        np.testing.assert_array_equal(frame, pixels)


def test_dict_observations_plot_item_by_item(exported: dict[str, tuple[Path, Path]]) -> None:
    _, target = exported["camera"]
    with open(target, "rb") as f:
        reader = make_reader(f)
        (schema,) = [s for s in reader.get_summary().schemas.values() if s.encoding == "jsonschema"]
        messages = [json.loads(m.data) for *_, m in reader.iter_messages(topics=["/steps"])]
    first = next(m for m in messages if m["step"] == 0)  # (after its reset, step -1)
    properties = json.loads(schema.data)["properties"]
    assert properties["observation"]["properties"] == {
        "state": {"type": "array", "items": {"type": "number", "description": NONFINITE_NULL}},
        "mode": {"type": "integer"},
    }  # the camera is an image, not numbers
    assert set(properties["terms"]["properties"]) == {"progress", "effort"}
    assert first["observation"] == {"state": [pytest.approx(0.1), pytest.approx(-0.1)], "mode": 1}
    assert first["terms"] == {"progress": 0.5, "effort": -0.25}
    assert (first["action"], first["terminated"], first["truncated"]) == (1, 0, 0)


def test_refuses_to_overwrite_and_leaves_nothing_on_failure(tmp_path: Path) -> None:
    source = ROOT / "fixtures" / "clean.mcap"
    out = tmp_path / "view.mcap"
    out.write_bytes(b"keep")
    with pytest.raises(
        ConfigurationError, match=r"view\.mcap: exists; pass overwrite=True to replace it$"
    ):
        export([source], out, to="foxglove")
    assert out.read_bytes() == b"keep"
    with pytest.raises(ConfigurationError, match="is the input"):
        export([source], source, to="foxglove", overwrite=True)
    with pytest.raises(ConfigurationError, match="one file from one input, got 2 inputs"):
        export([source, source], out, to="foxglove")
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(source.read_bytes()[:50])
    with pytest.raises(EvidenceError, match=r"broken\.mcap"):
        export([broken], tmp_path / "none.mcap", to="foxglove")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.mcap", "view.mcap"]


def test_cli_export_to_foxglove(tmp_path: Path) -> None:
    runner = CliRunner()
    out = tmp_path / "view.mcap"
    args = ["export", str(ROOT / "fixtures" / "clean.mcap"), "--to", "foxglove", "-o", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "wrote 6 episodes, 447 steps" in result.output and out.is_file()
    again = runner.invoke(app, args)
    assert again.exit_code == 2 and "exists; pass --overwrite to replace it" in again.output
    wrong = runner.invoke(app, [*args[:3], "vlc", *args[4:], "--overwrite"])
    assert wrong.exit_code == 2 and "--to: expected one of parquet, foxglove, rerun" in wrong.output


def test_times_no_foxglove_timestamp_holds_are_left_out_and_said(tmp_path: Path) -> None:
    """A file whose times are before 1970 (not from our recorder): those messages are left
    out, and the notes say how many (the SDK would refuse them: OverflowError)."""
    import gymnasium as gym
    import pyarrow as pa

    from episode_audit import RecordEvidence
    from episode_audit.format import names as fmt
    from tests import fuzzing

    path = tmp_path / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0)
        for _ in range(30):
            *_, terminated, truncated, _ = env.step(0)
            if terminated or truncated:
                env.reset()
    model = fuzzing.read_model(path.read_bytes())
    for topic, column in ((fmt.TOPIC_STEPS, "time_ns"), (fmt.TOPIC_EPISODES, "end_time_ns")):
        for k in model.on(topic):
            batch = fuzzing._batch_of(model.messages[k].data)
            i = batch.schema.get_field_index(column)
            early = pa.array([-1] * batch.num_rows, pa.int64())
            changed = batch.set_column(i, batch.schema.field(i), early)
            model.messages[k].data = fuzzing._arrow_stream(changed)
    early = tmp_path / "early.mcap"
    early.write_bytes(fuzzing.write_model(model))
    episodes = len(open_evidence(early).episodes())
    result = export([early], tmp_path / "out", to="foxglove")
    assert result.steps == 0 and result.episodes == 0
    assert result.out_of_range == 30 + episodes
    assert any("their times are missing or outside what Foxglove" in n for n in result.notes)

    # episodes without any time: left out and counted alike, not said to be written
    for k in model.on(fmt.TOPIC_EPISODES):
        batch = fuzzing._batch_of(model.messages[k].data)
        for column in ("start_time_ns", "end_time_ns"):
            i = batch.schema.get_field_index(column)
            none = pa.nulls(batch.num_rows, pa.int64())
            batch = batch.set_column(i, batch.schema.field(i), none)
        model.messages[k].data = fuzzing._arrow_stream(batch)
    early.write_bytes(fuzzing.write_model(model))
    result = export([early], tmp_path / "out", to="foxglove", overwrite=True)
    assert result.episodes == 0 and result.out_of_range == 30 + episodes


def test_an_export_given_as_evidence_is_named_and_what_to_do_said(tmp_path: Path) -> None:
    """A Foxglove export named to `check` is an MCAP file but not evidence: the error says it
    is our viewer export, of which file, and what to pass. In a folder given it is left out."""
    folder = tmp_path / "vdir"
    folder.mkdir()
    source = folder / "run.mcap"
    shutil.copy(ROOT / "fixtures" / "clean.mcap", source)
    out = folder / "run.foxglove.mcap"
    export([source], out, to="foxglove")
    problem = (
        f"episode-audit's Foxglove export of {str(source)!r} (a viewer file), not evidence: "
        "pass the evidence files, or their directory (its viewer exports are left out)"
    )
    with pytest.raises(NotEvidenceError, match=f"^{re.escape(f'{out}: {problem}')}$"):
        open_evidence(out)
    result = CliRunner().invoke(app, ["check", str(out), "--format", "json"])
    assert result.exit_code == 2
    assert f"episode-audit: error: {out}: {problem}\n" in result.stderr
    result = CliRunner().invoke(app, ["check", str(folder), "--format", "json"])
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["files"] == [str(source)]


def test_another_warning_on_the_sdk_s_write_logger_is_no_failed_write(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Only the SDK's failed writes (``error logging message: McapError(…)`` and
    ``SinkClosed``: the full-disk test below) fail the export; another warning on that logger
    (another sink's, a later SDK's own) is passed on, and the export finishes."""
    source = random_cartpole_file(tmp_path / "run.mcap", 2000)
    logger = logging.getLogger("foxglove.log_sink_set")
    said = [
        "error logging message: SendError { sink: 7 }",  # (another sink's, not ours)
        "a later release's note",
    ]

    def warn(_: int) -> None:  # (while the export writes)
        while said:
            logger.warning(said.pop())

    out = tmp_path / "run.fox.mcap"
    with caplog.at_level(logging.WARNING, logger=logger.name):
        result = export([source], out, to="foxglove", progress=warn)
    assert not said and out.exists() and result.steps == 2000
    assert [r.getMessage() for r in caplog.records if r.name == logger.name] == [
        "a later release's note",
        "error logging message: SendError { sink: 7 }",
    ]


def test_a_full_disk_is_one_error_naming_the_output(small_disk: Path, tmp_path: Path) -> None:
    """Full before the export or midway (the SDK logs each message it fails to write)."""
    source = random_cartpole_file(tmp_path / "run.mcap", 2000)  # (more than a chunk)
    filler = fill_disk(small_disk)
    full = filler.stat().st_size
    for free in (0, 16 * 1024):
        os.truncate(filler, full - free)
        for out in (small_disk / "run.fox.mcap", small_disk / "new" / "run.fox.mcap"):
            with pytest.raises(
                ConfigurationError,
                match=rf"^{re.escape(str(out))}: cannot write it: No space left on device; free "
                "some space there or choose another output path$",
            ):
                export([source], out, to="foxglove")
            assert sorted(small_disk.iterdir()) == [filler]  # no output, no folder it made
    # one line: not foxglove-sdk's own line for each message it failed to write (hundreds)
    assert export_stderr(source, "foxglove", out) == (
        2,
        f"episode-audit: error: {out}: cannot write it: No space left on device; free some "
        "space there or choose another output path\n",
    )
    assert sorted(small_disk.iterdir()) == [filler]
