r"""JUnit XML for CI test reporters (GitHub Actions reporters, GitLab, Jenkins).

:class:`JUnitCase` is one test case: its suite, its name, its status and, for one that did
not pass, a one-line message and details. :func:`junit_xml` writes cases as one document:
``<testsuites>`` holding a ``<testsuite>`` per suite (in the order suites first appear), with
their counts. A case's ``classname`` is its suite. Every string is shown literally
(:func:`~.common.safe`: no control character, no CI workflow command), so the document stays
well-formed XML 1.0 whatever a file holds.

>>> print(junit_xml([JUnitCase("a.mcap", "terms_sum_mismatch", "failed", "step 3: 1 != 2")],
...                 name="episode-audit check"))  # doctest: +NORMALIZE_WHITESPACE
<?xml version="1.0" encoding="utf-8"?>
<testsuites name="episode-audit check" tests="1" failures="1" errors="0">
  <testsuite name="a.mcap" tests="1" failures="1" errors="0" skipped="0">
    <testcase name="terms_sum_mismatch" classname="a.mcap">
      <failure message="step 3: 1 != 2">step 3: 1 != 2</failure>
    </testcase>
  </testsuite>
</testsuites>
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal, NamedTuple
from xml.etree import ElementTree as ET

from .common import safe

__all__ = ["JUnitCase", "JUnitStatus", "junit_xml"]

JUnitStatus = Literal["passed", "failed", "error", "skipped"]
"""``failed``: the check ran and its answer is no (exit 1); ``error``: it could not run (an
unreadable input, exit 2); ``skipped``: it did not apply (e.g. an episode not replayable)."""

_ELEMENT: dict[str, str] = {"failed": "failure", "error": "error", "skipped": "skipped"}


class JUnitCase(NamedTuple):
    """One JUnit test case (one gate, finding kind or verdict)."""

    suite: str
    """The suite it is in: a file, a group of a report."""
    case: str
    """Its name within the suite: a finding code, ``episode 3``, a gate."""
    status: JUnitStatus
    message: str = ""
    """One line saying why it did not pass (a reporter's headline)."""
    details: str = ""
    """More lines: the body of its failure, error or skip, or its output when it passed."""


def _text(value: str) -> str:
    """``value`` shown literally, line by line (the lines of ``details`` stay lines)."""
    return "\n".join(safe(line) for line in value.splitlines())


def _case(parent: ET.Element, case: JUnitCase) -> None:
    element = ET.SubElement(
        parent, "testcase", {"name": safe(case.case), "classname": safe(case.suite)}
    )
    body = _text(case.details) or safe(case.message)
    if case.status == "passed":
        if case.details:
            ET.SubElement(element, "system-out").text = body
        return
    outcome = ET.SubElement(element, _ELEMENT[case.status], {"message": safe(case.message)})
    outcome.text = body


def junit_xml(cases: Iterable[JUnitCase], *, name: str) -> str:
    """``cases`` as a JUnit XML document named ``name`` (e.g. ``episode-audit check``).

    The shape is the one Jenkins' ``junit-10.xsd`` describes (the schema pytest checks its own
    ``--junitxml`` against), which GitLab and GitHub Actions reporters read too.
    """
    suites: dict[str, list[JUnitCase]] = {}
    for case in cases:
        suites.setdefault(case.suite, []).append(case)
    root = ET.Element("testsuites", {"name": safe(name)})
    totals = {"tests": 0, "failures": 0, "errors": 0}
    for suite, members in suites.items():
        counts = {
            "tests": len(members),
            "failures": sum(c.status == "failed" for c in members),
            "errors": sum(c.status == "error" for c in members),
            "skipped": sum(c.status == "skipped" for c in members),
        }
        element = ET.SubElement(
            root, "testsuite", {"name": safe(suite), **{k: str(v) for k, v in counts.items()}}
        )
        for case in members:
            _case(element, case)
        for key in totals:
            totals[key] += counts[key]
    for key, value in totals.items():
        root.set(key, str(value))
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode")
