"""Every command's ``--help`` names its values in words, never by a Python type."""

from __future__ import annotations

import re

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from episode_audit.cli import app

COMMANDS = sorted(get_command(app).commands)  # type: ignore[attr-defined]
PYTHON_TYPE = re.compile(r"<(?:list|dict|tuple|str|int|float|bool|path|Path)\b[^>]*>|\brange>")


@pytest.mark.parametrize("command", [[], *([c] for c in COMMANDS)], ids=lambda c: " ".join(c))
def test_help_shows_no_python_type(command: list[str]) -> None:
    result = CliRunner().invoke(app, [*command, "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    assert not PYTHON_TYPE.search(result.output), PYTHON_TYPE.findall(result.output)
    assert "Usage:" in result.output


def test_every_option_with_a_value_has_a_metavar() -> None:
    for name, command in get_command(app).commands.items():  # type: ignore[attr-defined]
        for param in command.params:
            if not getattr(param, "is_flag", False) and param.name != "help":
                assert param.metavar, f"{name} {param.name}: no metavar"


def test_compare_help_names_its_positional_paths_the_baseline() -> None:
    result = CliRunner().invoke(app, ["compare", "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0
    # ({BASELINE}... in Typer's newer usage line, BASELINE in older ones)
    assert re.search(r"compare \[OPTIONS\] \{?BASELINE\b", result.output), result.output
    assert "The baseline's evidence files" in result.output


@pytest.mark.parametrize(
    ("command", "example"),
    [
        ("export", "e.g. episode-audit export runs/ -o tables/"),
        ("export", "python -m episode_audit.export.layout run.foxglove.mcap > layout.json"),
        ("show", "e.g. episode-audit show runs/run.mcap"),
    ],
)
def test_export_and_show_help_give_an_example_within_80_columns(command: str, example: str) -> None:
    result = CliRunner().invoke(app, [command, "--help"], terminal_width=80)
    assert result.exit_code == 0, result.output
    assert example in result.output  # (a line of its own: Click does not rewrap it)
    assert all(len(line) <= 80 for line in result.output.splitlines()), result.output


def test_no_help_points_to_a_docs_file_the_installed_package_lacks() -> None:
    """``export --help`` pointed to docs/viewers.md, which no installed package holds."""
    for command in COMMANDS:
        result = CliRunner().invoke(app, [command, "--help"], terminal_width=100)
        assert not re.search(r"docs/\S+\.(md|json)", result.output), (command, result.output)


def test_compare_help_names_the_verdicts_and_which_exit_1() -> None:
    """``compare --help`` named neither its verdicts nor the exit codes nor where they are told."""
    result = CliRunner().invoke(app, ["compare", "--help"], terminal_width=80)
    assert result.exit_code == 0, result.output
    for verdict in ("regressed", "improved", "held", "underpowered", "inconclusive"):
        assert re.search(rf"^ +{verdict} +\S", result.output, re.M), verdict
    assert "significantly worse (Holm-adjusted p < 0.05): exit 1" in result.output
    assert "Exit 1 also when a gate fails" in result.output
    assert "compare.md in the project's docs" in result.output
    assert all(len(line) <= 80 for line in result.output.splitlines()), result.output
