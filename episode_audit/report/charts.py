"""The HTML report's charts: matplotlib figures rendered to SVG text (no pyplot, no JS).

:func:`rate_chart` (rates with 95 % intervals as whiskers), :func:`count_chart` (failure labels
and truncation reasons), :func:`term_chart` (reward-term totals by outcome) and
:func:`distribution_chart` (returns or lengths by outcome). Labels come from evidence files:
:func:`chart_text` shows them literally (no mathtext, no control characters); matplotlib's SVG
writer escapes them for XML. matplotlib is the optional ``html`` extra.
"""

from __future__ import annotations

import inspect
import io
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from ..errors import ConfigurationError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "MAX_CHART_GROUPS",
    "MAX_DOTS",
    "chart_text",
    "count_chart",
    "distribution_chart",
    "dots",
    "rate_chart",
    "term_chart",
]

MAX_CHART_GROUPS = 30
"""The most groups a chart draws: a row is ~0.3 inch and a few ms of matplotlib per mark, so
2 000 groups (a campaign by file) would be a chart 600 inches tall taking minutes to draw.
The page's tables list every group."""
MAX_DOTS = 200
"""The most episodes a distribution row draws as dots (the box is of them all)."""
OUTCOME_COLOURS = {"success": "#2e7d32", "failure": "#c62828", "truncated": "#f9a825"}
_MAX_LABEL = 40
_MISSING_GLYPH = r"Glyph \d+ .* missing from (current )?font"
"""matplotlib's warning on a character its fonts lack (the SVG still holds it as text): "missing
from font(s) ..." in matplotlib 3.9 and later, "missing from current font." before."""
_RC: dict[Any, Any] = {
    "svg.fonttype": "none",  # text as <text>, escaped by matplotlib's XML writer
    "svg.hashsalt": "episode-audit",  # the same ids for the same report
    "text.parse_math": False,  # a label "$x$" is shown as written
    "font.size": 9,
}


def chart_text(value: object) -> str:
    r"""A label as a chart shows it: control characters escaped, at most 40 characters.

    A longer one keeps its start and its end (a file path's name):

    >>> chart_text("a\x1b[2Jb"), chart_text("/runs/" + "x" * 50 + "/hacker.mcap")
    ('a\\x1b[2Jb', '/runs/xxxxxxxxx…xxxxxxxxxxxx/hacker.mcap')
    """
    text = str(value)
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    if len(text) <= _MAX_LABEL:
        return text
    head = (_MAX_LABEL - 1) * 2 // 5
    return text[:head] + "…" + text[-(_MAX_LABEL - 1 - head) :]


def _figure(rows: int, width: float = 9.0) -> Figure:
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ConfigurationError(
            "the HTML report draws its charts with matplotlib, which is not installed: "
            "pip install 'episode-audit[html]'"
        ) from None
    return Figure(figsize=(width, 1.0 + 0.32 * max(rows, 1)), layout="constrained")


def _svg(fig: Figure) -> str:
    """The figure as SVG text without the XML declaration and DOCTYPE (inline in HTML)."""
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context(_RC), warnings.catch_warnings():
        # text is written as <text> (svg.fonttype "none"): the browser draws a glyph matplotlib's
        # font lacks (an emoji in a file name), only matplotlib's measuring of it warns
        warnings.filterwarnings("ignore", _MISSING_GLYPH, UserWarning)
        # no <metadata> block: no date (the same report, the same page), no RDF namespaces
        fig.savefig(
            buf, format="svg", metadata=dict.fromkeys(("Date", "Creator", "Format", "Type"))
        )
    text = buf.getvalue()
    return text[text.index("<svg") :]


def _with_rc(draw: Any) -> Any:
    """Run ``draw`` (which builds a figure) under the charts' rc settings."""
    import matplotlib

    with matplotlib.rc_context(_RC):
        return draw()


def rate_chart(
    groups: Sequence[str], rates: Mapping[str, Sequence[tuple[float, float, float] | None]]
) -> str:
    """Horizontal bars of each outcome's rate per group, whiskers at its 95 % interval.

    ``rates[outcome][i]`` is ``(rate, low, high)`` of ``groups[i]``, or ``None`` (no episode
    ended).
    """

    def draw() -> Figure:
        fig = _figure(len(groups) * len(rates))
        ax = fig.add_subplot()
        height = 0.8 / max(len(rates), 1)
        for k, (outcome, values) in enumerate(rates.items()):
            ys = [i + k * height for i, v in enumerate(values) if v is not None]
            known = [v for v in values if v is not None]
            ax.barh(
                ys,
                [v[0] for v in known],
                height=height,
                xerr=[[v[0] - v[1] for v in known], [v[2] - v[0] for v in known]],
                capsize=3,
                color=OUTCOME_COLOURS.get(outcome, "#607d8b"),
                label=outcome,
            )
        ax.set_yticks([i + height * (len(rates) - 1) / 2 for i in range(len(groups))])
        ax.set_yticklabels([chart_text(g) for g in groups])
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_xlabel("rate of ended episodes (bars), 95% Wilson interval (whiskers)")
        fig.legend(loc="outside right upper", fontsize=8)
        return fig

    return _svg(_with_rc(draw))


