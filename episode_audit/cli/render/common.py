r"""The renderers' shared parts: Rich tables, Markdown tables (CI job summaries) and JSON.

Every string from an evidence file is made safe before display (:func:`safe`,
:func:`markdown_text`; the rules: ``docs/security.md``, "Inject markup"):

>>> safe("[red]x[/red]\x1b[2J")
'[red]x[/red]\\x1b[2J'
>>> print(markdown_table(["a", "b"], [["1", "x|y"]]))
| a | b |
| --- | --- |
| 1 | x\|y |
>>> markdown_text("[a](x) <b>|`c`")
'[a\\](x) \\<b\\>\\|\\`c\\`'
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any, Literal

import numpy as np
from rich import box
from rich.console import RenderableType
from rich.table import Table
from rich.text import Text

from ...read.inputs import Unreadable

__all__ = [
    "Output",
    "OutputFormat",
    "fmt_number",
    "markdown_table",
    "markdown_text",
    "rate",
    "safe",
    "table",
    "to_json",
    "unreadable_json",
]

OutputFormat = Literal["table", "markdown", "json"]
Output = RenderableType | str


def safe(value: Any) -> str:
    """``str(value)`` with control characters written as escapes (no ANSI, no newlines)."""
    text = str(value)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def fmt_number(value: float | None, digits: int = 3) -> str:
    """A compact number for tables (``-`` for missing).

    ``digits`` significant digits, whole numbers in full up to a million (a MuJoCo return reads
    ``4824``, not ``4.82e+03``); ``nan`` for a NaN (not missing: a value that is not a number).

    >>> [fmt_number(x) for x in (None, math.nan, 4823.7, 1000.0, 12.345, -0.05291, 2.5e7, 7)]
    ['-', 'nan', '4824', '1000', '12.3', '-0.0529', '2.500e+07', '7']
    """
    if value is None:
        return "-"
    if isinstance(value, (int, np.integer)):
        return str(value)
    if not math.isfinite(value):
        return str(float(value))  # nan, inf, -inf
    size = abs(value)
    if size >= 1e6:
        return f"{value:.3e}"
    if size >= 10**digits:
        return f"{value:.0f}"
    return f"{value:.{digits}g}"


def rate(value: float | None) -> str:
    """A rate as a percentage (``-`` for missing).

    >>> rate(0.125), rate(None)
    ('12.5%', '-')
    """
    return "-" if value is None else f"{value:.1%}"


def table(title: str | None, headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> Table:
    """A Rich table of plain text: title, headers and cells are never parsed as markup."""
    out = Table(
        title=None if title is None else Text(safe(title), style="table.title"),
        box=box.SIMPLE_HEAD,
        title_justify="left",
        pad_edge=False,
    )
    for header in headers:
        out.add_column(Text(safe(header), style="table.header"), overflow="fold")
    for row in rows:
        out.add_row(*(Text(safe(cell)) for cell in row))
    return out


_MARKDOWN_ESCAPES = str.maketrans({c: "\\" + c for c in "\\|`<>&"})


def markdown_text(value: Any) -> str:
    """``safe(value)`` for Markdown: one line, shown literally (no link, code span or HTML)."""
    text = safe(value).translate(_MARKDOWN_ESCAPES)
    return text.replace("](", "\\](").replace("][", "\\][") if "]" in text else text


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table (cells escaped), pasteable into a CI job summary."""
    cell = markdown_text

    lines = [
        "| " + " | ".join(cell(h) for h in headers) + " |",
        "| " + " | ".join("---" for _ in headers) + " |",
    ]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def to_json(data: Any) -> str:
    """Stable, indented JSON (keys in insertion order, non-finite floats as strings)."""
    from ...format.records import to_jsonable

    return json.dumps(to_jsonable(data), indent=2, allow_nan=False)


def unreadable_json(unreadable: Iterable[Unreadable]) -> list[dict[str, str]]:
    """``[{"file", "why"}]``: the inputs a command could not read (each also named on stderr)."""
    return [{"file": u.file, "why": u.why} for u in unreadable]
