"""The check wing: evidence files in, findings out (see ``docs/findings.md``)."""

from .core import (
    FINDING_CODES,
    CheckResult,
    Finding,
    Severity,
    check,
    check_evidence,
    ignored_codes,
    is_ignored,
)

__all__ = [
    "FINDING_CODES",
    "CheckResult",
    "Finding",
    "Severity",
    "check",
    "check_evidence",
    "ignored_codes",
    "is_ignored",
]