def count_chart(counts: Mapping[str, Mapping[str, int]], what: str) -> str:
    """Horizontal bars: how many episodes of each group ended with each label or reason."""
    rows = [(group, label, n) for group, c in counts.items() for label, n in sorted(c.items())]

    def draw() -> Figure:
        fig = _figure(len(rows))
        ax = fig.add_subplot()
        ax.barh(range(len(rows)), [n for _, _, n in rows], color="#546e7a")
        ax.set_yticks(range(len(rows)))
        ax.set_yticklabels([f"{chart_text(g)} · {chart_text(label)}" for g, label, _ in rows])
        ax.invert_yaxis()
        ax.set_xlabel(f"episodes ({what})")
        return fig

    return _svg(_with_rc(draw))


def term_chart(term_means: Mapping[str, Mapping[str, Mapping[str, float]]]) -> str:
    """Bars of each reward term's mean episode total, per group and outcome.

    ``term_means[group][outcome][term]``: where each outcome's return comes from.
    """
    rows = [(g, o) for g, by_outcome in term_means.items() for o in by_outcome]
    terms = sorted(
        {t for by_outcome in term_means.values() for v in by_outcome.values() for t in v}
    )

    def draw() -> Figure:
        fig = _figure(len(rows) * max(len(terms), 1) // 2 + len(rows))
        ax = fig.add_subplot()
        height = 0.8 / max(len(terms), 1)
        for k, term in enumerate(terms):
            values = [term_means[g][o].get(term, 0.0) for g, o in rows]
            ax.barh([i + k * height for i in range(len(rows))], values, height=height, label=term)
        ax.set_yticks([i + height * (len(terms) - 1) / 2 for i in range(len(rows))])
        ax.set_yticklabels([f"{chart_text(g)} · {chart_text(o)}" for g, o in rows])
        ax.invert_yaxis()
        ax.axvline(0, color="black", linewidth=0.8)
        ax.set_xlabel("mean total per episode")
        handles, labels = ax.get_legend_handles_labels()
        fig.legend(handles, [chart_text(t) for t in labels], loc="outside right upper", fontsize=8)
        return fig

    return _svg(_with_rc(draw))


def _horizontal(ax: Any) -> dict[str, Any]:
    """``boxplot``'s argument for horizontal boxes: ``orientation`` since matplotlib 3.10."""
    if "orientation" in inspect.signature(ax.boxplot).parameters:
        return {"orientation": "horizontal"}
    return {"vert": False}  # (matplotlib 3.8 and 3.9; deprecated by 3.10)


def dots(values: Sequence[float], most: int = MAX_DOTS) -> list[float]:
    """The values a distribution row draws as dots: all, or ``most`` of them at even ranks.

    The smallest and the largest are always among them:

    >>> dots([5.0, 1.0, 3.0]), dots([float(v) for v in range(10)], most=4)
    ([5.0, 1.0, 3.0], [0.0, 3.0, 6.0, 9.0])
    """
    if len(values) <= most:
        return list(values)
    ordered = sorted(values)
    step = (len(ordered) - 1) / (most - 1)
    return [ordered[round(i * step)] for i in range(most)]


def distribution_chart(values: Mapping[tuple[str, str], Sequence[float]], what: str) -> str:
    """Box plots with the episodes as dots (:func:`dots`), one row per (group, outcome)."""
    keys = [k for k in values if len(values[k])]

    def draw() -> Figure:
        fig = _figure(len(keys))
        ax = fig.add_subplot()
        data = [list(values[k]) for k in keys]
        ax.boxplot(data, **_horizontal(ax), widths=0.6, showfliers=False)
        for i, (k, points) in enumerate(zip(keys, data, strict=True)):
            colour = OUTCOME_COLOURS.get(k[1], "#607d8b")
            shown = dots(points)
            ax.scatter(shown, [i + 1] * len(shown), s=10, color=colour, alpha=0.6, zorder=3)
        ax.set_yticks(range(1, len(keys) + 1))
        ax.set_yticklabels([f"{chart_text(g)} · {chart_text(o)}" for g, o in keys])
        ax.invert_yaxis()
        ax.set_xlabel(what)
        return fig

    return _svg(_with_rc(draw))
