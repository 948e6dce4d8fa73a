from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from episode_audit import demo
from episode_audit.read import open_evidence
from tests.support.chromium import open_page

CHARTS = """({
  charts: [...document.querySelectorAll("figure svg")].map(s => s.getBBox().width),
  remote: [...document.querySelectorAll("script[src], link[href], img[src]")].length,
  text: document.body.innerText,
})"""


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    pytest.importorskip("mujoco")
    out = tmp_path_factory.mktemp("demo") / "out"
    import contextlib
    import io

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert demo.main([str(out)]) == 0
    return out, printed.getvalue()


def test_demo_runs_clean(demo_run: tuple[Path, str]) -> None:
    _, out = demo_run
    assert "0 diverged, 0 not replayable" in out
    for label in ("door_slammed", "drawer_yanked", "dropped_object", "time_limit"):
        assert label in out
    assert "(exit code 1)" in out  # the CI gate fails on the hacker run, as it should
    assert ".venv/bin/episode-audit" in out  # how to run the commands it printed


def test_demo_commands_paste_into_a_shell(demo_run: tuple[Path, str], tmp_path: Path) -> None:
    out, printed = demo_run
    (line,) = [
        s for s in printed.splitlines() if s.startswith("$ episode-audit record") and "hacker" in s
    ][:1]
    command = line[2:].replace(str(out), str(tmp_path))
    shell = f'episode-audit() {{ "{sys.executable}" -m episode_audit "$@"; }}; {command}'
    done = subprocess.run(
        ["bash", "-c", shell], capture_output=True, text=True, env=os.environ, timeout=600
    )
    assert done.returncode == 0, done.stderr
    (made,) = tmp_path.glob("*.mcap")
    ev = open_evidence(made)
    assert (ev.run.env_spec or {})["kwargs"]["proxy_reward"] is True
    assert ev.run.tags == {"policy": "hacker", "reward": "proxy"}


def test_demo_html_report_renders_in_chromium(demo_run: tuple[Path, str]) -> None:
    out, printed = demo_run
    page = out / "report.html"
    assert f"HTML report: {page}" in printed
    text = page.read_text(encoding="utf-8")
    assert not re.search(r"<(script|link|img)\b[^>]*(src|href)=[\"']?\s*(https?:)?//", text)
    shot = out.parent / "demo-report.png"
    result = open_page(page, CHARTS, shot)
    assert result.errors == []
    assert len(result.value["charts"]) == 5 and min(result.value["charts"]) > 100
    assert result.value["remote"] == 0
    assert "shaping_dominates" in result.value["text"]
    assert shot.stat().st_size > 50_000
    print(f"\ndemo HTML report screenshot: {shot}")


def test_the_demo_deletes_only_its_own_folders(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "run.mcap").write_bytes(b"evidence")
    assert demo.main([str(precious)]) == 2
    assert "holds files the demo did not make" in capsys.readouterr().err
    assert (precious / "run.mcap").read_bytes() == b"evidence"
    assert not (tmp_path / "precious-viewers").exists()
    # a folder of what a demo run made (before the mark), or with the mark, is emptied
    older = tmp_path / "older"
    older.mkdir()
    (older / "grasp-hacker.mcap").write_bytes(b"")
    (older / "report.html").write_text("")
    assert demo.fresh(older) is None
    assert [p.name for p in older.iterdir()] == [demo.MARK]
    (older / "grasp-hacker.mcap").write_bytes(b"")
    assert demo.fresh(older) is None and [p.name for p in older.iterdir()] == [demo.MARK]


def test_the_demo_s_help_is_help_not_a_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``python -m episode_audit.demo --help`` took ``--help`` for its folder and recorded."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as shown:
        demo.main(["--help"])
    assert shown.value.code == 0
    assert capsys.readouterr().out.startswith("usage: python -m episode_audit.demo [-h] [OUT_DIR]")
    with pytest.raises(SystemExit) as refused:
        demo.main(["a", "b"])
    assert refused.value.code == 2 and "unrecognized arguments: b" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
