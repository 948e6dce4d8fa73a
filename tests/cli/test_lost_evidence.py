"""A file whose recorder dropped what a full disk refused: check, show and report say so.

The file is recorded for real on a full disk (``RLIMIT_FSIZE`` in a child, as
``tests/record/test_disk_full.py`` does): two blocks of steps refused until the retry buffer
gave up, then ``close()`` finishes the file with room for its end. It is finished, not torn.
"""

from __future__ import annotations

import io
import json
import re
import signal
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from episode_audit import check, open_evidence, report
from episode_audit.cli import app
from episode_audit.cli.render import report_output
from episode_audit.cli.render.show import summary_output
from episode_audit.read.summary import summarize
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


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout


def at_80_columns(renderable: object) -> str:
    console = Console(file=io.StringIO(), width=80, color_system=None)
    console.print(renderable)
    return str(console.file.getvalue())  # type: ignore[attr-defined]


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


def test_show_has_a_dropped_row_in_each_format(dropped_file: Path) -> None:
    dropped = summarize(open_evidence(dropped_file))["dropped"]
    assert dropped is not None and dropped["steps"] == 6000
    assert dropped["resets"] > 0 and dropped["episode_records"] > 0
    code, out = run("show", str(dropped_file), "--format", "markdown")
    assert code == 0
    match = DROPPED.search(out)
    assert match and (int(match[1]), int(match[2])) == (
        dropped["resets"],
        dropped["episode_records"],
    )
    assert "| dropped | 6000 step rows" in out and "the file is not the whole run |" in out
    code, out = run("show", str(dropped_file), "--format", "json")
    assert json.loads(out)["dropped"] == dropped
    code, out = run("show", str(dropped_file))
    assert code == 0 and re.search(r"^ dropped +6000 step rows", out, re.M), out
    narrow = at_80_columns(summary_output(open_evidence(dropped_file), "table"))
    assert re.search(r"^ dropped +6000 step rows, ", narrow, re.M), narrow
    assert max(map(len, narrow[: narrow.index("Episodes")].splitlines())) <= 80


def test_show_of_a_file_that_dropped_nothing_has_no_dropped_row(tmp_path: Path) -> None:
    _, stderr, code = record(tmp_path, end="close_full", slack=64 << 10, refused=0)
    assert code == 0, stderr
    assert summarize(open_evidence(tmp_path / "run.mcap"))["dropped"] is None
    code, out = run("show", str(tmp_path / "run.mcap"))
    assert code == 0 and not re.search(r"^ dropped", out, re.M)


def test_report_names_the_file_and_what_it_lost(dropped_file: Path, tmp_path: Path) -> None:
    result = report([dropped_file])
    assert not result.unfinished  # (finished: not torn, not being written)
    ((name, what),) = result.dropped
    assert name == str(dropped_file) and DROPPED.search(what), what
    assert result.to_dict()["dropped"] == [{"file": name, "what": what}]
    code, out = run("report", str(dropped_file))
    assert code == 0 and "the recorder dropped 6000 step rows" in out
    assert "Files missing what their recorder dropped: counts over what they hold" in out
    narrow = at_80_columns(report_output(result, "table"))
    assert "Files missing what their recorder dropped: counts over what they hold" in narrow
    assert max(map(len, narrow.splitlines())) <= 80
    code, out = run("report", str(dropped_file), "--format", "markdown")
    assert "#### Files missing what their recorder dropped" in out
    code, _ = run("report", str(dropped_file), "--html", str(tmp_path / "report.html"))
    page = (tmp_path / "report.html").read_text()
    assert code == 0 and "Files missing what their recorder dropped" in page
    assert "the recorder dropped 6000 step rows" in page


def test_a_recovered_copy_still_says_what_its_recorder_dropped(
    dropped_file: Path, tmp_path: Path
) -> None:
    """Torn after its run-end record (the footer lost), then recovered: the copy's run-end
    record is recover's, and keeps the original's counts of what the recorder dropped."""
    from episode_audit import recover

    torn = tmp_path / "torn.mcap"
    torn.write_bytes(dropped_file.read_bytes()[:-8])
    copy = tmp_path / "copy.mcap"
    recover(torn, copy)
    assert open_evidence(copy).run_end["status"] == "recovered"  # type: ignore[index]
    (trouble,) = [f for f in check([copy]).findings if f.code == "recorder_trouble"]
    assert DROPPED.search(trouble.message), trouble.message
