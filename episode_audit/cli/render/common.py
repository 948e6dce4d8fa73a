r"""The renderers' shared parts: Rich tables, Markdown tables (CI job summaries) and JSON.

Every string from an evidence file is made safe before display (:func:`safe`,
:func:`markdown_text`, :func:`to_json`; the rules: ``docs/security.md``, "Inject markup"):

>>> safe("[red]x[/red]\x1b[2J")
'[red]x[/red]\\x1b[2J'
>>> safe("::error::x ##[group]")  # no CI workflow command: a word joiner (U+2060) inside
':\u2060:error:\u2060:x ##\u2060[group]'
>>> print(markdown_table(["a", "b"], [["1", "x|y"]]))
| a | b |
| --- | --- |
| 1 | x\|y |
>>> markdown_text("[a](x) <b>|`c`")
'[a\\](x) \\<b\\>\\|\\`c\\`'
>>> markdown_text("https://e.invalid www.e.invalid u@e.invalid")  # no autolink
'https\\://e.invalid www\\.e.invalid u@\u2060e.invalid'
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any, Literal

import numpy as np
from rich import box
from rich.cells import cell_len
from rich.console import Console, ConsoleOptions, RenderableType, RenderResult
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from ...read.inputs import Unreadable

__all__ = [
    "JSON_SCHEMA_VERSION",
    "UNREADABLE_TITLE",
    "WORD_JOINER",
    "FittedTable",
    "Output",
    "OutputFormat",
    "fmt_number",
    "markdown_table",
    "markdown_text",
    "rate",
    "safe",
    "soft_broken",
    "table",
    "to_json",
    "unreadable_json",
    "unreadable_section",
    "versioned",
    "wrapped",
]

OutputFormat = Literal["table", "markdown", "json", "junit"]
Output = RenderableType | str


WORD_JOINER = "\u2060"
"""An invisible character that splits a CI workflow command or an e-mail autolink apart.

Neither GFM nor the GitHub Actions runner (which ``TrimStart()``s a line, then looks for
``::`` at its start and ``##[`` anywhere) treats U+2060 as whitespace, and Rich counts it as
zero cells wide, so the value reads as it was.
"""

_CI_COMMAND = re.compile(r":(?=:)|##(?=[\[A-Za-z])")
"""``::`` (GitHub Actions ``::cmd::``) and ``##[`` / ``##vso[`` / ``##teamcity[`` (GitHub,
Azure Pipelines, TeamCity): a word joiner goes after the first ``:`` / the ``##``."""


def safe(value: Any) -> str:
    """``str(value)`` shown literally: escapes for control characters, no workflow command.

    Control characters are written as escapes (no ANSI, no newlines); a :data:`WORD_JOINER`
    goes inside ``::`` and ``##[``, so no CI runner reads a workflow command in the value.
    """
    text = str(value)
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    if "::" in text or "##" in text:
        text = _CI_COMMAND.sub("\\g<0>" + WORD_JOINER, text)
    return text


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


def table(
    title: str | None,
    headers: Sequence[str],
    rows: Iterable[Sequence[Any]],
    *,
    whole_cells: bool = False,
) -> FittedTable:
    """A Rich table of plain text: title, headers and cells are never parsed as markup.

    It fits the console (:class:`FittedTable`): no header or cell word is broken (one wider
    than the console is broken where it reads on, :func:`soft_broken`), and with
    ``whole_cells`` no cell is wrapped side by side.
    """
    rows = [[safe(cell) for cell in row] for row in rows]
    return FittedTable(title, headers, rows, whole_cells=whole_cells)


