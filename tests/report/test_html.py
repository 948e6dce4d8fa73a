from __future__ import annotations

import html
import html.parser
import re
import warnings
from pathlib import Path

import pytest

from episode_audit import ConfigurationError
from episode_audit.report import charts, report_inputs
from episode_audit.report.core import BY_LABEL_NOTE
from episode_audit.report.html import EpisodeRow, episode_commands, write_report_html
from tests.report.test_report import Plan, _record_plans
from tests.support.chromium import open_page

pytest.importorskip("matplotlib")

EVIL = (
    "</svg><script>alert(1)</script><img src=http://e.invalid/x onerror=alert(2)>$x^2$ --> \x1b[2J"
)
"""A failure label, tag and term name that try HTML, SVG, mathtext, a comment end and ANSI."""

CHECKS = """({
  charts: [...document.querySelectorAll("figure svg")].map(
    s => [s.getBBox().width, s.getBBox().height, s.querySelectorAll("path, text").length]),
  scripts: document.scripts.length,
  imgs: document.images.length,
  remote: [...document.querySelectorAll("[src], [href]")].map(
    e => e.getAttribute("src") || e.getAttribute("href")).filter(u => !u.startsWith("#")),
  text: document.body.innerText,
})"""


class _Tags(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))


def _evidence(tmp_path: Path) -> Path:
    plans = [
        Plan("success", terms={"progress": 1.0, EVIL: 0.5}),
        Plan(f"failure:{EVIL}", terms={"progress": 3.0, EVIL: 0.5}),
        Plan("truncated:time_limit", terms={"progress": 0.1, EVIL: 0.0}),
        Plan("failure:fell", reward=2.0, terms={"progress": 2.0, EVIL: 0.0}),
    ]
    return _record_plans(tmp_path / "run one.mcap", plans, tags={"policy": EVIL})


def _page(tmp_path: Path, by: str = "tag:policy") -> tuple[Path, str]:
    path = _evidence(tmp_path)
    result = report_inputs([path], by=by)
    out = write_report_html(result.report, result.parts, tmp_path / "report.html")
    return out, out.read_text(encoding="utf-8")


def test_html_report_escapes_every_value_from_the_file(tmp_path: Path) -> None:
    _, page = _page(tmp_path)
    parser = _Tags()
    parser.feed(page)
    tags = [tag for tag, _ in parser.tags]
    assert "script" not in tags and "img" not in tags
    assert not any(k.startswith("on") for _, attrs in parser.tags for k in attrs)
    assert "&lt;/svg&gt;&lt;script&gt;" in page  # shown, as text
    assert "\x1b" not in page and "\\x1b[2J" in page
    assert tags.count("svg") == 5  # rates, endings, terms, returns, lengths


def test_html_report_has_no_network_reference(tmp_path: Path) -> None:
    _, page = _page(tmp_path)
    parser = _Tags()
    parser.feed(page)
    for tag, attrs in parser.tags:
        for name in ("src", "href"):
            assert not (attrs.get(name) or "").startswith(("http", "//")), (tag, attrs)
    assert "default-src 'none'" in page  # the page's CSP: no load from outside, no script
    assert "<!DOCTYPE svg" not in page


def test_html_report_rates_and_intervals_share_their_unit(tmp_path: Path) -> None:
    _, page = _page(tmp_path, by="all")
    assert "<span>1 (25.0%</span> <span>[4.6, 69.9])</span></td>" in page  # 1 of 4 ended
    assert not re.search(r"\[[01]\.\d\d, ", page)


def test_html_report_lists_each_episode_with_its_commands(tmp_path: Path) -> None:
    _, page = _page(tmp_path)
    path = tmp_path / "run one.mcap"
    for episode in range(4):
        assert f"episode-audit replay &#x27;{path}&#x27; --episode {episode}</code>" in page
        assert f"episode-audit show &#x27;{path}&#x27; --episode {episode}</code>" in page


def test_episode_commands_are_shell_quoted() -> None:
    row = EpisodeRow("a b;rm -rf x.mcap", 2, None, "g", "failure", None, 1.0, 3)
    assert episode_commands(row) == [
        "episode-audit replay 'a b;rm -rf x.mcap' --episode 2",
        "episode-audit show 'a b;rm -rf x.mcap' --episode 2",
    ]
    assert episode_commands(EpisodeRow("g.mcap", 0, 1, "g", "success", None, 1.0, 3, True)) == []


