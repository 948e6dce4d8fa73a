"""The terminal tables at 80, 100 and 120 columns: no header or label is broken mid-word."""

from __future__ import annotations

import io
import re
from pathlib import Path

import gymnasium as gym
import pytest
from rich.console import Console, Group

from episode_audit import RecordEvidence, RecordVectorEvidence
from episode_audit.check import check
from episode_audit.cli.render import FittedTable, check_output, replay_output, report_output, table
from episode_audit.cli.render.report import _group_row
from episode_audit.replay import replay
from episode_audit.report import report_inputs
from tests.report.test_report import Plan, _record_plans
from tests.support.factories import heavy_cartpole

WIDTHS = [80, 100, 120]


def _render(renderable: object, width: int) -> str:
    console = Console(file=io.StringIO(), width=width, color_system=None)
    console.print(renderable)
    text = console.file.getvalue()  # type: ignore[attr-defined]
    assert max(map(len, text.splitlines())) <= width
    return str(text)


def _tables(renderable: object) -> list[FittedTable]:
    if isinstance(renderable, FittedTable):
        return [renderable]
    if isinstance(renderable, Group):
        return [t for r in renderable.renderables for t in _tables(r)]
    return []


_SOFT_END = tuple("=(,/:;.")


def _assert_words_whole(renderable: object, width: int) -> str:
    """Every word of every header and cell appears whole on one line of the output, or broken
    only after a ``=``, ``(``, ``,``, ``/``, ``:``, ``;`` or ``.`` (a word too long for its
    column)."""
    text = _render(renderable, width)
    split = text.split()
    tokens = set(split)
    for _ in range(3):  # a piece ending at a soft break, joined to the next token
        split = [a + b if a.endswith(_SOFT_END) else a for a, b in zip(split, [*split[1:], ""])]
        tokens |= set(split)
    tables = _tables(renderable)
    assert tables
    for t in tables:
        words = {w for cell in [*t.headers, *(c for r in t.rows for c in r)] for w in cell.split()}
        broken = sorted(w for w in words if len(w) <= width // 2 and w not in tokens)
        assert not broken, f"split across lines at width {width}: {broken}\n{text}"
    return text


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    for policy, plans in {
        "scripted": [Plan("success"), Plan("truncated:time_limit"), Plan("success")],
        "hacker": [
            Plan("failure:door_slammed"),
            Plan("failure:drawer_yanked", reward=3.0),
            Plan("failure:dropped_object", terms={"progress_velocity": 2.0, "ctrl_cost": -1.0}),
        ],
    }.items():
        _record_plans(root / f"{policy}.mcap", plans, tags={"policy": policy})
    return root


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("by", ["tag:policy", "file", "label"])
def test_report_fits_without_breaking_words(runs: Path, by: str, width: int) -> None:
    result = report_inputs([runs], by=by).report
    text = _assert_words_whole(report_output(result, "table"), width)
    for header in ("success", "episodes", "truncated", "incomplete", "drawer_yanked"):
        assert re.search(rf"(?<!\S){re.escape(header)}", text), header


@pytest.mark.parametrize("width", [*WIDTHS, 160])
def test_report_is_side_by_side_only_when_no_cell_wraps(runs: Path, width: int) -> None:
    text = _render(report_output(report_inputs([runs], by="tag:policy").report, "table"), width)
    header = next(line for line in text.splitlines() if "episodes" in line)
    assert ("incomplete" in header) == (width >= 160)  # else the vertical layout


@pytest.fixture(scope="module")
def vector_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("vector") / "vector.mcap"
    envs = gym.make_vec("CartPole-v1", 4, vectorization_mode="sync")
    with RecordVectorEvidence(envs, path) as env:
        env.reset(seed=0)
        env.action_space.seed(0)
        for _ in range(120):
            env.step(env.action_space.sample())
    return path


@pytest.mark.parametrize("width", [*WIDTHS, 160])
@pytest.mark.parametrize("by", ["env_index", "all", "file", "env", "label", "tag:policy"])
def test_report_outcome_cells_are_never_cut(vector_run: Path, by: str, width: int) -> None:
    # side by side at 100 columns, "13 (100.0% [77.2, 100.0])" was read over three lines
    result = report_inputs([vector_run], by=by).report
    lines = _render(report_output(result, "table"), width).splitlines()
    for g in result.groups:
        row = _group_row(g)
        for cell in [row[2], row[3], row[5], row[10], row[11]]:  # rates, return, length
            assert any(cell in line for line in lines), (cell, width)


@pytest.mark.parametrize("width", WIDTHS)
def test_check_findings_fit_without_breaking_words(repo: Path, width: int) -> None:
    result = check([repo / "fixtures" / "terms_mismatch.mcap", repo / "fixtures" / "torn.mcap"])
    assert result.findings
    _assert_words_whole(check_output(result, "table"), width)


@pytest.mark.parametrize("width", WIDTHS)
def test_replay_divergences_fit_without_breaking_words(tmp_path: Path, width: int) -> None:
    path = tmp_path / "cartpole.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        for seed in range(2):
            env.reset(seed=seed)
            for _ in range(8):  # (CartPole falls after ~9 steps of one action)
                env.step(seed % 2)
    result = replay([path], env_factory=heavy_cartpole)
    assert result.count("diverged")
    _assert_words_whole(replay_output(result, "table"), width)


@pytest.mark.parametrize("width", [40, 60, *WIDTHS])
def test_a_table_too_wide_for_the_console_turns_vertical(width: int) -> None:
    rows = [["/runs/" + "a" * 30 + ".mcap", "failure", "door_slammed", "3", "long " * 20]]
    out = table("t", ["file", "outcome", "failure label", "episodes", "why"], rows)
    text = _assert_words_whole(out, width)
    assert ("failure label" in text) or ("failure" in text and "label" in text)


@pytest.mark.parametrize("width", [*WIDTHS, 160])
def test_compare_metric_cells_are_never_cut(tmp_path: Path, width: int) -> None:
    # side by side at 120 columns, "0.0% (n 20)" was read over two lines
    from episode_audit.cli.render.compare import _row, compare_output
    from episode_audit.compare import compare_inputs

    paths = []
    for name, seed in (("base", 0), ("cand", 100)):
        path = tmp_path / f"{name}.mcap"
        with RecordEvidence(gym.make("CartPole-v1"), path) as env:
            env.action_space.seed(seed)
            for episode in range(12):
                env.reset(seed=seed + episode)
                done = False
                while not done:
                    *_, terminated, truncated, _ = env.step(env.action_space.sample())
                    done = terminated or truncated
        paths.append(path)
    result = compare_inputs([paths[0]], [paths[1]]).comparison
    lines = _render(compare_output(result, "table"), width).splitlines()
    for g in result.groups:
        for metric in g.metrics:
            for cell in _row(g.key, metric)[2:5]:  # baseline, candidate, difference
                assert any(cell in line for line in lines), (cell, width)


@pytest.mark.parametrize("width", [60, 64, *WIDTHS])
def test_a_gate_detail_with_a_long_call_breaks_it_where_it_reads_on(
    tmp_path: Path, width: int
) -> None:
    """``ending_rules=EndingRules(success_fn=...)``, longer than the detail column, was cut
    mid-word (``EndingRules(success`` / ``_fn=...)``); it breaks after ``(`` now."""
    from episode_audit.cli.render.compare import compare_output
    from episode_audit.compare import compare_inputs

    paths = []
    for name, seed in (("base", 0), ("cand", 100)):
        path = tmp_path / f"{name}.mcap"
        with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=20), path) as env:
            for episode in range(4):
                env.reset(seed=seed + episode)
                for _ in range(20):
                    if any(env.step(episode % 2)[2:4]):
                        break
        paths.append(path)
    result = compare_inputs([paths[0]], [paths[1]], max_success_drop=0.05).comparison
    text = _assert_words_whole(compare_output(result, "table"), width)
    assert "ending_rules=EndingRules(" in text
    assert "EndingRules(success " not in " ".join(text.split())  # (not folded at the edge)


