"""The compare wing: whether the candidate regressed against the baseline, and how surely.

- :mod:`.core`: :func:`compare`, :func:`compare_tables` and the :class:`Comparison` they return;
- :mod:`.inputs`: :func:`compare_inputs`, the library behind ``episode-audit compare``;
- :mod:`.groups`: one group's metrics, gates (:class:`CompareGates`) and new warnings;
- :mod:`.metrics`: one metric's difference, interval, test, plan and verdict;
- :mod:`.sides`: a side's episodes as arrays; pairs on matched reset seeds;
- :mod:`.spec`: what differs between the sides' runs; :mod:`.stats`: the statistics.

Statistics, verdicts and the JSON shape: ``docs/compare.md``.
"""

from .core import Case, Comparison, compare, compare_tables
from .groups import CompareGates, GroupComparison
from .inputs import InputsComparison, compare_inputs
from .metrics import VERDICTS, MetricComparison, Verdict
from .spec import Mismatch

__all__ = [
    "VERDICTS",
    "Case",
    "CompareGates",
    "Comparison",
    "GroupComparison",
    "InputsComparison",
    "MetricComparison",
    "Mismatch",
    "Verdict",
    "compare",
    "compare_inputs",
    "compare_tables",
]
