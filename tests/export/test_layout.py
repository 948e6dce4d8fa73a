"""The Foxglove layout: the shape the Foxglove app imports, and the topics the export wrote.

The app's *Layouts → Import from file…* reads a layout as the app exports one (``configById``,
``layout``, ``globalVariables``, ``userNodes``, ``playbackConfig``); the layout used to be
foxglove-sdk's ``foxglove.layouts`` JSON (``{"version": 1, "content": …}``), which the app
does not read as a layout. Each panel's settings are checked against the keys the app writes
for it (from layouts exported by the app, in foxglove-sdk's examples and elsewhere).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from mcap.reader import make_reader

from episode_audit import ConfigurationError, RecordEvidence
from episode_audit.export import export
from episode_audit.export.layout import foxglove_layout, foxglove_layout_of, main
from tests.export.test_agents import _Alike
from tests.support.viewer_files import VIEWER_FILES

ROOT = Path(__file__).resolve().parents[2]
PANEL_TYPES = {"Plot", "StateTransitions", "Image", "RawMessages", "RosOut"}
_TOPIC = re.compile(r'^(?:"((?:[^"\\]|\\.)+)"|([a-zA-Z0-9_/-]+))')
_FIELD = re.compile(r'^\.(?:"((?:[^"\\]|\\.)+)"|([a-zA-Z0-9_-]+))')


def _parse(path: str) -> tuple[str, list[str]]:
    """A message path's topic and fields, as Foxglove's grammar reads them (quotes included)."""
    match = _TOPIC.match(path)
    assert match, path
    topic = re.sub(r"\\(.)", r"\1", match[1]) if match[1] else match[2]
    rest, fields = path[match.end() :], []
    while rest:
        field = _FIELD.match(rest)
        assert field, (path, rest)
        fields.append(re.sub(r"\\(.)", r"\1", field[1]) if field[1] else field[2])
        rest = rest[field.end() :]
    return topic, fields


def _panels_in(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert set(node) <= {"first", "second", "direction", "splitPercentage"}, node
    assert node["direction"] in ("row", "column") and 0 < node["splitPercentage"] < 100
    return _panels_in(node["first"]) + _panels_in(node["second"])


def app_shape(text: str) -> dict[str, Any]:
    """The layout of ``text``, checked to be one the Foxglove app imports; its panels' settings."""
    layout = json.loads(text)
    assert set(layout) == {"configById", "layout", "globalVariables", "userNodes", "playbackConfig"}
    assert layout["globalVariables"] == {} and layout["userNodes"] == {}
    assert layout["playbackConfig"] == {"speed": 1}
    config: dict[str, Any] = layout["configById"]
    panels = _panels_in(layout["layout"])
    assert sorted(panels) == sorted(config), "every panel in the tree has settings, and only they"
    for panel, settings in config.items():
        kind = panel.split("!")[0]
        assert kind in PANEL_TYPES and panel.count("!") == 1, panel
        assert isinstance(settings["foxglovePanelTitle"], str)
        if kind == "Plot":
            for series in settings["paths"]:
                assert set(series) == {"value", "enabled", "timestampMethod", "label"}, series
                assert series["timestampMethod"] == "receiveTime" and series["enabled"] is True
            assert settings["xAxisVal"] == "timestamp" and settings["isSynced"] is True
        elif kind == "StateTransitions":
            for series in settings["paths"]:
                assert set(series) == {"value", "timestampMethod", "label"}, series
        elif kind == "Image":
            assert set(settings["imageMode"]) == {"imageTopic"}
        elif kind == "RawMessages":
            assert isinstance(settings["topicPath"], str) and settings["diffEnabled"] is False
        elif kind == "RosOut":
            assert settings["topicToRender"] == "/log" and settings["searchTerms"] == []
    return config


def _paths(config: dict[str, Any]) -> list[str]:
    """Every message path the panels read (a topic in one is quoted where it needs to be)."""
    out = [s["value"] for c in config.values() for s in c.get("paths", [])]
    return out + [c["topicPath"] for c in config.values() if "topicPath" in c]


