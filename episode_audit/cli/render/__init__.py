"""Renderers of the CLI's results: Rich tables, Markdown (CI job summaries), JSON and JUnit."""

from .check import check_cases, check_output
from .common import (
    JSON_SCHEMA_VERSION,
    WORD_JOINER,
    FittedTable,
    Output,
    OutputFormat,
    fmt_number,
    markdown_table,
    markdown_text,
    rate,
    safe,
    table,
    to_json,
    unreadable_json,
    versioned,
    wrapped,
)
from .junit import JUnitCase, JUnitStatus, junit_xml
from .replay import replay_cases, replay_output
from .report import REPORT_HEADERS, report_cases, report_output

__all__ = [
    "JSON_SCHEMA_VERSION",
    "REPORT_HEADERS",
    "WORD_JOINER",
    "FittedTable",
    "JUnitCase",
    "JUnitStatus",
    "Output",
    "OutputFormat",
    "check_cases",
    "check_output",
    "fmt_number",
    "junit_xml",
    "markdown_table",
    "markdown_text",
    "rate",
    "replay_cases",
    "replay_output",
    "report_cases",
    "report_output",
    "safe",
    "table",
    "to_json",
    "unreadable_json",
    "versioned",
    "wrapped",
]
