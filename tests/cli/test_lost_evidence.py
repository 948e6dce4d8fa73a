"""A file whose recorder dropped what a full disk refused: check, show and report say so.

The file is recorded for real on a full disk (``RLIMIT_FSIZE`` in a child, as
``tests/record/test_disk_full.py`` does): two blocks of steps refused until the retry buffer
gave up, then ``close()`` finishes the file with room for its end. It is finished, not torn.
"""

from __future__ import annotations

import re
import signal
from pathlib import Path

import pytest

from episode_audit import check, open_evidence
from tests.record.test_disk_full import record

pytestmark = pytest.mark.skipif(
    not hasattr(signal, "SIGXFSZ"), reason="needs RLIMIT_FSIZE and SIGXFSZ (POSIX)"
)

DROPPED = re.compile(r"6000 step rows, (\d+) reset rows and (\d+) episode records")


@pytest.fixture(scope="module")
def dropped_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("full")
    _, stderr, code = record(folder, end="close_full", slack=64 << 10)
    assert code == 0, stderr
    path = folder / "run.mcap"
    ev = open_evidence(path)
    assert ev.finished and ev.run_end is not None and ev.run_end["recorder_lost_steps"] == "6000"
    return path


def test_check_says_what_was_dropped_and_why_episodes_are_incomplete(dropped_file: Path) -> None:
    findings = check([dropped_file]).findings
    (trouble,) = [f for f in findings if f.code == "recorder_trouble"]
    assert trouble.severity == "error"
    assert DROPPED.search(trouble.message), trouble.message
    assert trouble.message.endswith(
        "it could not write (the run-end record counts them): the file's episodes, steps and "
        "outcomes are not the whole run; free disk space and record the run again"
    )
    (incomplete,) = [f for f in findings if f.code == "incomplete_episode"]
    assert "torn" not in incomplete.message  # (the file is finished)
    assert re.search(
        r"1 of them without an end record: their end was among what the recorder dropped "
        r"\(recorder_trouble\), so how they ended is unknown",
        incomplete.message,
    ), incomplete.message