def test_html_report_puts_each_warning_next_to_its_numbers(tmp_path: Path) -> None:
    # fell earns more than the success: failure_outearns_success, by the return column
    _, page = _page(tmp_path, by="all")
    assert re.search(r'<td class="n warn">[^<]*<div class="warn-note">⚠ failure_outearns', page)


def test_a_shaping_warning_sits_in_no_paragraph(tmp_path: Path) -> None:
    # its <div> was inside a <p>: invalid HTML (a parser closes the <p> before the <div>)
    terms = {"alive": 1.0, "progress": 0.1}
    plans = [Plan("success", reward=1.1, terms=terms)] + [
        Plan("failure:fell", reward=1.1, terms=terms, length=2)
    ] * 3
    result = report_inputs([_record_plans(tmp_path / "shaped.mcap", plans)])
    page = write_report_html(result.report, result.parts, tmp_path / "r.html").read_text("utf-8")
    assert '<div class="warn-note">⚠ shaping_dominates' in page
    assert not re.search(r"<p>(?:(?!</p>).)*<div", page, re.DOTALL)


def test_html_report_by_label_draws_no_rate_chart_and_warns_of_nothing(tmp_path: Path) -> None:
    # each label group holds one outcome: its rates were bars at 0 and 100 % by construction
    (tmp_path / "label").mkdir(), (tmp_path / "all").mkdir()
    _, page = _page(tmp_path / "label", by="label")
    _, by_all = _page(tmp_path / "all", by="all")
    assert "rate of ended episodes" not in page and "rate of ended episodes" in by_all
    assert 'class="warn-note"' not in page and 'class="warn-note"' in by_all
    assert '<td class="n rate"><span>1 (-)</span></td>' in page  # (the counts stay; no rate)
    assert f'<ul class="notes"><li>{html.escape(BY_LABEL_NOTE)}</li></ul>' in page  # (why)
    assert '<ul class="notes">' not in by_all


@pytest.mark.parametrize("name", ["report.mcap", "run one.mcap"])
def test_html_report_never_overwrites_evidence(tmp_path: Path, name: str) -> None:
    path = _evidence(tmp_path)
    before = path.read_bytes()
    result = report_inputs([path])
    with pytest.raises(ConfigurationError, match="looks like an evidence file"):
        write_report_html(result.report, result.parts, tmp_path / name)
    assert path.read_bytes() == before


