"""What ``check`` returns: :class:`Finding` (one problem or remark) and :class:`CheckResult`.

The codes, severities and meanings of findings are in :mod:`episode_audit.check.registry`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..read.inputs import Unreadable
from .registry import Severity

__all__ = ["CheckResult", "Finding"]


@dataclass(frozen=True)
class Finding:
    """One thing :func:`~episode_audit.check.check` found in an evidence file.

    ``episode`` and ``step`` locate the first occurrence (``None`` for a file-level finding, and
    ``step`` is ``None`` for episode-level ones and reset observations).

    >>> Finding("error", "nonfinite_reward", "reward nan at step 3", "run.mcap", 0, 3).to_dict()
    {'severity': 'error', 'code': 'nonfinite_reward', 'message': 'reward nan at step 3', \
'file': 'run.mcap', 'episode': 0, 'step': 3}
    """

    severity: Severity
    code: str
    message: str
    file: str
    episode: int | None = None
    step: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the finding as a JSON-able dict (keys as the dataclass fields, in order)."""
        return {
            "severity": self.severity,
            "code": self.code,
            "message": self.message,
            "file": self.file,
            "episode": self.episode,
            "step": self.step,
        }


@dataclass
class CheckResult:
    """The findings of :func:`~episode_audit.check.check` over some files, with what was checked.

    :meth:`to_dict` returns this JSON shape (stable; new keys may be added, none removed)::

        {
          "ok": bool,                    # no error-severity findings
          "files": [str, ...],           # the files checked, in the order given
          "episodes": int,               # episodes checked, over all files (unstarted
                                         # ones, reset and never stepped, not counted)
          "steps": int,                  # step rows checked, over all files
          "counts": {"error": int, "warning": int, "note": int},
          "findings": [                  # ordered by file, then location
            {"severity": "error" | "warning" | "note", "code": str, "message": str,
             "file": str, "episode": int | null, "step": int | null},
            ...
          ],
          "ignored": int                 # findings left out by ``ignore`` (not in counts)
        }
    """

    findings: list[Finding]
    files: list[str]
    episodes: int
    steps: int
    ignored: int = 0
    """Findings left out because their code was ignored (see :func:`~episode_audit.check.check`)."""
    ignored_by: dict[str, int] = field(default_factory=dict)
    """How many findings each code given to ``ignore`` left out (0: it matched none)."""
    unreadable: list[Unreadable] = field(default_factory=list)
    """The inputs that could not be read (only with ``keep_going``; each is also in ``files``)."""

    def _count(self, severity: str) -> int:
        return sum(1 for f in self.findings if f.severity == severity)

    @property
    def errors(self) -> int:
        """Number of error-severity findings."""
        return self._count("error")

    @property
    def warnings(self) -> int:
        """Number of warning-severity findings."""
        return self._count("warning")

    @property
    def notes(self) -> int:
        """Number of note-severity findings."""
        return self._count("note")

    @property
    def ok(self) -> bool:
        """Whether files were checked and no finding has error severity.

        Nothing checked is no pass: ``check([]).ok`` is false (an ``assert check(files).ok``
        over a glob that found nothing fails).
        """
        return self.errors == 0 and bool(self.files)

    def to_dict(self) -> dict[str, Any]:
        """Return the result in the JSON shape documented on the class."""
        return {
            "ok": self.ok,
            "files": list(self.files),
            "episodes": self.episodes,
            "steps": self.steps,
            "counts": {"error": self.errors, "warning": self.warnings, "note": self.notes},
            "findings": [f.to_dict() for f in self.findings],
            "ignored": self.ignored,
        }
