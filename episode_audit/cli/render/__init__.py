"""Renderers of the CLI's results: Rich tables, Markdown (CI job summaries) and JSON."""

from .check import check_output
from .common import (
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
)
from .replay import replay_output
from .report import REPORT_HEADERS, report_output

__all__ = [
    "REPORT_HEADERS",
    "WORD_JOINER",
    "FittedTable",
    "Output",
    "OutputFormat",
    "check_output",
    "fmt_number",
    "markdown_table",
    "markdown_text",
    "rate",
    "replay_output",
    "report_output",
    "safe",
    "table",
    "to_json",
    "unreadable_json",
]