class FittedTable:
    """A table that fits its console's width without breaking a word, under its title.

    The title is a line of its own, wrapped at the console's width.
    Side by side when every column can keep its longest word (header included): columns wider
    than that are narrowed first, wrapping at spaces. With ``whole_cells``, side by side only
    when every cell keeps its line (a value such as ``13 (100.0% [77.2, 100.0])`` read in
    pieces over three lines is no table); headers may still wrap. Else one line per (row,
    column): the row's first cell, the column's header and the value (the vertical layout).
    A word of the last column still wider than it is broken where it reads on
    (:func:`soft_broken`); one with nowhere to break is folded.
    """

    def __init__(
        self,
        title: str | None,
        headers: Sequence[str],
        rows: Sequence[Sequence[str]],
        *,
        whole_cells: bool = False,
    ) -> None:
        self.title, self.rows = title, [list(r) for r in rows]
        self.headers = [safe(h) for h in headers]
        self.whole_cells = whole_cells

    def _table(self, headers: Sequence[str], rows: Sequence[Sequence[str]]) -> Table:
        out = Table(
            box=box.SIMPLE_HEAD,
            pad_edge=False,
            collapse_padding=True,  # two spaces between columns, not three
        )
        for header in headers:
            out.add_column(Text(header, style="table.header"), overflow="fold")
        for row in rows:
            out.add_row(*(Text(cell) for cell in row))  # cells and headers: already safe
        return out

    def _vertical_rows(self) -> list[list[str]]:
        """The vertical layout's rows: the row's first cell, a column's header, its value."""
        return [
            [row[0] if i == 0 else "", header, cell]
            for row in self.rows
            for i, (header, cell) in enumerate(zip(self.headers[1:], row[1:], strict=True))
        ]

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        if self.title is not None:  # (a line of its own, wrapped at the console's width: as
            # the table's title it was wrapped at the table's, a narrow one's over lines)
            yield Text(safe(self.title), style="table.title")
        wide = self._table(self.headers, self.rows)
        if _fit(wide, console, options, self.whole_cells):
            yield wide
            return
        headers, rows, fold = self.headers, self.rows, False
        if len(self.headers) >= 3:
            headers, rows, fold = [self.headers[0], "", "value"], self._vertical_rows(), True
        fold &= self.whole_cells
        out = self._table(headers, rows)
        # a first cell too long for its column (a file path, a group name): broken where it
        # reads on, as a value's word is below
        firsts = [row[0] for row in rows]
        first = _first_room(out, console, options, self.whole_cells, firsts, fold_first=fold)
        if first is not None:
            rows = [[soft_broken(row[0], first), *row[1:]] for row in rows]
            out = self._table(headers, rows)
        if not _fit(out, console, options, self.whole_cells, fold_first=fold):
            # a word longer than its column (a long call in a message): broken where it reads on
            width = _last_room(out, console, options, fold_first=fold)
            out = self._table(headers, [[*row[:-1], soft_broken(row[-1], width)] for row in rows])
            _fit(out, console, options, self.whole_cells, fold_first=fold)
        yield out

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        table = Measurement.get(console, options, self._table(self.headers, self.rows))
        if self.title is None:
            return table
        title = Measurement.get(console, options, Text(safe(self.title)))
        return Measurement(max(table.minimum, title.minimum), max(table.maximum, title.maximum))


_FOLDED = 12
"""The narrowest a first column is folded to (``fold_first``)."""


