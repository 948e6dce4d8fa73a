"""Every command's lines for people fit 80 columns (``COLUMNS=80``, output not a terminal).

A line may be longer only for a word no line holds (a long path), which is never broken.
"""

from __future__ import annotations

import shutil
from itertools import pairwise
from pathlib import Path

import gymnasium as gym
import pytest
from rich.cells import cell_len
from typer.testing import CliRunner

from episode_audit import RecordEvidence
from episode_audit.cli import app

runner = CliRunner()


def _too_long(text: str) -> list[str]:
    """The lines of ``text`` wider than 80 cells without a word wider than 78 (a long path)."""
    return [
        line
        for line in text.splitlines()
        if cell_len(line) > 80 and all(cell_len(word) <= 78 for word in line.split())
    ]


def _run(args: list[str], code: int) -> tuple[str, str]:
    result = runner.invoke(app, args, env={"COLUMNS": "80"})
    assert result.exit_code == code, (result.stdout, result.stderr)
    assert not _too_long(result.stdout), result.stdout
    assert not _too_long(result.stderr), result.stderr
    return result.stdout, result.stderr


def _cartpole(path: Path, episodes: int = 3) -> Path:
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        for seed in range(episodes):
            env.reset(seed=seed)
            while not any(env.step(seed % 2)[2:4]):
                pass
    return path


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, repo: Path) -> Path:
    """A folder of short file names, the current one: a torn file and two CartPole runs."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(repo / "fixtures" / "torn.mcap", "torn.mcap")
    _cartpole(tmp_path / "base.mcap")
    _cartpole(tmp_path / "cand.mcap")
    return tmp_path


def test_recover_says_its_result_within_80_columns(here: Path) -> None:
    """It was one line of about 255 characters."""
    out, _ = _run(["recover", "torn.mcap", "-o", "out.mcap"], 1)
    assert out.startswith("recovered torn.mcap -> out.mcap: ")
    assert len(out.splitlines()) > 1 and out.splitlines()[1].startswith("  ")


def test_export_s_notes_fit_80_columns(here: Path) -> None:
    """A note on a torn input was one line of about 170 characters."""
    _, err = _run(["export", "torn.mcap", "-o", "tables"], 0)
    assert err.startswith("episode-audit: note: torn.mcap is unfinished")
    assert "exported what it holds" in " ".join(err.split())


def test_report_s_and_compare_s_warnings_fit_80_columns(here: Path) -> None:
    _run(["report", "base.mcap", "--by", "label"], 0)
    _, err = _run(["compare", "base.mcap", "--candidate", "cand.mcap"], 0)
    assert "too few" in err


@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["show", "."], 2),  # a directory; show reads one evidence file ...
        (["recover", "torn.mcap", "-o", "base.mcap"], 2),  # file exists ...
        (["compare", "base.mcap", "--candidate", "base.mcap"], 2),  # on both sides ...
        (["export", "base.mcap", "--to", "foxglove", "-o", "b.foxglove.mcap"], 0),
        (["record", "CartPole-v1", "--episodes", "2", "--out", "rec.mcap"], 0),
    ],
    ids=lambda a: " ".join(a) if isinstance(a, list) else None,
)
def test_other_lines_fit_80_columns(here: Path, args: list[str], code: int) -> None:
    _run(args, code)


def test_a_line_naming_a_path_no_line_holds_stays_one_line(here: Path) -> None:
    """The path is never broken; the error naming it is one line, as in a log."""
    deep = here / ("a_rather_long_folder_name_for_evaluation_runs_" * 2) / "runs"
    deep.mkdir(parents=True)
    missing = deep / "cartpole_evaluation_run.mcap"
    _, err = _run(["check", str(missing)], 2)
    assert err == f"episode-audit: error: {missing}: no such file or directory\n"


def test_a_table_s_title_wraps_at_the_terminal_s_width(here: Path) -> None:
    """``show --episode``'s title was wrapped at its table's width (49 columns) at 80."""
    _run(["record", "episode_audit/DoorOpen-v0", "--policy", "hacker", "--episodes", "1",
          "--seed", "100", "--out", "door.mcap"], 0)  # fmt: skip
    out, _ = _run(["show", "door.mcap", "--episode", "0", "--steps", "0:2"], 0)
    title = out.splitlines()[0]
    assert title.startswith("episode 0: failure (") and title.endswith(", seed 100"), out
    assert max(map(cell_len, out.splitlines()[1:])) < cell_len(title), out  # (narrower table)


NO_BREAK = "EvaluationOfTheCartPoleAgentTrainedWithProximalPolicyOptimisationOnNovemberTwentyNinth"


def test_a_file_name_with_no_break_point_is_broken_between_words_whole(here: Path) -> None:
    """A name with no space, ``-``, ``_``, ``/`` or ``.`` was cut where the column ended
    (``EvaluationOfTheCartPoleAgentTrai`` / ``nedWith...``): it breaks between a small and a
    capital letter now, every character kept."""
    shutil.copy("base.mcap", f"{NO_BREAK}.mcap")
    out, _ = _run(["report", f"{NO_BREAK}.mcap", "--by", "file"], 0)
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(" Evaluation"))
    pieces = [line.split()[0] for line in lines[at : at + 4]]
    assert "".join(pieces) == f"{NO_BREAK}.mcap", out
    assert all(a[-1].islower() and b[0].isupper() for a, b in pairwise(pieces)), pieces
