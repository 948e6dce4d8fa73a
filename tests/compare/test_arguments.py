"""compare()'s arguments: what the command line refuses, the library refuses in the same words."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from episode_audit import CompareGates, ConfigurationError, Gates, compare
from episode_audit.compare.inputs import compare_inputs
from episode_audit.report import report_inputs
from episode_audit.rollout import record_episodes


@pytest.fixture(scope="module")
def sides(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("sides")
    for name in ("base", "cand"):
        record_episodes("CartPole-v1", out / f"{name}.mcap", episodes=5, max_episode_steps=20)
    return out / "base.mcap", out / "cand.mcap"


@pytest.mark.parametrize(
    ("margin", "message"),
    [
        (2, r"^rate_margin: expected a rate in \(0, 1\], got 2$"),
        (-1, r"^rate_margin: expected a rate in \(0, 1\], got -1$"),
        (0, r"^rate_margin: expected a rate in \(0, 1\], got 0$"),
        ("x", r"^rate_margin: expected a rate in \(0, 1\], got 'x'$"),
        (None, r"^rate_margin: expected a rate in \(0, 1\], got None$"),
    ],
)
def test_a_rate_margin_out_of_range_is_refused_not_judged(
    sides: tuple[Path, Path], margin: Any, message: str
) -> None:
    with pytest.raises(ConfigurationError, match=message):
        compare([sides[0]], [sides[1]], rate_margin=margin)


@pytest.mark.parametrize(
    ("gates", "message"),
    [
        ({"max_return_drop": -1}, r"^max_return_drop: expected a finite number >= 0, got -1$"),
        ({"max_return_drop": "5"}, r"^max_return_drop: expected a finite number >= 0, got '5'$"),
        ({"max_return_drop": float("nan")}, "max_return_drop: expected a finite number >= 0"),
        ({"max_success_drop": 2}, r"^max_success_drop: expected a rate between 0 and 1, got 2$"),
        (
            {"max_failure_increase": -0.5},
            r"^max_failure_increase: expected a rate between 0 and 1, got -0.5$",
        ),
        (
            {"max_failure_increase_by_label": {"collision": True}},
            r"^max_failure_increase_by_label\['collision'\]: expected a rate between 0 and 1",
        ),
        (
            {"max_failure_increase_by_label": [("collision", 0.1)]},
            r"^max_failure_increase_by_label: expected a mapping of failure labels to rates",
        ),
        (  # (compare raised TypeError sorting the labels)
            {"max_failure_increase_by_label": {3: 0.1}},
            r"^max_failure_increase_by_label: expected failure labels as text, got 3",
        ),
        (
            {"fail_on_new_incentive_warning": "no"},
            r"^fail_on_new_incentive_warning: expected True or False, got 'no'$",
        ),
    ],
)
def test_compare_gates_refuse_what_the_command_line_refuses(
    gates: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigurationError, match=message):
        CompareGates(**gates)


def test_reports_gates_given_to_compare_say_which_gates_it_takes(
    sides: tuple[Path, Path],
) -> None:
    with pytest.raises(
        ConfigurationError,
        match=r"^gates: expected a CompareGates, got Gates; report's Gates bound one run's",
    ):
        compare([sides[0]], [sides[1]], gates=Gates(min_success_rate=0.5))  # type: ignore[arg-type]


@pytest.mark.parametrize("empty", ["baseline", "candidate"])
def test_a_side_without_files_is_said_so(sides: tuple[Path, Path], empty: str) -> None:
    given = {"baseline": [sides[0]], "candidate": [sides[1]], empty: []}
    with pytest.raises(ConfigurationError, match=rf"^no {empty} files: expected at least one"):
        compare(given["baseline"], given["candidate"])


def test_a_tag_no_file_has_is_said_as_report_says_it(sides: tuple[Path, Path]) -> None:
    # report warned of a misspelt tag; compare put every episode in '(none)' and said nothing
    result = compare([sides[0]], [sides[1]], by="tag:confg")
    note = (
        "by tag:confg: no file has the tag 'confg', so every episode is in the group '(none)': "
        "is the tag spelt as recorded?"
    )
    assert result.notes[0] == note and result.to_dict()["notes"][0] == note
    assert note not in compare([sides[0]], [sides[1]], by="env").notes


def test_a_gate_given_twice_is_refused_naming_both_values(sides: tuple[Path, Path]) -> None:
    # the last value was kept silently: 0.9 replaced 0.1, and the run passed
    from typer.testing import CliRunner

    from episode_audit.cli import app

    base, cand = map(str, sides)
    runner = CliRunner()
    for args, line in [
        (
            ["report", base, "--max-failure-rate", "0.1", "--max-failure-rate", "0.9"],
            "--max-failure-rate: given twice for all failures ('0.1' and '0.9'); give each "
            "gate once",
        ),
        (
            ["compare", base, "--candidate", cand, "--max-failure-increase", "fell=0.05",
             "--max-failure-increase", "fell=0.5"],
            "--max-failure-increase: given twice for the label 'fell' ('fell=0.05' and "
            "'fell=0.5'); give each gate once",
        ),
    ]:  # fmt: skip
        result = runner.invoke(app, [*args, "-j", "1"])
        assert result.exit_code == 2 and result.stderr == f"episode-audit: error: {line}\n"
    both = ["0.1", "fell=0.2", "0.1"]
    with pytest.raises(ConfigurationError, match=r"^--max-failure-rate: given twice for all"):
        report_inputs([base], max_failure_rate=both)
    other_labels = compare_inputs([base], [cand], max_failure_increase=["a=0.1", "b=0.1", "0.2"])
    assert other_labels.comparison.groups  # (one gate a label, and one overall: accepted)


def test_an_unknown_grouping_lists_only_those_compare_takes(sides: tuple[Path, Path]) -> None:
    # the list was report's, with 'file' and 'label', which compare then refused
    line = "by: expected 'all', 'env', 'env_index', 'agent' or 'tag:NAME', actually: 'foo'"
    with pytest.raises(ConfigurationError, match=f"^{line}$"):
        compare([sides[0]], [sides[1]], by="foo")
    from typer.testing import CliRunner

    from episode_audit.cli import app

    args = ["compare", str(sides[0]), "--candidate", str(sides[1]), "--by", "foo", "-j", "1"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and result.stderr == f"episode-audit: error: {line}\n"
