"""The incentive-warning registry and the docs table generated from it."""

from __future__ import annotations

from pathlib import Path

from episode_audit.report.incentives import INCENTIVE_WARNINGS, incentive_table

REPO = Path(__file__).resolve().parents[2]


def test_the_reporting_doc_holds_the_generated_incentive_table() -> None:
    doc = (REPO / "docs" / "reporting.md").read_text()
    assert incentive_table() in doc, "paste incentive_table() into docs/reporting.md"
    assert set(INCENTIVE_WARNINGS) == {
        "failure_outearns_success",
        "truncation_outearns_success",
        "no_success_positive_return",
        "shaping_dominates",
    }
