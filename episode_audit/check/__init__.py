"""The check wing: evidence files in, findings out.

:func:`check` (files) and :func:`check_evidence` (one open file) return :class:`Finding` s in a
:class:`CheckResult`. Every finding code, with its severity, meaning and fix, is an entry of
the registry (:data:`KINDS`, :class:`FindingKind`), from which ``docs/findings.md`` is made.
"""

from .core import check, check_evidence
from .findings import CheckResult, Finding
from .registry import (
    FINDING_CODES,
    KINDS,
    FindingKind,
    Severity,
    ignored_codes,
    is_ignored,
    kind_of,
)

__all__ = [
    "FINDING_CODES",
    "KINDS",
    "CheckResult",
    "Finding",
    "FindingKind",
    "Severity",
    "check",
    "check_evidence",
    "ignored_codes",
    "is_ignored",
    "kind_of",
]
