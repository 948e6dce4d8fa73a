"""Observation fields and reward terms in the viewer exports: one topic / entity path each,
whatever their names (``_values.frame_names``, Rerun's escaped entity path parts)."""

from __future__ import annotations

import io
from collections import defaultdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from mcap.reader import make_reader

from episode_audit import RecordEvidence
from episode_audit.export import export

SIDE = 16


class _Alike(gym.Env[Any, int]):
    """Fields whose names join to one: ``"cam.left"`` and ``"cam"`` → ``"left"`` (frames, white
    and black), ``"a/b"`` and ``"a"`` → ``"b"`` (+t and -t); terms ``"x"``, ``"x/y"`` and
    ``"ctrl cost"``."""

    frame = spaces.Box(0, 255, (SIDE, SIDE, 3), np.uint8)
    number = spaces.Box(-10, 10, (1,), np.float32)
    observation_space = spaces.Dict(
        {
            "cam.left": frame,
            "cam": spaces.Dict({"left": frame}),
            "a/b": number,
            "a": spaces.Dict({"b": number}),
        }
    )
    action_space = spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {}

    def _obs(self) -> dict[str, Any]:
        t = np.array([self.t], np.float32)
        return {
            "cam.left": np.full((SIDE, SIDE, 3), 255, np.uint8),
            "cam": {"left": np.zeros((SIDE, SIDE, 3), np.uint8)},
            "a/b": t,
            "a": {"b": -t},
        }

    def step(self, action: int) -> Any:
        self.t += 1
        terms = {"x": 0.75, "x/y": 0.25, "ctrl cost": -0.5}
        return self._obs(), 0.5, False, self.t >= 3, {"reward_terms": terms}


@pytest.fixture(scope="module")
def alike(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fields") / "alike.mcap"
    with RecordEvidence(_Alike(), path) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(0)
    return path


def test_foxglove_camera_topics_are_one_per_field(alike: Path, tmp_path: Path) -> None:
    """``"cam.left"`` and ``"cam"`` → ``"left"`` were one ``/camera/observation.cam.left``
    topic, the two fields' frames alternating on it."""
    pytest.importorskip("foxglove")
    from mcap_protobuf.decoder import DecoderFactory
    from PIL import Image

    out = tmp_path / "alike.foxglove.mcap"
    result = export([alike], out, to="foxglove")
    means: dict[str, set[int]] = defaultdict(set)
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if "/camera/" in channel.topic:
                image = DecoderFactory().decoder_for("protobuf", schema)(message.data)
                pixels = np.asarray(Image.open(io.BytesIO(image.data)))
                means[channel.topic].add(int(pixels.mean()))
                assert image.frame_id == channel.topic.removeprefix("/camera/")
    # the nested field keeps the name it always had; the key with a "." takes the next one
    assert dict(means) == {
        "/camera/observation.cam.left": {0},
        "/camera/observation.cam.left-2": {255},
    }
    assert {p for p in result.paths if "/camera/" in p} == set(means)
    assert result.frames == 8  # 2 fields x (1 reset + 3 steps)


def _rows(path: Path) -> dict[str, list[dict[str, Any]]]:
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        rows[chunk.entity_path].extend(chunk.to_record_batch().to_pylist())
    return rows


def test_rerun_entities_are_one_per_field_and_term(
    alike: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A Dict key ``"a/b"`` and ``"a"`` → ``"b"`` were one entity ``…/observation/a/b``, a term
    ``"x/y"`` a child of ``"x"``, both cameras one entity; a term ``"ctrl cost"`` made
    rerun-sdk print its own ANSI-coloured WARN line (unescaped whitespace)."""
    pytest.importorskip("rerun")
    out = tmp_path / "alike.rrd"
    result = export([alike], out, to="rerun")
    assert "WARN" not in capfd.readouterr().err
    rows = _rows(out)

    def values(entity: str) -> list[tuple[int, float]]:
        return sorted((r["step"], r["Scalars:scalars"][0]) for r in rows[entity])

    assert values("/steps/observation/a/b") == [(-1, 0.0), (0, -1.0), (1, -2.0), (2, -3.0)]
    assert values("/steps/observation/a\\/b") == [(-1, 0.0), (0, 1.0), (1, 2.0), (2, 3.0)]
    assert values("/steps/terms/x") == [(0, 0.75), (1, 0.75), (2, 0.75)]
    assert values("/steps/terms/x\\/y") == [(0, 0.25), (1, 0.25), (2, 0.25)]
    assert values("/steps/terms/ctrl\\ cost") == [(0, -0.5), (1, -0.5), (2, -0.5)]
    cameras = {entity: len(r) for entity, r in rows.items() if "/camera/" in entity}
    assert cameras == {"/camera/observation.cam.left": 4, "/camera/observation.cam.left-2": 4}
    assert set(cameras) <= set(result.paths)
    assert "/steps/terms/x\\/y" in result.paths
