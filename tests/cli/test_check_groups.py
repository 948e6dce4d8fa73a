"""``check`` over many files: a code found in more than five files is one entry, not a row each."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence
from episode_audit.check import check
from episode_audit.cli import app
from episode_audit.cli.render import check_output

runner = CliRunner()


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # short file names (``runs/run_0.mcap``) keep the table wide


TITLE = "Findings in more than 5 files, by code (--no-group lists each one)"


class _HalfTerms(gym.Wrapper[Any, Any, Any, Any]):
    """Reward terms that sum to half the reward: a ``terms_sum_mismatch`` error each episode."""

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "reward_terms": {"alive": 0.5}}


class _TextReward(gym.Wrapper[Any, Any, Any, Any]):
    """A reward as text: a ``nonfinite_reward`` error and a recorder note (warning)."""

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, str(reward), terminated, truncated, info


def _record(path: Path, wrapper: type[gym.Wrapper[Any, Any, Any, Any]] | None = None) -> None:
    env: Any = gym.make("CartPole-v1")
    with RecordEvidence(env if wrapper is None else wrapper(env), path) as rec:
        rec.reset(seed=0)
        while not rec.step(0)[2]:  # (pushed left, the pole falls within a few steps)
            pass


def _campaign(clean: int, wrapper: Any = None, odd: int = 0) -> Path:
    root = Path("runs")
    root.mkdir()
    for i in range(clean):
        _record(root / f"run_{i}.mcap")
    for i in range(odd):
        _record(root / f"odd_{i}.mcap", wrapper)
    return root


def run(*args: str) -> tuple[int, str]:
    """Exit code and output at 80 columns (lines without their trailing padding)."""
    result = runner.invoke(app, list(args), env={"COLUMNS": "80"})
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    assert "json" in args or max(map(len, result.stdout.splitlines())) <= 80
    return result.exit_code, "\n".join(line.rstrip() for line in result.stdout.splitlines())


def test_codes_in_more_than_five_files_are_one_entry_each(tmp_path: Path) -> None:
    root = _campaign(clean=6, wrapper=_HalfTerms, odd=1)
    code, out = run("check", str(root))
    assert code == 1, out  # the one file's error still fails the check
    # the error of one file: a row of the table (vertical at 80 columns), with its message
    assert out.startswith("Findings")
    assert re.search(
        r"error +file +runs/odd_0\.mcap\n.*\n.*\n +code +terms_sum_mismatch\n"
        r" +message +reward 1 != terms sum 0\.5",
        out,
    ), out
    # missing_terms, in the 6 clean files: one entry, the first three places and the rest
    block = out[out.index(TITLE) :]
    assert re.search(
        r"note +missing_terms: 6 in 6 file\(s\)\n +Steps without reward terms\.\n"
        r" +runs/run_0\.mcap:0:0\n +runs/run_1\.mcap:0:0\n +runs/run_2\.mcap:0:0\n"
        r" +… and 3 more\n\n",
        block,
    ), out
    assert re.search(r"note +unlabeled_failure: 7 in 7 file\(s\)\n", block), out
    assert "missing_terms" not in out[: out.index(TITLE)]  # not also rows of the table
    assert out.rstrip().endswith("1 error(s), 0 warning(s), 13 note(s)")
    assert len(out.splitlines()) < 40


def test_grouped_errors_come_before_grouped_notes(tmp_path: Path) -> None:
    root = _campaign(clean=0, wrapper=_TextReward, odd=6)
    code, out = run("check", str(root))
    assert code == 1, out
    assert not out.startswith("Findings\n")  # no table: every code is an entry
    severities = re.findall(r"^(error|warning|note) +(\S+): \d+ in", out, flags=re.M)
    assert severities == [
        ("error", "nonfinite_reward"),
        ("warning", "recorder_note:reward_not_numeric"),
        ("note", "missing_terms"),
        ("note", "unlabeled_failure"),
    ]


def test_five_files_keep_a_row_per_finding(tmp_path: Path) -> None:
    root = _campaign(clean=5)
    code, out = run("check", str(root))
    assert code == 0, out
    assert TITLE not in out and "… and" not in out
    assert out.count("missing_terms") == 5


def test_group_and_no_group_override_the_rule(tmp_path: Path) -> None:
    root = _campaign(clean=6)
    _, out = run("check", str(root), "--no-group")
    assert TITLE not in out
    assert out.count("missing_terms") == 6
    _, out = run("check", str(root / "run_0.mcap"), "--group")
    title = "Findings, by code (--no-group lists each one)"
    assert out.startswith(title), out
    assert re.search(r"note +missing_terms: 1 in 1 file\(s\)\n", out), out


def test_markdown_groups_and_json_keeps_every_finding(tmp_path: Path) -> None:
    root = _campaign(clean=6, wrapper=_HalfTerms, odd=1)
    result = check(sorted(root.iterdir()))
    markdown = str(check_output(result, "markdown"))
    assert f"{TITLE}:\n\n| severity | code | findings | files | first at |" in markdown
    assert re.search(r"\| note \| missing_terms \| 6 \| 6 \| runs/run_0\.mcap:0:0, ", markdown)
    assert "and 3 more |" in markdown
    assert "| error | " in markdown.split(TITLE)[0]  # the one file's error: a row
    data = json.loads(str(check_output(result, "json")))
    assert len(data["findings"]) == len(result.findings) == 14
    code, out = run("check", str(root), "-f", "json")
    assert code == 1 and json.loads(out)["findings"] == data["findings"]


@pytest.mark.parametrize("width", [80, 100, 120])
def test_grouped_entries_fit_the_terminal(tmp_path: Path, width: int) -> None:
    root = _campaign(clean=6)
    result = runner.invoke(app, ["check", str(root)], env={"COLUMNS": str(width)})
    assert TITLE in result.stdout
    assert max(map(len, result.stdout.splitlines())) <= width