def test_html_report_replaces_only_an_earlier_report(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from episode_audit.cli import app

    path = _evidence(tmp_path)
    backup = tmp_path / "evidence.backup"
    backup.write_bytes(path.read_bytes())
    refused = CliRunner().invoke(app, ["report", str(path), "--html", str(backup)])
    assert refused.exit_code == 2 and refused.stdout == ""  # refused before the report
    assert "exists and is not an HTML page" in refused.stderr
    assert backup.read_bytes() == path.read_bytes()
    device = CliRunner().invoke(app, ["report", str(path), "--html", "/dev/null"])
    assert device.exit_code == 2 and "is a character device" in device.stderr
    out = tmp_path / "r.html"
    for _ in range(2):  # the second run replaces the first's page
        assert CliRunner().invoke(app, ["report", str(path), "--html", str(out)]).exit_code == 0


def test_html_report_renders_in_headless_chromium(tmp_path: Path) -> None:
    page, _ = _page(tmp_path)
    shot = tmp_path / "report.png"
    result = open_page(page, CHECKS, shot)
    assert result.errors == []
    value = result.value
    assert len(value["charts"]) == 5
    for width, height, marks in value["charts"]:
        assert width > 100 and height > 50 and marks > 10
    assert value["scripts"] == 0 and value["imgs"] == 0 and value["remote"] == []
    assert "</svg><script>alert(1)</script>" in value["text"]  # shown as text
    assert shot.stat().st_size > 10_000
    print(f"screenshot: {shot}")


WIDTHS = """(() => {
  const h = [...document.querySelectorAll("h2")].find(h => h.textContent === "Outcomes");
  let e = h.nextElementSibling;
  while (!e.matches("table") && !e.querySelector("table")) e = e.nextElementSibling;
  const table = e.matches("table") ? e : e.querySelector("table");
  return {page: document.documentElement.scrollWidth, view: window.innerWidth,
          outcomes: table.offsetWidth, room: table.parentElement.clientWidth};
})()"""


def test_html_report_fits_the_window_its_outcomes_table_whole(tmp_path: Path) -> None:
    """At 1200 px the page does not scroll sideways and the Outcomes table fits (its last
    column shown); in a narrow window a table too wide scrolls in its own box, not the page."""
    plans = [Plan("failure:door_slammed", reward=7.0, terms={"progress_velocity": 7.0})] * 6
    hacker = _record_plans(tmp_path / "hacker.mcap", plans, tags={"policy": "hacker"})
    plans = [Plan("success", length=5, terms={"progress_velocity": 1.0})] * 5
    plans.append(Plan("truncated:time_limit", length=9, reward=0.0))
    scripted = _record_plans(tmp_path / "scripted.mcap", plans, tags={"policy": "scripted"})
    result = report_inputs([hacker, scripted], by="tag:policy")
    page = write_report_html(result.report, result.parts, tmp_path / "report.html")
    assert "no_success_positive_return" in page.read_text(encoding="utf-8")
    wide = open_page(page, WIDTHS, width=1200)
    assert wide.errors == []
    assert wide.value["page"] <= wide.value["view"] == 1200, wide.value
    assert wide.value["outcomes"] <= wide.value["room"], wide.value
    narrow = open_page(page, WIDTHS, width=480)
    assert narrow.value["page"] <= narrow.value["view"] == 480, narrow.value


def test_report_command_writes_html_beside_its_table(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from episode_audit.cli import app

    path = _evidence(tmp_path)
    out = tmp_path / "r.html"
    result = CliRunner().invoke(app, ["report", str(path), "--by", "all", "--html", str(out)])
    assert result.exit_code == 0, result.output
    assert "Outcomes (by all)" in result.stdout
    assert f"note: HTML report written to {out}" in result.stderr
    assert "<svg" in out.read_text(encoding="utf-8")
    bad = CliRunner().invoke(app, ["report", str(path), "--html", str(path)])
    assert bad.exit_code == 2
    assert bad.stderr.count("\n") == 1 and "looks like an evidence file" in bad.stderr
    nowhere = tmp_path / "no" / "r.html"
    missing = CliRunner().invoke(app, ["report", str(path), "--html", str(nowhere)])
    assert missing.exit_code == 2, missing.output
    assert (
        missing.stderr
        == f"episode-audit: error: --html: cannot write {nowhere}: No such file or directory\n"
    )
    assert not nowhere.parent.exists()


@pytest.mark.parametrize("games", [False, True])
def test_html_report_of_pettingzoo_games_and_agents(tmp_path: Path, games: bool) -> None:
    rps = pytest.importorskip("pettingzoo.classic.rps_v2")
    from episode_audit import RecordParallelEvidence

    path = tmp_path / "rps.mcap"
    with RecordParallelEvidence(rps.parallel_env(max_cycles=3), path) as env:
        for seed in range(2):
            env.reset(seed=seed)
            while env.agents:
                env.step({a: env.action_space(a).sample() for a in env.agents})
    result = report_inputs([path], by="all" if games else "agent", games=games)
    out = write_report_html(result.report, result.parts, tmp_path / "r.html", games=games)
    page = out.read_text(encoding="utf-8")
    assert page.count("<svg") >= 2
    rows = page[page.index("<h2>Episodes</h2>") :].count("<tr>") - 1
    assert rows == (2 if games else 4)  # two games, or two agents' episodes in each
    assert ("episode-audit replay" in page) is not games  # a game is no episode to replay


def test_html_report_is_the_same_page_for_the_same_report(tmp_path: Path) -> None:
    _, page = _page(tmp_path)
    result = report_inputs([tmp_path / "run one.mcap"], by="tag:policy")
    again = write_report_html(result.report, result.parts, tmp_path / "again.html")
    assert again.read_text(encoding="utf-8") == page  # no date, stable ids
    assert "<metadata" not in page and "purl.org" not in page


def _figures(page: str) -> list[str]:
    return re.findall(r'<figure class="chart">(.*?)</figure>', page, re.S)


def test_html_charts_draw_at_most_their_groups_and_say_so(tmp_path: Path) -> None:
    # 2 000 groups (a campaign by file) took minutes and 600 MB: one chart row per group
    labels = [f"label{i:02d}" for i in range(charts.MAX_CHART_GROUPS + 5)]
    path = _record_plans(
        tmp_path / "many.mcap", [Plan(f"failure:{label}", length=1) for label in labels]
    )
    result = report_inputs([path], by="label")
    page = write_report_html(result.report, result.parts, tmp_path / "r.html").read_text()
    figures = _figures(page)
    assert len(figures) == 3  # endings, returns, lengths (by label no rates; no terms)
    caption = (
        f"The charts draw the first {charts.MAX_CHART_GROUPS} of {len(labels)} groups; "
        "the tables list every group."
    )
    for figure in figures:
        assert caption in figure
        drawn = [label for label in labels if f">{label}" in figure]
        assert drawn == labels[: charts.MAX_CHART_GROUPS]
    outcomes = page[page.index("<h2>Outcomes</h2>") : page.index("<h2>Failure labels")]
    assert outcomes.count("<tr>") == len(labels) + 1  # the table: every group


def test_html_distribution_draws_a_bounded_number_of_dots(tmp_path: Path) -> None:
    n = charts.MAX_DOTS + 50
    path = _record_plans(tmp_path / "long.mcap", [Plan("failure:fell", length=1)] * n)
    result = report_inputs([path], by="all")
    page = write_report_html(result.report, result.parts, tmp_path / "r.html").read_text()
    returns = _figures(page)[-2]
    uses = returns.count("<use ")  # the dots and the axis' tick marks
    assert charts.MAX_DOTS <= uses < charts.MAX_DOTS + 20 < n
    assert "caption" not in returns  # one group: nothing cut
    assert page[page.index("<h2>Episodes</h2>") :].count("<tr>") == n + 1


def test_write_report_html_reads_no_file_again(tmp_path: Path) -> None:
    # it opened every file a second time for the episode table: 2.7 s of 11.4 s at 2 000 files
    paths = [
        _record_plans(tmp_path / name, [Plan("success"), Plan("failure:fell")])
        for name in ("a.mcap", "b.evidence", "c.mcap")
    ]
    result = report_inputs(paths)
    for path in paths:
        path.write_bytes(b"gone")  # the page comes from what the report read
    out = write_report_html(result.report, result.parts, tmp_path / "r.html")
    page = out.read_text()
    assert page.count("episode-audit replay") == 6
    assert f"episode-audit replay {paths[1]} --episode 1" in page
    with pytest.raises(ConfigurationError, match="looks like an evidence file"):
        write_report_html(result.report, result.parts, paths[1])  # an input: never replaced


def test_html_report_says_which_files_are_unfinished(tmp_path: Path) -> None:
    """The terminal report had an "Unfinished files" table; the HTML page said nothing, so its
    rates over a torn or live file read as final ones."""
    import gymnasium as gym

    from episode_audit import RecordEvidence
    from episode_audit.cli.render.report import report_output

    title = "Unfinished files (still being written, or torn): counts so far"  # (the terminal's)
    fixtures = Path(__file__).resolve().parents[2] / "fixtures"
    live = tmp_path / "live <b>.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), live) as env:
        env.reset(seed=0)
        for _ in range(5):
            env.step(0)
        env.flush()  # (still open: a live file)
        inputs = [fixtures / "torn.mcap", fixtures / "clean.mcap", live]
        result = report_inputs(inputs, by="file")
        out = write_report_html(result.report, result.parts, tmp_path / "report.html")
    page = out.read_text(encoding="utf-8")
    unfinished = result.report.unfinished
    assert [name for name, _ in unfinished] == [str(fixtures / "torn.mcap"), str(live)]
    section = page.split(f'<h2 class="unfinished">{html.escape(title)}</h2>')[1]
    section = section.split("</table>")[0]
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td></tr>", section)
    assert rows == [(html.escape(n), html.escape(w)) for n, w in unfinished]
    assert page.index(title) < page.index("<h2>Outcomes</h2>")  # (before the rates)
    terminal = str(report_output(result.report, "markdown"))
    assert title in terminal and all(w in terminal for _, w in unfinished)

    finished = report_inputs([fixtures / "clean.mcap"], by="file")
    clean = write_report_html(finished.report, finished.parts, tmp_path / "clean.html")
    assert "Unfinished files" not in clean.read_text(encoding="utf-8")


def test_a_label_with_a_glyph_the_font_lacks_is_drawn_without_a_warning(tmp_path: Path) -> None:
    """A file name with an emoji: the SVG holds it as text (the browser draws it), and
    matplotlib's missing-glyph warning is not printed (once per chart, with a source line)."""
    path = _record_plans(tmp_path / "pölé 🚀.mcap", [Plan("success"), Plan("failure:fell")])
    result = report_inputs([path], by="file")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = write_report_html(result.report, result.parts, tmp_path / "report.html")
    assert [str(w.message) for w in caught if "Glyph" in str(w.message)] == []
    labels = re.findall(r"<text [^>]*>([^<]*🚀[^<]*)</text>", out.read_text(encoding="utf-8"))
    assert labels and all("pölé 🚀" in label for label in labels), labels
