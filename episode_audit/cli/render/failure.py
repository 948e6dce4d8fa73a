"""The JSON or JUnit document of a command that could not do its work (exit 2)."""

from __future__ import annotations

from collections.abc import Sequence

from ...read.inputs import Unreadable
from .common import Output, OutputFormat, to_json, unreadable_json, versioned
from .junit import JUnitCase, junit_xml

__all__ = ["error_output"]


def error_output(
    command: str, message: str, output: OutputFormat, unreadable: Sequence[Unreadable] = ()
) -> Output:
    """The document of ``command`` failing with ``message``, so a CI job that saves it has one.

    JSON ``{"command", "schema_version", "error", "unreadable"}`` (the second ``anyOf`` branch
    of ``docs/schemas/<command>.json``); JUnit an error case named for the command beside one
    per input that could not be read.

    >>> print(error_output("check", "nope: no such file or directory", "json"))
    {
      "command": "check",
      "schema_version": 1,
      "error": "nope: no such file or directory",
      "unreadable": []
    }
    """
    if output == "json":
        data = {"error": message, "unreadable": unreadable_json(unreadable)}
        return to_json(versioned(command, data))
    cases = [JUnitCase(u.file, "read", "error", u.why) for u in unreadable]
    cases.append(JUnitCase(f"episode-audit {command}", command, "error", message))
    return junit_xml(cases, name=f"episode-audit {command}")
