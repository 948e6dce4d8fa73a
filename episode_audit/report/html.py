"""The report as one self-contained HTML file: tables, inline SVG charts, no script, offline.

:func:`report_html` returns the page, :func:`write_report_html` writes it. Every value from an
evidence file is HTML-escaped (``docs/security.md``); the page's Content-Security-Policy
forbids any script and any load from outside the file. Each episode row carries the exact
``episode-audit replay`` / ``show`` command, shell-quoted (:func:`episode_commands`).
"""

from __future__ import annotations

import html
import os
import shlex
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigurationError
from ..format import names as fmt
from ..record.lock import output_kind
from . import charts
from .collect import ENDED
from .core import DROPPED_TITLE, UNFINISHED_TITLE, FilePart, Report
from .groups import GroupReport
from .incentives import SHAPING_DOMINATES
from .stats import Interval, rate_text

__all__ = [
    "EpisodeRow",
    "check_html_path",
    "episode_commands",
    "episode_rows",
    "report_html",
    "write_report_html",
]

_CSP = "default-src 'none'; style-src 'unsafe-inline'; img-src data:"
_STYLE = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em auto;max-width:75em;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1.5em}td,th{padding:.2em .4em;text-align:left;
border-bottom:1px solid #ddd;vertical-align:top}th{background:#f4f4f4}
td.n{text-align:right;white-space:nowrap}.warn{background:#fff3cd}
.warn-note{color:#8a4b00;font-size:.9em;white-space:normal;max-width:28em}code{font-size:.85em;
white-space:nowrap}figure{margin:.5em 0 1.5em}figure svg{max-width:100%;height:auto}
.wide{overflow-x:auto}td.rate{white-space:normal}td.rate span{white-space:nowrap}
.failure{color:#c62828}.success{color:#2e7d32}.truncated{color:#9a6b00}
h2.unfinished{color:#8a4b00}table.unfinished td{background:#fff3cd}
"""


@dataclass(frozen=True)
class EpisodeRow:
    """One episode (or PettingZoo game) of the report, with its group key."""

    file: str
    episode: int
    seed: int | None
    group: str
    outcome: str
    label: str | None
    """The failure label or the truncation reason."""
    ret: float | None
    length: int
    game: bool = False
    """A PettingZoo game (its index is a game's, not an episode's: no replay command)."""


def episode_commands(row: EpisodeRow) -> list[str]:
    """The ``replay`` and ``show`` commands of ``row``, ready to paste into a POSIX shell.

    >>> row = EpisodeRow("runs/a b.mcap", 3, 7, "x", "failure", "fell", -1.0, 20)
    >>> for command in episode_commands(row):
    ...     print(command)
    episode-audit replay 'runs/a b.mcap' --episode 3
    episode-audit show 'runs/a b.mcap' --episode 3
    """
    if row.game:
        return []
    where = f"{shlex.quote(row.file)} --episode {row.episode}"
    return [f"episode-audit replay {where}", f"episode-audit show {where}"]


def episode_rows(parts: Iterable[FilePart], games: bool = False) -> list[EpisodeRow]:
    """The episodes a report of ``parts`` counts (unstarted ones left out), with group keys.

    From the rows each part took from its file when the report was made (:func:`~.core.file_part`):
    no file is read again. ``games``: the parts count PettingZoo games.
    """
    out: list[EpisodeRow] = []
    for part in parts:
        episodes = part.rows[0]
        if episodes is None:
            continue
        cols = episodes.select(_ROW_COLUMNS).to_pydict().values()
        for episode, seed, key, outcome, label, reason, ret, length in zip(*cols, strict=True):
            failed = outcome == fmt.OUTCOME_FAILURE
            out.append(
                EpisodeRow(
                    part.name, episode, seed, key, outcome, label if failed else reason, ret,
                    length, games,
                )
            )  # fmt: skip
    return out


_ROW_COLUMNS = [
    "episode",
    "seed",
    "key",
    "outcome",
    "failure_label",
    "truncation_reason",
    "return",
    "length",
]
"""The columns of a part's episode rows an :class:`EpisodeRow` is made of, in its order."""


def _full(value: object) -> str:
    """A value from a file as HTML text: control characters as escapes, markup escaped."""
    text = str(value)
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return html.escape(text, quote=True)


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _warning_notes(group: GroupReport, shaping: bool) -> str:
    notes = [w for w in group.warnings if (w.code == SHAPING_DOMINATES) == shaping]
    return "".join(
        f'<div class="warn-note">⚠ {_full(w.code)}: {_full(w.message)}</div>' for w in notes
    )


def _outcome_table(result: Report) -> str:
    head = (
        "<tr><th>group</th><th>episodes</th><th>success (95% CI)</th><th>failure (95% CI)</th>"
        "<th>truncated (95% CI)</th><th>incomplete</th><th>error</th><th>return (mean ± std)"
        "</th><th>length (mean ± std)</th></tr>"
    )
    rows = []
    for g in result.groups:
        warned = _warning_notes(g, shaping=False)
        rows.append(
            f"<tr><td>{_full(g.key)}</td><td class=n>{g.episodes}</td>"
            f"{_rate_cell(g.success, rate_text(g.success_rate, g.success_ci))}"
            f"{_rate_cell(g.failure, rate_text(g.failure_rate, g.failure_ci))}"
            f"{_rate_cell(g.truncated, rate_text(g.truncation_rate, g.truncation_ci))}"
            f"<td class=n>{g.incomplete}</td><td class=n>{g.errors}</td>"
            f'<td class="n{" warn" if warned else ""}">{_num(g.return_mean)} ± '
            f"{_num(g.return_std)}{warned}</td>"
            f"<td class=n>{_num(g.length_mean)} ± {_num(g.length_std)}</td></tr>"
        )
    return _table(f"{head}{''.join(rows)}")


def _rate_cell(count: int, rate: str) -> str:
    """A count and its rate: it may wrap before the rate's interval, never inside either.

    >>> _rate_cell(6, "100.0% [61.0, 100.0]")
    '<td class="n rate"><span>6 (100.0%</span> <span>[61.0, 100.0])</span></td>'
    >>> _rate_cell(1, "-")
    '<td class="n rate"><span>1 (-)</span></td>'
    """
    value, _, interval = rate.partition(" ")
    if not interval:
        return f'<td class="n rate"><span>{count} ({value})</span></td>'
    return f'<td class="n rate"><span>{count} ({value}</span> <span>{interval})</span></td>'


def _table(rows: str, cls: str = "") -> str:
    """A table in a box of the page's width: a table wider than the window scrolls in it."""
    attr = f' class="{cls}"' if cls else ""
    return f'<div class="wide"><table{attr}>{rows}</table></div>'


def _endings_table(result: Report) -> str:
    rows = [
        f"<tr><td>{_full(g.key)}</td><td>{kind}</td><td>{_full(label)}</td>"
        f"<td class=n>{n}</td></tr>"
        for g in result.groups
        for kind, counted in (("failure", g.failures), ("truncated", g.truncations))
        for label, n in sorted(counted.items())
    ]
    if not rows:
        return "<p>No failure or truncation.</p>"
    head = "<tr><th>group</th><th>outcome</th><th>label / reason</th><th>episodes</th></tr>"
    return _table(f"{head}{''.join(rows)}")


def _drawn(groups: Sequence[GroupReport]) -> tuple[Sequence[GroupReport], str]:
    """The groups a chart draws (:data:`~.charts.MAX_CHART_GROUPS`), and a caption if cut."""
    if len(groups) <= charts.MAX_CHART_GROUPS:
        return groups, ""
    return groups[: charts.MAX_CHART_GROUPS], (
        f"<figcaption>The charts draw the first {charts.MAX_CHART_GROUPS} of {len(groups):,} "
        "groups; the tables list every group.</figcaption>"
    )


def _terms_section(result: Report) -> str:
    means = {g.key: g.term_means for g in result.groups if g.term_means}
    if not means:
        return "<p>No reward terms recorded.</p>"
    drawn, caption = _drawn([g for g in result.groups if g.term_means])
    notes = "".join(
        f"<div><b>{_full(g.key)}</b>{_warning_notes(g, shaping=True)}</div>"
        for g in result.groups
        if any(w.code == SHAPING_DOMINATES for w in g.warnings)
    )
    rows = "".join(
        f"<tr><td>{_full(g)}</td><td>{_full(o)}</td><td>{_full(t)}</td><td class=n>{_num(v)}</td>"
        "</tr>"
        for g, by_outcome in means.items()
        for o, terms in by_outcome.items()
        for t, v in terms.items()
    )
    head = "<tr><th>group</th><th>outcome</th><th>term</th><th>mean total per episode</th></tr>"
    return (
        f'<figure class="chart">{charts.term_chart({g.key: means[g.key] for g in drawn})}'
        f"{caption}</figure>{notes}"
        f"{_table(head + rows)}"
    )


def _episode_table(rows: Sequence[EpisodeRow]) -> str:
    head = (
        "<tr><th>file</th><th>episode</th><th>seed</th><th>group</th><th>outcome</th>"
        "<th>label / reason</th><th>return</th><th>length</th><th>commands</th></tr>"
    )
    body = "".join(
        f"<tr><td>{_full(r.file)}</td><td class=n>{r.episode}</td><td class=n>"
        f"{_full(r.seed) if r.seed is not None else '-'}</td><td>{_full(r.group)}</td>"
        f'<td class="{_full(r.outcome)}">{_full(r.outcome)}</td>'
        f"<td>{_full(r.label) if r.label is not None else ''}</td><td class=n>{_num(r.ret)}</td>"
        f"<td class=n>{r.length}</td><td>"
        + "<br>".join(f"<code>{_full(c)}</code>" for c in episode_commands(r))
        + "</td></tr>"
        for r in rows
    )
    return _table(f"{head}{body}")


def _charts(result: Report, rows: Sequence[EpisodeRow]) -> tuple[str, str, str]:
    """The rate chart, the endings chart and the return / length distributions.

    Each draws at most :data:`~.charts.MAX_CHART_GROUPS` groups (its caption says so).
    """
    groups, caption = _drawn(result.groups)
    keys = [g.key for g in groups]

    def triple(rate: float | None, ci: Interval | None) -> tuple[float, float, float] | None:
        return None if rate is None or ci is None else (rate, ci.low, ci.high)

    rates = {
        fmt.OUTCOME_SUCCESS: [triple(g.success_rate, g.success_ci) for g in groups],
        fmt.OUTCOME_FAILURE: [triple(g.failure_rate, g.failure_ci) for g in groups],
        fmt.OUTCOME_TRUNCATED: [triple(g.truncation_rate, g.truncation_ci) for g in groups],
    }
    endings = {
        f"{g.key}": {**{f"failure: {k}": v for k, v in g.failures.items()},
                     **{f"truncated: {k}": v for k, v in g.truncations.items()}}
        for g in groups
    }  # fmt: skip
    returns: dict[tuple[str, str], list[float]] = {}
    lengths: dict[tuple[str, str], list[float]] = {}
    drawn = set(keys)
    for r in rows:
        if r.outcome in ENDED and r.group in drawn:
            if r.ret is not None:
                returns.setdefault((r.group, r.outcome), []).append(r.ret)
            lengths.setdefault((r.group, r.outcome), []).append(r.length)
    has_rates = any(r is not None for values in rates.values() for r in values)  # (by label: none)
    rate_svg = charts.rate_chart(keys, rates) + caption if has_rates else ""
    end_svg = (
        charts.count_chart(endings, "failures and truncations") + caption
        if any(endings.values())
        else ""
    )
    dist = "".join(
        f'<figure class="chart">{charts.distribution_chart(v, what)}{caption}</figure>'
        for v, what in ((returns, "return"), (lengths, "length (steps)"))
        if v
    )
    return rate_svg, end_svg, dist


def _notes(notes: Sequence[str]) -> str:
    """The report's notes, and :attr:`Report.reward_note` (whose returns they are).

    :attr:`Report.notes` says what the report matched nothing of, or left out.
    """
    if not notes:
        return ""
    return '<ul class="notes">' + "".join(f"<li>{_full(n)}</li>" for n in notes) + "</ul>"


def _unfinished(result: Report) -> str:
    """The files still being written or torn, and why: their counts are not final.

    Then the files whose recorder dropped what it could not write, and what.
    """
    return _files(UNFINISHED_TITLE, "why", result.unfinished) + _files(
        DROPPED_TITLE, "what", result.dropped
    )


def _files(title: str, header: str, files: Sequence[tuple[str, str]]) -> str:
    """A highlighted table of files and what is said of each (nothing when there is none)."""
    if not files:
        return ""
    rows = "".join(f"<tr><td>{_full(name)}</td><td>{_full(why)}</td></tr>" for name, why in files)
    return f'<h2 class="unfinished">{_full(title)}</h2>' + _table(
        f"<tr><th>file</th><th>{header}</th></tr>{rows}", "unfinished"
    )


def report_html(result: Report, rows: Sequence[EpisodeRow], *, title: str = "") -> str:
    """The report as one HTML page: charts inline (SVG), no script, nothing loaded from outside.

    ``rows`` are the report's episodes (:func:`episode_rows`), listed with their commands.
    """
    rate_svg, end_svg, dist = _charts(result, rows)
    unit = "games" if result.unit == "game" else "episodes"
    heading = f"episode-audit report (by {_full(result.by)}, {unit})"
    gates = "".join(
        f"<tr><td>{_full(g.gate)}</td><td>{_full(g.group)}</td>"
        f"<td>{'pass' if g.passed else '<b>FAIL</b>'}</td><td>{_full(g.message)}</td></tr>"
        for g in result.gates
    )
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">',
        f"<title>{_full(title or heading)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{heading}</h1>",
        _notes([*result.notes, *filter(None, [result.reward_note])]),
        _unfinished(result),
        "<h2>Outcomes</h2>",
        f'<figure class="chart">{rate_svg}</figure>' if rate_svg else "",
        _outcome_table(result),
        "<h2>Failure labels and truncation reasons</h2>",
        f'<figure class="chart">{end_svg}</figure>' if end_svg else "",
        _endings_table(result),
        "<h2>Reward terms by outcome</h2>",
        _terms_section(result),
        "<h2>Return and length by outcome</h2>",
        dist or "<p>No episode ended.</p>",
    ]
    if gates:
        head = "<tr><th>gate</th><th>group</th><th>result</th><th>detail</th></tr>"
        parts += ["<h2>Gates</h2>", _table(head + gates)]
    parts += ["<h2>Episodes</h2>", _episode_table(rows), "</body></html>"]
    return "\n".join(p for p in parts if p)


def write_report_html(
    result: Report,
    parts: Sequence[FilePart],
    path: str | os.PathLike[str],
    *,
    games: bool = False,
) -> Path:
    """Write the HTML report of ``result`` (made of ``parts``) to ``path``; return the path.

    ``parts`` are the files' parts the report was made of (:attr:`.inputs.InputsReport.parts`,
    or :func:`~.core.file_part` of each file): the page lists their episodes without reading a
    file again. A path :func:`check_html_path` refuses (one of the parts' files, for one) raises
    :class:`~episode_audit.errors.ConfigurationError`, before anything is written: a report
    replaces only an earlier one.
    """
    out = Path(path)
    check_html_path(out, [part.name for part in parts])
    page = report_html(result, episode_rows(parts, games))
    partial = out.with_name(out.name + ".partial")
    try:
        partial.write_text(page, encoding="utf-8")
        os.replace(partial, out)  # a reader never sees half a page
    except OSError:
        partial.unlink(missing_ok=True)
        raise
    return out


def check_html_path(out: Path, inputs: Sequence[str]) -> None:
    """Refuse a report path that is evidence or anything but an HTML report written before.

    Raises :class:`~episode_audit.errors.ConfigurationError` for a path ending in ``.mcap`` or
    naming one of the ``inputs``, one that exists and is not a regular file (a directory, a
    device), or a file that is not an HTML page (a report replaces only an earlier one).
    """
    if out.suffix.lower() == ".mcap" or any(_same(out, name) for name in inputs):
        raise ConfigurationError(
            f"--html: {out} looks like an evidence file; name the report e.g. report.html"
        )
    kind = output_kind(out)
    if kind is not None:
        raise ConfigurationError(
            f"--html: {out} is {kind}, not a regular file; name the report e.g. report.html"
        )
    try:
        with open(out, "rb") as f:
            head = f.read(64).lstrip().lower()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise ConfigurationError(f"--html: cannot read {out}: {exc.strerror or exc}") from None
    if head and not head.startswith((b"<!doctype html", b"<html")):
        raise ConfigurationError(
            f"--html: {out} exists and is not an HTML page; a report replaces only an earlier "
            "report: remove the file or name another"
        )


def _same(out: Path, name: str) -> bool:
    try:
        return out.exists() and out.samefile(name)
    except OSError:
        return False
