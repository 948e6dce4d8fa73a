"""Every warning of episode-audit's own (an ``EpisodeAuditWarning``) is one line on stderr.

In the ``warning:`` form of the command's other lines, without the library's file, line and
source line that Python's own form adds; another library's warnings keep Python's form.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from tests.support.deep_autoreset import DEEP_AUTORESET, PLAIN_WARNING

REPO = Path(__file__).resolve().parents[2]


def test_a_recorder_warning_is_one_line_and_another_librarys_is_left_as_it_is(
    tmp_path: Path,
) -> None:
    out = tmp_path / "deep.mcap"
    done = subprocess.run(
        [sys.executable, "-m", "episode_audit", "record", DEEP_AUTORESET, "--out", str(out),
         "--import", "tests.support.deep_autoreset", "--episodes", "2"],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    ours = [line for line in lines if "Autoreset under the recorder" in line]
    assert len(ours) == 1, done.stderr
    assert ours[0].startswith(
        "episode-audit: warning: RecordEvidence: Autoreset under the recorder, not right under "
        "it: it resets the env inside step()"
    ), done.stderr
    assert "RecorderWarning" not in done.stderr and "rollout.py" not in done.stderr
    theirs = [line for line in lines if PLAIN_WARNING in line]
    assert len(theirs) == 1 and theirs[0].endswith(f"UserWarning: {PLAIN_WARNING}"), done.stderr
    assert "deep_autoreset.py:" in theirs[0]
    assert len(lines) == 3, done.stderr  # (Python's form: the source line under it)
