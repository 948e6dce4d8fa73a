from __future__ import annotations

from pathlib import Path

import pytest

from episode_audit import demo


def test_demo_runs_clean(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mujoco")
    assert demo.main([str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "0 diverged, 0 not replayable" in out
    for label in ("door_slammed", "drawer_yanked", "dropped_object", "time_limit"):
        assert label in out
    assert "(exit code 1)" in out  # the CI gate fails on the hacker run, as it should
