"""The report wing: success, failure and truncation rates per group, gates for CI."""

from .core import (
    GateResult,
    Gates,
    GroupReport,
    IncentiveWarning,
    Interval,
    Report,
    report,
    report_tables,
    wilson_interval,
)

__all__ = [
    "GateResult",
    "Gates",
    "GroupReport",
    "IncentiveWarning",
    "Interval",
    "Report",
    "report",
    "report_tables",
    "wilson_interval",
]