def _topics(config: dict[str, Any]) -> list[str]:
    """Every topic the panels read, as it is named (not a message path)."""
    out = {_parse(p)[0] for p in _paths(config)}
    out |= {c["topicToRender"] for c in config.values() if "topicToRender" in c}
    out |= {c["imageMode"]["imageTopic"] for c in config.values() if "imageMode" in c}
    return sorted(out)


def _channels(path: Path) -> dict[str, tuple[str, dict[str, Any]]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    out = {}
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        body = json.loads(schema.data) if schema.encoding == "jsonschema" else {}
        out[channel.topic] = (schema.name, body)
    return out


def _reads_only_what_the_export_wrote(config: dict[str, Any], exported: Path) -> None:
    """Each path's topic is a topic of the export and its fields are in that topic's schema."""
    channels = _channels(exported)
    assert set(_topics(config)) <= set(channels), (_topics(config), sorted(channels))
    for path in _paths(config):
        topic, fields = _parse(path)
        node = channels[topic][1]
        for name in fields:
            node = node["properties"][name]
    (image,) = [c["imageMode"]["imageTopic"] for c in config.values() if "imageMode" in c] or [None]
    assert image is None or channels[image][0] == "foxglove.CompressedImage"


def test_the_docs_layout_is_the_generated_one_in_the_app_s_shape() -> None:
    text = (ROOT / "docs" / "foxglove-layout.json").read_text()
    assert text == foxglove_layout(), (
        "python -m episode_audit.export.layout > docs/foxglove-layout.json"
    )
    config = app_shape(text)
    assert {p.split("!")[0] for p in config} == PANEL_TYPES
    assert "/steps.reward" in _paths(config) and "/steps.terms.ctrl_cost" in _paths(config)
    assert config["Image!camera"]["imageMode"]["imageTopic"] == "/camera/observation"


def test_the_layout_needs_no_viewer_library(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # as if foxglove-sdk were not installed
    monkeypatch.setitem(sys.modules, "foxglove.layouts", None)
    assert app_shape(foxglove_layout())


def test_a_prefix_moves_every_topic_the_image_s_too() -> None:
    """``prefix="/env_0"`` moved the plots but left the image at ``/camera/observation``."""
    config = app_shape(foxglove_layout(["ctrl cost"], prefix="/p.1"))
    assert _topics(config) == ["/log", "/p.1/camera/observation", "/p.1/steps"]
    assert '"/p.1/steps".terms."ctrl cost"' in _paths(config)  # (quoted as Foxglove reads them)
    config = app_shape(foxglove_layout(prefix="/env_0"))
    assert config["Image!camera"]["imageMode"]["imageTopic"] == "/env_0/camera/observation"
    assert "Image!camera" not in app_shape(foxglove_layout(image_topic=None))


def _render_file(path: Path) -> Path:
    """CartPole seen through ``AddRenderObservation``: its frames are ``observation.pixels``."""
    env = gym.wrappers.AddRenderObservation(
        gym.make("CartPole-v1", render_mode="rgb_array"), render_only=False
    )
    with RecordEvidence(env, path) as rec:
        rec.reset(seed=0)
        for _ in range(3):
            rec.step(0)
    return path


MAKERS = {**VIEWER_FILES, "render": _render_file}


@pytest.mark.parametrize("name", list(MAKERS))
def test_the_layout_of_an_export_reads_what_it_wrote(tmp_path: Path, name: str) -> None:
    """With AddRenderObservation the frames are ``/camera/observation.pixels`` and a vector
    env's ``/env_0/camera/…``: the fixed ``/camera/observation`` showed nothing."""
    pytest.importorskip("foxglove")
    if name == "render":
        pytest.importorskip("pygame")
    source = MAKERS[name](tmp_path / f"{name}.mcap")
    out = tmp_path / f"{name}.foxglove.mcap"
    result = export([source], out, to="foxglove")
    streams = sorted(p.removesuffix("/steps") for p in result.paths if p.endswith("/steps"))
    for stream in streams:
        config = app_shape(foxglove_layout_of(out, stream))
        _reads_only_what_the_export_wrote(config, out)
        assert _parse(config["RawMessages!step"]["topicPath"])[0] == f"{stream}/steps"
        cameras = [p for p in result.paths if p.startswith(f"{stream}/camera/")]
        image = config.get("Image!camera", {}).get("imageMode", {}).get("imageTopic")
        assert image == (cameras[0] if cameras else None)
    assert foxglove_layout_of(out) == foxglove_layout_of(out, streams[0])
    expected_image = {
        "camera": "/camera/observation.camera",
        "camera_vector": "/env_0/camera/observation.camera",
        "render": "/camera/observation.pixels",
    }
    image = app_shape(foxglove_layout_of(out)).get("Image!camera")
    assert (image and image["imageMode"]["imageTopic"]) == expected_image.get(name)
    if name == "camera":
        terms = app_shape(foxglove_layout_of(out))["Plot!terms"]["paths"]
        assert [s["label"] for s in terms] == ["effort", "progress"]


def test_agent_streams_with_quoted_topics(tmp_path: Path) -> None:
    pytest.importorskip("foxglove")
    from episode_audit import RecordParallelEvidence

    class Dotted(_Alike):
        possible_agents = ["p.1", "a b"]

    source = tmp_path / "dotted.mcap"
    with RecordParallelEvidence(Dotted(), source) as env:
        env.reset(seed=0)
        while env.agents:
            env.step(dict.fromkeys(env.agents, 0))
    out = tmp_path / "dotted.foxglove.mcap"
    export([source], out, to="foxglove")
    for stream in ("/p.1", "/a_b"):
        config = app_shape(foxglove_layout_of(out, stream))
        _reads_only_what_the_export_wrote(config, out)


def test_the_module_has_a_help_and_says_what_is_wrong(tmp_path: Path) -> None:
    """``python -m episode_audit.export.layout --help`` printed the layout."""
    done = subprocess.run(
        [sys.executable, "-m", "episode_audit.export.layout", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
    )
    assert done.stdout.startswith("usage: python -m episode_audit.export.layout")
    assert "Import from file" in done.stdout and "configById" not in done.stdout
    assert main([]) == 0
    evidence = ROOT / "fixtures" / "clean.mcap"
    with pytest.raises(ConfigurationError, match=r"not a Foxglove export of episode-audit"):
        foxglove_layout_of(evidence)
    assert main([str(evidence)]) == 2
    assert main([str(tmp_path / "none.mcap")]) == 2


@pytest.mark.parametrize("reset", [False, True], ids=["empty", "reset-only"])
def test_the_export_suggests_the_layout_only_where_there_is_one(
    tmp_path: Path, reset: bool
) -> None:
    """Exporting a file with no episodes suggested ``python -m episode_audit.export.layout
    OUT``, which then said OUT was not a Foxglove export of episode-audit."""
    pytest.importorskip("foxglove")
    from typer.testing import CliRunner

    from episode_audit.cli import app

    source = tmp_path / "run.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), source) as env:
        if reset:  # (a reset alone is on the steps topic, at step -1: a layout shows it)
            env.reset(seed=0)
    out = tmp_path / "run.foxglove.mcap"
    result = CliRunner().invoke(app, ["export", str(source), "--to", "foxglove", "-o", str(out)])
    assert result.exit_code == 0, result.output
    line = result.output.strip().splitlines()[-1]
    if reset:
        assert line.startswith("  python -m episode_audit.export.layout ")
        assert '"configById"' in foxglove_layout_of(out)
        return
    assert line == "open it in Foxglove (no steps or resets: no layout)", line
    expected = "a Foxglove export of a file with no steps or resets: nothing for a layout to show"
    with pytest.raises(ConfigurationError, match=expected):
        foxglove_layout_of(out)
    assert main([str(out)]) == 2
