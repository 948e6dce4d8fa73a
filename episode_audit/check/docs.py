"""Write ``docs/findings.md`` from the findings registry.

Run ``python -m episode_audit.check.docs > docs/findings.md``; :func:`findings_markdown`
returns the page (a test compares it with the committed file).
"""

from __future__ import annotations

from .registry import KINDS, RECORDER_NOTE, FindingKind

__all__ = ["findings_markdown"]

_HEADER = """\
# Finding codes

<!-- Generated from episode_audit/check/registry.py by
     `python -m episode_audit.check.docs > docs/findings.md`; edit the registry, not this file. -->

Every finding of `episode-audit check` (and of `episode_audit.check`) has a stable code, a
severity (`error`, `warning`, `note`), a file, and the episode and step of its first occurrence
where it has one; its message gives counts. The severity below is the code's usual one; a
code's section says when it is another. `--ignore CODE` leaves a code out (see
[cli.md](cli.md#episode-audit-check-paths)); `recorder_note` stands for every
`recorder_note:<code>`.
"""


def _display(kind: FindingKind) -> str:
    return f"{kind.code}:<code>" if kind.code == RECORDER_NOTE else kind.code


def _severity(kind: FindingKind) -> str:
    return f"{kind.severity} ({kind.severity_note})" if kind.severity_note else kind.severity


def findings_markdown() -> str:
    """The page ``docs/findings.md``: a table of every code, then a section per code."""
    lines = [_HEADER, "| code | severity | summary |", "|---|---|---|"]
    for kind in KINDS:
        lines.append(f"| [`{_display(kind)}`](#{kind.code}) | {kind.severity} | {kind.summary} |")
    for kind in KINDS:
        lines += [
            "",
            f"## {kind.code}",
            "",
            f"`{_display(kind)}` — {_severity(kind)}. {kind.summary}",
            "",
            f"**What it means.** {kind.meaning}",
            "",
            f"**Why it matters.** {kind.why}",
            "",
            f"**How to fix it.** {kind.fix}",
        ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(findings_markdown(), end="")
