"""report_inputs: the library behind ``episode-audit report`` (options, inputs, --games)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from episode_audit import ConfigurationError, EpisodeAuditError
from episode_audit.report import Gates, report, report_inputs
from episode_audit.report.inputs import gates_from_options

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures"
CLEAN = FIXTURES / "clean.mcap"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"by": "colour"}, "--by: expected file, env, env_index, agent, label, all or tag:NAME"),
        ({"by": "tag:"}, "--by: expected file, env, env_index, agent, label, all or tag:NAME"),
        ({"by": "agent", "games": True}, "--games cannot be grouped --by agent"),
        ({"max_failure_rate": ["x"]}, "--max-failure-rate: expected RATE or LABEL=RATE, got 'x'"),
        ({"max_failure_rate": ["x=2"]}, "--max-failure-rate: expected a rate between 0 and 1"),
        ({"max_failure_rate": ["=0.1"]}, "got '=0.1' (no label)"),
        ({"min_success_rate": 80.0}, "--min-success-rate: expected a rate between 0 and 1, got 80"),
        ({"max_truncation_rate": -1.0}, "--max-truncation-rate: expected a rate"),
        ({"max_error_rate": float("nan")}, "--max-error-rate: expected a rate"),
        # the options first, in the command's order, then the inputs
        ({"by": "colour", "max_failure_rate": ["x"]}, "--by: expected"),
        ({"max_failure_rate": ["x"], "min_success_rate": 2.0}, "--max-failure-rate: expected"),
    ],
)
def test_options_are_checked_in_the_command_line_words(
    tmp_path: Path, options: dict[str, object], message: str
) -> None:
    with pytest.raises(ConfigurationError) as raised:
        report_inputs([tmp_path / "missing.mcap"], **options)  # type: ignore[arg-type]
    assert message in str(raised.value)


def test_gates_from_options_parse_rate_and_label_rate() -> None:
    gates = gates_from_options(
        min_success_rate=0.9,
        max_failure_rate=["collision=0.1", "drop=0", "0.2"],
        max_truncation_rate=0.5,
        max_error_rate=0.0,
        fail_on_incentive_warning=True,
    )
    assert gates == Gates(
        min_success_rate=0.9,
        max_failure_rate=0.2,
        max_failure_rate_by_label={"collision": 0.1, "drop": 0.0},
        max_truncation_rate=0.5,
        fail_on_incentive_warning=True,
        max_error_rate=0.0,
    )
    assert gates_from_options() == Gates()


def test_unreadable_inputs_are_listed_and_the_others_reported(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 100)
    shutil.copy(CLEAN, tmp_path / "clean.mcap")
    told: list[EpisodeAuditError] = []
    result = report_inputs([tmp_path], by="all", on_error=told.append)
    assert result.readable == 1
    assert [u.file for u in result.unreadable] == [str(bad)]
    assert [str(e) for e in told] == [f"{u.file}: {u.why}" for u in result.unreadable]
    assert result.report.to_dict() == report([CLEAN], by="all").to_dict()


def test_a_missing_input_is_a_configuration_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match=r"missing\.mcap: no such file or directory"):
        report_inputs([tmp_path / "missing.mcap"])


def test_games_refuse_a_file_that_is_not_pettingzoo() -> None:
    with pytest.raises(ConfigurationError, match=r"clean\.mcap is a single-env file"):
        report_inputs([CLEAN], games=True)
    # the library functions count nothing of it, as they always did
    assert report([CLEAN], games=True).groups == []


def test_gates_are_checked_and_notes_kept() -> None:
    result = report_inputs([CLEAN], by="all", max_failure_rate=["colision=0.1"])
    assert result.report.passed and result.report.unmatched_labels == ["colision"]
    assert result.unreadable == []
    missed = report_inputs([CLEAN], min_success_rate=0.95)
    assert not missed.report.passed