def _fit(
    table: Table,
    console: Console,
    options: ConsoleOptions,
    whole: bool = False,
    *,
    fold_first: bool = False,
) -> bool:
    """Give ``table``'s columns widths that keep every word whole; whether it could.

    ``whole``: every cell but the headers whole. ``fold_first``: the first column (a vertical
    layout's long group name) is folded, down to 12 characters, rather than a value wrapped.
    """
    low, high, room = _measure(table, console, options, whole)
    if sum(high) <= room:
        return True
    if fold_first and sum(low) > room:
        low[0] = min(low[0], max(_FOLDED, room - sum(low[1:])))
        high[0] = max(high[0], low[0])
    if sum(low) > room:
        return False
    spare, want = room - sum(low), [h - lo for h, lo in zip(high, low, strict=True)]
    widths = [lo + spare * w // max(sum(want), 1) for lo, w in zip(low, want, strict=True)]
    widths[want.index(max(want))] += room - sum(widths)
    for column, width in zip(table.columns, widths, strict=True):
        column.width = width
    return True


def _measure(
    table: Table, console: Console, options: ConsoleOptions, whole: bool
) -> tuple[list[int], list[int], int]:
    """Each column's narrowest and natural widths, and the room the columns have.

    The narrowest keeps every word whole (``whole``: every cell but the header); the room is
    ``options``' width less the table's padding.
    """
    free = options.update_width(1 << 20)  # natural widths
    cells = [[col.header, *col.cells] for col in table.columns]
    sizes = [[Measurement.get(console, free, c) for c in col] for col in cells]
    low = [max(m.maximum if whole and i else m.minimum for i, m in enumerate(col)) for col in sizes]
    high = [max(m.maximum for m in col) for col in sizes]
    padding = Measurement.get(console, free, table).maximum - sum(high)
    return low, high, options.max_width - padding


def _first_room(
    table: Table,
    console: Console,
    options: ConsoleOptions,
    whole: bool,
    firsts: Sequence[str],
    *,
    fold_first: bool,
) -> int | None:
    """The width the first column's words (``firsts``) are broken to; ``None``: kept whole.

    Only when the columns cannot all keep their words (``whole``: their cells). The first
    column then gets what the others leave when they keep theirs, but no more than its widest
    piece between two break points (the others get the rest) and no less than 12 characters.
    Without ``fold_first`` it may take more to keep those pieces whole, as long as the last
    column keeps its longest word or half the room.
    """
    low, _, room = _measure(table, console, options, whole)
    if sum(low) <= room:
        return None
    widest = max(_FOLDED, *(_widest_piece(text) for text in firsts))
    width = room - sum(low[1:])
    if not fold_first:
        width = max(width, min(widest, room - sum(low[1:-1]) - min(low[-1], room // 2)))
    return min(max(width, _FOLDED), widest)


def _last_room(table: Table, console: Console, options: ConsoleOptions, *, fold_first: bool) -> int:
    """The width the last column has when the others keep their words (the first folded)."""
    low, _, room = _measure(table, console, options, False)
    if fold_first:
        low[0] = min(low[0], _FOLDED)
    return room - sum(low[:-1])


_SOFT_BREAK = re.compile(r"[=(,/:;](?=[^\s=(,/:;])|\.(?=[A-Za-z_])")
"""Where a word too long for its column is broken: after ``=``, ``(``, ``,``, ``/``, ``:`` or
``;`` followed by more of it (``ending_rules=EndingRules(`` / ``success_fn=...)``), and after a
``.`` followed by a letter (``gymnasium.envs.`` / ``classic_control``, ``run.`` / ``mcap``;
not a number's)."""


_WEAK_BREAK = re.compile(r"(?<=[^\W_])[-_](?=[^\W_])|(?<=[a-z])(?=[A-Z])")
"""Where a word too long for its column is broken when no :data:`_SOFT_BREAK` point fits: after
a ``-`` or ``_`` between two letters or digits (``cartpole-evaluation-`` / ``runs``), or between
a small and a capital letter (``EvaluationOfCartPole`` / ``Agent``)."""


def soft_broken(text: str, width: int) -> str:
    """``text`` with each word wider than ``width`` broken onto lines at :data:`_SOFT_BREAK`.

    A line ends at the last such point that fits, else at the last :data:`_WEAK_BREAK` point
    that fits; where none fits, the word is cut at ``width``, and the rest of it is broken the
    same way: no character is left out (two file names that differ in the middle still read
    apart). The text still wraps at spaces.

    >>> print(soft_broken("record with ending_rules=EndingRules(success_fn=...) or x", 30))
    record with ending_rules=EndingRules(
    success_fn=...) or x
    >>> print(soft_broken("runs/2026-11-29/counting-environment-run.mcap", 20))
    runs/2026-11-29/
    counting-
    environment-run.mcap
    >>> print(soft_broken("cartpole-evaluation-runs-november29/a.mcap", 33))
    cartpole-evaluation-runs-
    november29/a.mcap
    >>> print(soft_broken("EvaluationOfCartPoleAgentTrainedWithPPO.mcap", 24))
    EvaluationOfCartPole
    AgentTrainedWithPPO.mcap
    """
    if width < 1:
        return text
    pieces = re.split(r"(\s+)", text)
    for i, word in enumerate(pieces):
        lines = []
        while cell_len(word) > width:
            fits = _fitting(word, width)
            cut = _last_break(_SOFT_BREAK, word, fits) or _last_break(_WEAK_BREAK, word, fits)
            cut = cut or fits
            lines.append(word[:cut])
            word = word[cut:]
        pieces[i] = "\n".join([*lines, word])
    return "".join(pieces)


def wrapped(text: str, width: int | None, whole: Iterable[str] = ()) -> str:
    r"""``text``'s lines wrapped at spaces to ``width`` cells, each next line indented two.

    Words are never broken, nor is any of ``whole`` (paths: ``a run.mcap`` is one word). A
    line with a word no line holds (a long path) stays one line, as is a line that starts
    indented (a command to copy). ``None``: as it was.

    >>> print(wrapped("episode-audit: note: a.mcap is unfinished: exported what it holds", 36))
    episode-audit: note: a.mcap is
      unfinished: exported what it holds
    >>> print(wrapped("error: runs/a-very-long-folder/run.mcap: no such file", 24))
    error: runs/a-very-long-folder/run.mcap: no such file
    >>> print(wrapped("open it in Foxglove; a layout for it:\n  python -m layout run.mcap", 20))
    open it in Foxglove;
      a layout for it:
      python -m layout run.mcap
    >>> print(wrapped("wrote 5 steps to ev/a run.rrd", 20, whole=["ev/a run.rrd"]))
    wrote 5 steps to
      ev/a run.rrd
    """
    if width is None:
        return text
    held = sorted({part for part in whole if " " in part}, key=len, reverse=True)
    if _HELD_SPACE in text:  # (a space of ``whole``'s could not be told from this one)
        held = []
    for part in held:
        text = text.replace(part, part.replace(" ", _HELD_SPACE))
    lines = "\n".join(_wrapped_line(line, width) for line in text.split("\n"))
    return lines.replace(_HELD_SPACE, " ")


_HELD_SPACE = "\ue000"
"""A space of :func:`wrapped`'s ``whole`` while it wraps: no whitespace, one cell (private use)."""


def _wrapped_line(line: str, width: int) -> str:
    """One line of text as :func:`wrapped` makes it."""
    indent, words = "  ", line.split()
    if line[:1].isspace() or any(cell_len(indent + word) > width for word in words):
        return line
    lines = [""]
    for word in words:
        joined = f"{lines[-1]} {word}" if lines[-1].strip() else lines[-1] + word
        if cell_len(joined) <= width:
            lines[-1] = joined
        else:
            lines.append(indent + word)
    return "\n".join(lines)


def _last_break(points: re.Pattern[str], word: str, fits: int) -> int:
    """The last point of ``points`` in ``word`` within its first ``fits`` characters, else 0."""
    ends = (m.end() for m in points.finditer(word, 0, fits + 1))
    return max((end for end in ends if end <= fits), default=0)


def _widest_piece(text: str) -> int:
    """The widest piece of ``text`` that no space or :data:`_SOFT_BREAK` point divides.

    >>> _widest_piece("runs/2026-11-29/counting-environment-run.mcap")
    25
    """
    widest = 0
    for word in text.split():
        start = 0
        for end in [*(m.end() for m in _SOFT_BREAK.finditer(word)), len(word)]:
            widest = max(widest, cell_len(word[start:end]))
            start = end
    return widest


def _fitting(word: str, width: int) -> int:
    """How many characters of ``word`` fit in ``width`` cells (at least one)."""
    cells = 0
    for n, char in enumerate(word):
        cells += cell_len(char)
        if cells > width:
            return max(n, 1)
    return len(word)


_MARKDOWN_ESCAPES = str.maketrans({c: "\\" + c for c in "\\|`<>&*~"})

_EMPHASIS_UNDERSCORE = re.compile(r"(?<![^\W_])_|_(?![^\W_])")
"""A ``_`` that could open or close emphasis: one not between two letters or digits
(``time_limit`` stays as it is, ``__main__`` is escaped)."""

_AUTOLINK = re.compile(r"(?=://)|(?i:(?<=www)(?=\.))")
"""Where GFM's extended autolinks of URLs start (``http://``, ``https://``, ``ftp://``,
``www.``): a backslash goes before ``://`` and before ``www``'s ``.``. An e-mail autolink
(also ``mailto:`` and ``xmpp:``) needs an ``@``, which a backslash does not hide from GFM:
a word joiner goes after it."""


def markdown_text(value: Any) -> str:
    """``safe(value)`` for Markdown: one line, shown literally.

    No link (autolinks included), code span, emphasis or HTML (docs/security.md, rule 3).
    """
    text = safe(value).translate(_MARKDOWN_ESCAPES)
    if "_" in text:
        text = _EMPHASIS_UNDERSCORE.sub("\\\\_", text)
    if "]" in text:
        text = text.replace("](", "\\](").replace("][", "\\][")
    if "://" in text or "www." in text.lower():
        text = _AUTOLINK.sub("\\\\", text)
    return text.replace("@", "@" + WORD_JOINER) if "@" in text else text


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
    r"""Stable, indented JSON (keys in insertion order, non-finite floats as strings).

    A ``##`` that could start a CI workflow command is followed by a ``\u`` escape (the
    same value once parsed); every line starts with indentation and a JSON token, never ``::``.

    >>> print(to_json({"label": "##[error]x"}))
    {
      "label": "##\u005berror]x"
    }
    """
    from ...format.records import to_jsonable

    text = json.dumps(to_jsonable(data), indent=2, allow_nan=False)
    if "##" not in text:
        return text
    return _JSON_CI_COMMAND.sub(lambda m: f"##\\u{ord(m.group(1)):04x}", text)


_JSON_CI_COMMAND = re.compile(r"##([\[A-Za-z])")


UNREADABLE_TITLE = "Unreadable files (not counted)"
"""The title of the table of the inputs a command could not read (terminal and Markdown)."""


def unreadable_section(
    unreadable: Iterable[Unreadable],
) -> tuple[str, list[str], list[list[str]]]:
    """The table of the inputs a command could not read, as (title, headers, rows)."""
    return (UNREADABLE_TITLE, ["file", "why"], [[u.file, u.why] for u in unreadable])


def unreadable_json(unreadable: Iterable[Unreadable]) -> list[dict[str, str]]:
    """``[{"file", "why"}]``: the inputs a command could not read (each also named on stderr)."""
    return [{"file": u.file, "why": u.why} for u in unreadable]


JSON_SCHEMA_VERSION = 1
"""The version of the JSON outputs' shapes (``docs/schemas/<command>.json``): a key removed or
changed in meaning raises it; a key added does not."""


def versioned(command: str, data: dict[str, Any]) -> dict[str, Any]:
    """A command's JSON output: ``data`` after ``command`` and ``schema_version``.

    >>> versioned("check", {"ok": True})
    {'command': 'check', 'schema_version': 1, 'ok': True}
    """
    return {"command": command, "schema_version": JSON_SCHEMA_VERSION, **data}
