"""Progress bars on a terminal: what else the command says goes on lines of its own, and the
bar's total.

The command runs with its stderr on a pseudo-terminal (Rich shows a bar only on a terminal);
the raw bytes are read back and cut where the terminal would start a line: a carriage return,
a newline, or an erase-line sequence.
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import shutil
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from tests.support.rewards import record_cartpole

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures"


def on_a_terminal(*args: str, columns: int = 80) -> list[str]:
    """``episode-audit ARGS`` with stderr on a terminal ``columns`` wide: its screen lines."""
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    env = {
        **{k: v for k, v in os.environ.items() if k not in ("NO_COLOR", "FORCE_COLOR")},
        "PYTHONPATH": str(REPO),
        "COLUMNS": str(columns),
        "TERM": "xterm-256color",
    }
    command = [sys.executable, "-m", "episode_audit", *args]
    proc = subprocess.Popen(
        command, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
        stderr=follower,
    )  # fmt: skip
    os.close(follower)
    raw = bytearray()
    while True:
        try:
            data = os.read(leader, 1 << 16)
        except OSError:  # (EIO: the command has closed its end)
            break
        if not data:
            break
        raw += data
    os.close(leader)
    proc.wait(timeout=120)
    text = raw.decode("utf-8", "replace").replace("\x1b[2K", "\n")
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)
    return [line for line in re.split(r"[\r\n]", text) if line.strip()]


@pytest.fixture
def campaign(tmp_path: Path) -> Path:
    """Twenty readable files (twenty runs), then an unreadable one (last in sorted order)."""
    for i in range(20):
        record_cartpole(tmp_path / f"{i:02d}.mcap", episodes=2, seed=i)
    (tmp_path / "zz-bad.mcap").write_bytes(b"")
    return tmp_path


@pytest.mark.parametrize("command", ["check", "report"])
def test_an_unreadable_file_s_line_is_not_written_onto_the_bar(
    campaign: Path, command: str
) -> None:
    # it was: "reading ━━━╺ 1481/1508 0:00:01episode-audit: error: ..."
    lines = on_a_terminal(command, str(campaign), "--jobs", "1")
    at = [i for i, line in enumerate(lines) if "episode-audit: error:" in line]
    assert len(at) == 1 and lines[at[0]].startswith("episode-audit: error:"), lines
    said = [lines[at[0]]]  # (and the lines it is wrapped onto, each indented)
    for line in lines[at[0] + 1 :]:
        if not line.startswith("  "):
            break
        said.append(line)
    message = f"episode-audit: error: {campaign}/zz-bad.mcap: the file is empty"
    assert " ".join(" ".join(said).split()) == message, lines
    assert any("━" in line for line in lines), "a bar was shown"


def test_a_torn_file_leaves_the_bar_its_total_and_time_left(tmp_path: Path) -> None:
    # one torn file among many: "checking ━━━━ 134466/?" all run, no time left
    for i in range(20):
        shutil.copy(FIXTURES / "clean.mcap", tmp_path / f"{i:02d}.mcap")
    shutil.copy(FIXTURES / "torn.mcap", tmp_path / "10-torn.mcap")
    (tmp_path / "zz-bad.mcap").write_bytes(b"")  # (an unreadable one: no steps to count)
    bars = [line for line in on_a_terminal("check", str(tmp_path), "--jobs", "1") if "━" in line]
    assert bars
    assert all(re.search(r" \d+/\d+ ", bar) for bar in bars), bars