LONG_PATH = (
    "longdir/a_fairly_long_folder_name_for_runs/another_long_subfolder_name/"
    "counting-environment-run.mcap"
)
_BREAK_AFTER = ("/", ".", "=", "(", ",", ":", ";")


def _first_column_pieces(text: str, first: str) -> list[str]:
    """The lines the first column shows ``first`` on, in order (under the header's rule)."""
    lines = text.splitlines()
    body = lines[next(i for i, line in enumerate(lines) if "─" in line) + 1 :]
    pieces: list[str] = []
    for line in body:
        if len("".join(pieces)) >= len(first):
            break
        if line[1:2].strip():
            pieces.append(line.split()[0])
    return pieces


@pytest.mark.parametrize("width", [40, 60, *WIDTHS])
@pytest.mark.parametrize("whole", [False, True])
def test_a_long_file_path_in_the_first_column_breaks_after_a_slash(width: int, whole: bool) -> None:
    """A path in the first column (replay's file, report's group) was folded character by
    character (``…/counting-environment-run.mca`` / ``p``): it breaks after ``/`` or ``.``
    now, and is cut only where no break point fits."""
    detail = "env id 'Counting-v0' is not registered in this process; pass --import MODULE"
    value = "3 (100.0% [43.9, 100.0])" if whole else detail
    out = table("t", ["file", "episodes", "status", "value"], [[LONG_PATH, "3", "ok", value]],
                whole_cells=whole)  # fmt: skip
    text = _render(out, width)
    pieces = _first_column_pieces(text, LONG_PATH)
    assert "".join(pieces) == LONG_PATH, text
    room = max(map(len, pieces))
    for i, piece in enumerate(pieces[:-1]):
        if piece.endswith(_BREAK_AFTER):
            continue
        rest = "".join(pieces[i:])  # cut: no break point of what follows fitted the column
        first_break = min((rest.find(c) + 1 for c in _BREAK_AFTER if c in rest), default=0)
        assert first_break > room, f"cut mid-word at width {width}: {pieces}\n{text}"
    if width >= 80:  # room for every piece between two slashes: no word is cut
        assert all(p.endswith(_BREAK_AFTER) for p in pieces[:-1]), text


@pytest.mark.parametrize("width", [60, *WIDTHS])
def test_a_first_cell_with_no_break_point_does_not_cut_the_values(width: int) -> None:
    """A folder name longer than the first column may have is cut; the values keep their
    words (``[0.0020830899011343718,`` was cut when the first column kept its piece)."""
    first = "runs/" + "x" * 70 + "/cartpole.mcap"
    detail = "observation expected [0.0020830899011343718, 0.24066002666950226, -0.034686]"
    out = table("t", ["file", "episode", "status", "detail"], [[first, "0", "diverged", detail]])
    _assert_words_whole(out, width)
    pieces = _first_column_pieces(_render(out, width), first)
    assert "".join(pieces) == first and pieces[0] == "runs/"
