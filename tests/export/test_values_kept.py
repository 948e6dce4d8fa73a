"""Every value a viewer export writes is the evidence file's: each step's time, reward, terms,
flags, action and observation, in Foxglove and in Rerun."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from episode_audit import open_evidence
from episode_audit.export import export
from episode_audit.export._values import streams
from tests.export.test_order import MAKERS
from tests.support.viewer_files import leaves


def _exported(tmp_path: Path, name: str, to: str, suffix: str) -> tuple[Path, Path]:
    """The evidence file ``name`` of :data:`MAKERS` and its export ``to`` a viewer."""
    pytest.importorskip(to)
    source = MAKERS[name](tmp_path / f"{name}.mcap")
    out = tmp_path / f"{name}{suffix}"
    export([source], out, to=to)  # type: ignore[call-overload]
    return source, out


def _recorded(source: Path) -> list[dict[str, Any]]:
    """Each step of ``source``, its action and observation decoded, and its stream's prefix."""
    ev = open_evidence(source)
    steps = ev.steps()
    assert ev.action_codec is not None and ev.observation_codec is not None
    actions = ev.action_codec.decode(steps.column("action"))
    observations = ev.observation_codec.decode(steps.column("observation"))
    prefix_of = streams(ev).prefix_of
    out = []
    for row, action, observation in zip(steps.to_pylist(), actions, observations, strict=True):
        out.append(
            {
                **row,
                "action": action,
                "observation": observation,
                "prefix": prefix_of[row["episode"]],
            }
        )
    return out


def _same(written: Any, recorded: Any) -> None:
    """Plotted numbers equal the recorded ones exactly (JSON null: a NaN or infinity)."""
    wrote = np.asarray(written, dtype=object).ravel()
    expected = np.ravel(np.asarray(recorded, dtype=np.float64))
    assert len(wrote) == len(expected)
    for w, e in zip(wrote, expected, strict=True):
        assert (w is None and not math.isfinite(e)) or w == e, (written, recorded)


@pytest.mark.parametrize("name", list(MAKERS))
def test_foxglove_messages_hold_the_evidence_values(tmp_path: Path, name: str) -> None:
    source, out = _exported(tmp_path, name, "foxglove", ".foxglove.mcap")
    written: dict[tuple[str, int, int], tuple[int, dict[str, Any]]] = {}
    with open(out, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/steps"):
                data = json.loads(message.data)
                key = (channel.topic, data["episode"], data["step"])
                assert key not in written
                written[key] = (message.log_time, data)
    steps = _recorded(source)
    for step in steps:
        time, data = written[(f"{step['prefix']}/steps", step["episode"], step["step"])]
        assert time == step["time_ns"]
        _same(data["reward"], step["reward"])
        assert (data["terminated"], data["truncated"]) == (
            int(step["terminated"]),
            int(step["truncated"]),
        )
        for term, value in step["terms"] or []:
            _same(data["terms"][term], value)
        for field in ("action", "observation"):
            recorded = leaves(step[field])
            plotted = leaves(data[field]) if field in data else {}
            for path, values in plotted.items():
                _same(values, recorded[path])
            assert set(recorded) - set(plotted) <= {("camera",)}  # (the camera: a frame)
    assert sum(1 for _, _, s in written if s >= 0) == len(steps)


@pytest.mark.parametrize("name", list(MAKERS))
def test_rerun_rows_hold_the_evidence_values(tmp_path: Path, name: str) -> None:
    source, out = _exported(tmp_path, name, "rerun", ".rrd")
    from rerun.chunk import RrdReader

    rows: dict[str, dict[tuple[int, int], dict[str, Any]]] = defaultdict(dict)
    for chunk in RrdReader(out).stream():
        for row in chunk.to_record_batch().to_pylist():
            if "step" in row:
                rows[chunk.entity_path][(row["episode"], row["step"])] = row
    for step in _recorded(source):
        key, steps = (step["episode"], step["step"]), f"{step['prefix']}/steps"
        reward = rows[f"{steps}/reward"][key]
        assert reward["time"].value == step["time_ns"]
        np.testing.assert_array_equal(reward["Scalars:scalars"], [step["reward"]])
        for flag in ("terminated", "truncated"):
            assert rows[f"{steps}/{flag}"][key]["Scalars:scalars"] == [float(step[flag])]
        for term, value in step["terms"] or []:
            np.testing.assert_array_equal(
                rows[f"{steps}/terms/{term}"][key]["Scalars:scalars"], [value]
            )
        for field in ("action", "observation"):
            for path, values in leaves(step[field]).items():
                entity = "/".join((steps, field, *path))
                if path == ("camera",):
                    continue
                np.testing.assert_array_equal(
                    rows[entity][key]["Scalars:scalars"], np.ravel(values).astype(np.float64)
                )
