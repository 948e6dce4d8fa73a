"""The report wing: success, failure and truncation rates per group, gates for CI.

- :mod:`.core`: :func:`report`, :func:`report_tables` and the :class:`Report` they return;
- :mod:`.inputs`: :func:`report_inputs`, the library behind ``episode-audit report``;
- :mod:`.collect`: episodes and reward-term totals of opened files, keyed by the grouping;
- :mod:`.groups`: one group's counts, rates and statistics (:class:`GroupReport`);
- :mod:`.incentives`: :class:`IncentiveWarning` and the rules that raise them;
- :mod:`.gates`: :class:`Gates` and :class:`GateResult`;
- :mod:`.stats`: :func:`wilson_interval` and :class:`Interval`; :mod:`.games`: PettingZoo games;
- :mod:`.html`: :func:`write_report_html`, the self-contained HTML page (charts: :mod:`.charts`).
- :mod:`.wrapped`: whose rewards the returns are (the reward wrappers files were recorded over).

Rates, denominators, warnings and the JSON shape: ``docs/reporting.md``.
"""

from .core import Report, report, report_tables
from .gates import GateResult, Gates
from .groups import GroupReport
from .html import write_report_html
from .incentives import IncentiveWarning
from .inputs import InputsReport, report_inputs
from .stats import Interval, wilson_interval

__all__ = [
    "GateResult",
    "Gates",
    "GroupReport",
    "IncentiveWarning",
    "InputsReport",
    "Interval",
    "Report",
    "report",
    "report_inputs",
    "report_tables",
    "wilson_interval",
    "write_report_html",
]
