"""The ``episode-audit`` command: a thin Typer layer over the library.

Exit codes (as linters use them): 0 clean, 1 findings / divergence / gate missed / data
lost (recover), 2 usage error or unreadable input. Expected failures print one line on
stderr, never a traceback.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from .._version import __version__
from ..errors import ConfigurationError, EpisodeAuditError, EvidenceError
from .render import OutputFormat, safe

if TYPE_CHECKING:
    from ..read.reader import Evidence

app = typer.Typer(
    name="episode-audit",
    help=(
        "Record, replay and audit reinforcement-learning episodes kept as MCAP evidence files."
        "\n\n"
        "Exit codes: 0 clean, 1 findings / divergence / gate missed / data lost (recover), "
        "2 usage error or unreadable input."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

EXIT_CLEAN, EXIT_FINDINGS, EXIT_USAGE = 0, 1, 2


def _stdout() -> Console:
    # Plain output when not a terminal: no colour, and wide enough for CI logs.
    return Console(highlight=False, width=None if sys.stdout.isatty() else 200)


def _stderr() -> Console:
    return Console(stderr=True, highlight=False)


def fail(message: str, code: int = EXIT_USAGE) -> NoReturn:
    """Print one line on stderr and exit."""
    _stderr().print(f"episode-audit: error: {safe(message)}", markup=False, soft_wrap=True)
    raise typer.Exit(code)


def collect(paths: Sequence[Path]) -> list[Path]:
    """Files as given and ``*.mcap`` files under directories (recursively, sorted).

    A file reached twice (named twice, or also found in a directory given) counts once.
    """
    out: list[Path] = []
    seen: set[Path] = set()
    for path in paths:
        try:
            if path.is_dir():
                found = sorted(p for p in path.rglob("*.mcap") if p.is_file())
                if not found:
                    fail(f"{path}: no *.mcap files in this directory")
            elif path.exists():
                found = [path]
            else:
                fail(f"{path}: no such file or directory")
            for file in found:
                real = file.resolve()
                if real not in seen:
                    seen.add(real)
                    out.append(file)
        except OSError as exc:  # e.g. a directory on the way without search permission
            fail(f"{path}: cannot read: {exc.strerror or exc}")
    return out


@contextmanager
def progress_bar(description: str, total: int | None) -> Iterator[Callable[[int], None]]:
    """A Rich progress bar on stderr when it is a terminal; a no-op otherwise."""
    console = _stderr()
    if not console.is_terminal:
        yield lambda n: None
        return
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(description, total=total)
        yield lambda n: bar.advance(task, n)


def emit(output: Any) -> None:
    """Print a renderable (table format) or text (markdown / JSON) on stdout."""
    console = _stdout()
    if isinstance(output, str):
        console.print(output, markup=False, highlight=False, soft_wrap=True)
    else:
        console.print(output)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"episode-audit {__version__}")
        raise typer.Exit()


@app.callback()
def main_options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Show the version and exit."
        ),
    ] = False,
) -> None:
    """Record, replay and audit reinforcement-learning episodes."""


FormatOption = Annotated[
    str,
    typer.Option(
        "--format",
        "-f",
        help="Output format: table, markdown (CI summaries) or json.",
        metavar="<format>",
    ),
]
# readable=False: the library says "cannot open: Permission denied" in one line, and the
# other inputs go on (Click's own check is a three-line usage error that stops them all)
PathsArgument = Annotated[
    list[Path],
    typer.Argument(help="Evidence files, or directories searched for *.mcap.", readable=False),
]


def _format(value: str) -> OutputFormat:
    if value not in ("table", "markdown", "json"):
        fail(f"--format: expected table, markdown or json, got {value!r}")
    return value  # type: ignore[return-value]


def _error_line(exc: EpisodeAuditError) -> None:
    _stderr().print(f"episode-audit: error: {safe(exc)}", markup=False, soft_wrap=True)


def _unreadable(path: Path, exc: EpisodeAuditError, into: list[tuple[str, str]]) -> None:
    """An input that could not be read: its stderr line, and ``(file, why)`` for the JSON."""
    _error_line(exc)
    into.append((str(path), exc.problem if isinstance(exc, EvidenceError) else str(exc)))


def _readable(
    files: Sequence[Path], load: Callable[[Evidence], object] | None = None
) -> tuple[list[tuple[Path, Evidence]], list[tuple[str, str]]]:
    """The files that open as evidence (and whose ``load`` reads), opened; and the others.

    One stderr line for each file that does not, so one bad file costs the others nothing.
    """
    from ..read.reader import open_evidence

    readable: list[tuple[Path, Evidence]] = []
    unreadable: list[tuple[str, str]] = []
    for path in files:
        try:
            ev = open_evidence(path)
            if load is not None:
                load(ev)
            readable.append((path, ev))
        except EpisodeAuditError as exc:
            _unreadable(path, exc, unreadable)
    return readable, unreadable


def _episode_index(index: int) -> int:
    if not 0 <= index < 2**63:
        fail(f"--episode: expected an episode index >= 0, got {index}")
    return index


def _steps_total(paths: Sequence[Path]) -> int | None:
    from ..read.reader import open_evidence

    total = 0
    for path in paths:
        try:
            run_end = open_evidence(path).run_end
        except EvidenceError:
            return None
        if not run_end or not str(run_end.get("steps", "")).isdigit():
            return None
        total += int(run_end["steps"])
    return total


# ----------------------------------------------------------------------------- check


@app.command()
def check(
    paths: PathsArgument,
    atol: Annotated[float, typer.Option(help="Absolute tolerance of the terms-sum check.")] = 1e-6,
    rtol: Annotated[
        float, typer.Option(help="Relative tolerance (times |reward|) of the terms-sum check.")
    ] = 1e-6,
    require_terms: Annotated[
        bool, typer.Option("--require-terms", help="Steps without reward terms are errors.")
    ] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Warnings also fail (exit 1).")] = False,
    ignore: Annotated[
        list[str] | None,
        typer.Option(
            "--ignore",
            help="Leave out findings with this code, from the output and the exit code "
            "(repeatable; recorder_note ignores every recorder note).",
            metavar="<code>",
        ),
    ] = None,
    output: FormatOption = "table",
) -> None:
    """Check integrity and consistency: terms sum to reward, endings labelled, nothing missing."""
    from ..check.core import FILE_UNREADABLE, CheckResult, Finding, ignored_codes, is_ignored
    from ..check.core import check as run_check
    from .render import check_output

    fmt = _format(output)
    try:
        ignored = ignored_codes(ignore or (), option="--ignore")
    except ConfigurationError as exc:
        fail(str(exc))
    files = collect(paths)
    merged = CheckResult(findings=[], files=[], episodes=0, steps=0)
    unreadable: list[tuple[str, str]] = []
    with progress_bar("checking", _steps_total(files)) as advance:
        for path in files:
            try:
                result = run_check(
                    [path],
                    atol=atol,
                    rtol=rtol,
                    require_terms=require_terms,
                    ignore=ignored,
                    progress=advance,
                )
            except ConfigurationError as exc:
                fail(str(exc))
            except EpisodeAuditError as exc:
                _unreadable(path, exc, unreadable)
                # in the result too, so a JSON consumer does not read "ok" over a skipped file
                if is_ignored(FILE_UNREADABLE, ignored):
                    merged.ignored += 1
                else:
                    merged.findings.append(
                        Finding("error", FILE_UNREADABLE, str(exc), str(path), None, None)
                    )
                merged.files.append(str(path))
                continue
            merged.findings.extend(result.findings)
            merged.files.extend(result.files)
            merged.episodes += result.episodes
            merged.steps += result.steps
            merged.ignored += result.ignored
    emit(check_output(merged, fmt, unreadable=unreadable))
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if merged.errors or (strict and merged.warnings):
        raise typer.Exit(EXIT_FINDINGS)


# ----------------------------------------------------------------------------- replay


@app.command()
def replay(
    paths: PathsArgument,
    episode: Annotated[
        list[int] | None,
        typer.Option(
            "--episode", "-e", help="Replay only this episode (repeatable).", metavar="<int>"
        ),
    ] = None,
    atol: Annotated[
        float, typer.Option(help="Tolerance for numeric comparisons (0: exact, the default).")
    ] = 0.0,
    env_factory: Annotated[
        str | None,
        typer.Option(help="MODULE:CALLABLE that returns the environment to replay in."),
    ] = None,
    import_: Annotated[
        list[str] | None,
        typer.Option(
            "--import",
            help="Import MODULE first (e.g. a package that registers envs; repeatable).",
            metavar="<module>",
        ),
    ] = None,
    trust_entry_points: Annotated[
        bool,
        typer.Option(
            "--trust-entry-points",
            help="Allow importing the entry point named inside the file (trusted files only).",
        ),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Re-run episodes from their recorded seed / RNG state and compare them step by step."""
    from ..replay import ReplayResult
    from ..replay import replay as run_replay
    from .render import replay_output

    fmt = _format(output)
    if not (math.isfinite(atol) and atol >= 0):
        fail(f"--atol: expected a finite number >= 0, got {atol}")
    for index in episode or []:
        _episode_index(index)
    files = collect(paths)
    merged = ReplayResult()
    unreadable: list[tuple[str, str]] = []
    with progress_bar("replaying", _steps_total(files) if episode is None else None) as advance:
        for path in files:
            try:
                result = run_replay(
                    [path],
                    episodes=episode,
                    atol=atol,
                    env_factory=env_factory,
                    imports=import_ or (),
                    trust_entry_points=trust_entry_points,
                    progress=advance,
                )
            except ConfigurationError as exc:
                fail(str(exc))
            except EpisodeAuditError as exc:
                _unreadable(path, exc, unreadable)
                continue
            merged.episodes.extend(result.episodes)
            merged.version_differences.update(result.version_differences)
    emit(replay_output(merged, fmt, unreadable=unreadable))
    missing = sorted(set(episode or ()) - {e.episode for e in merged.episodes})
    if missing and not unreadable:
        listed = ", ".join(map(str, missing))
        fail(
            f"--episode: no episode {listed} in the file(s) given "
            "(`episode-audit show FILE` says how many there are)"
        )
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not merged.ok:
        raise typer.Exit(EXIT_FINDINGS)


# ----------------------------------------------------------------------------- report


def _parse_failure_rates(values: Sequence[str]) -> tuple[float | None, dict[str, float]]:
    overall: float | None = None
    by_label: dict[str, float] = {}
    for value in values:
        label, sep, rate = value.rpartition("=")
        try:
            number = float(rate)
        except ValueError:
            fail(f"--max-failure-rate: expected RATE or LABEL=RATE, got {value!r}")
        if not 0.0 <= number <= 1.0:
            fail(f"--max-failure-rate: expected a rate between 0 and 1, got {rate!r}")
        if sep and not label:
            fail(f"--max-failure-rate: expected RATE or LABEL=RATE, got {value!r} (no label)")
        if sep:
            by_label[label] = number
        else:
            overall = number
    return overall, by_label


def _rate_option(name: str, value: float | None) -> float | None:
    if value is not None and not 0.0 <= value <= 1.0:
        fail(f"{name}: expected a rate between 0 and 1, got {value}")
    return value


@app.command()
def report(
    paths: PathsArgument,
    by: Annotated[
        str,
        typer.Option(
            help="Group by: file, env, env_index, agent, label, all, or tag:NAME (e.g. tag:policy)."
        ),
    ] = "file",
    games: Annotated[
        bool,
        typer.Option(
            "--games",
            help="PettingZoo files: count whole games (outcome derived from the agents') "
            "instead of agent-episodes.",
        ),
    ] = False,
    min_success_rate: Annotated[
        float | None, typer.Option(help="Gate: fail (exit 1) if a group's success rate is lower.")
    ] = None,
    max_failure_rate: Annotated[
        list[str] | None,
        typer.Option(
            help="Gate: RATE overall, or LABEL=RATE for one failure label (repeatable).",
            metavar="<[label=]rate>",
        ),
    ] = None,
    max_truncation_rate: Annotated[
        float | None, typer.Option(help="Gate: fail if a group's truncation rate is higher.")
    ] = None,
    max_error_rate: Annotated[
        float | None,
        typer.Option(
            help="Gate: fail if a group's error rate (episodes whose env raised, of all its "
            "episodes; the other rates leave them out) is higher."
        ),
    ] = None,
    fail_on_incentive_warning: Annotated[
        bool,
        typer.Option("--fail-on-incentive-warning", help="Gate: fail on any incentive warning."),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Success / failure / truncation rates side by side, term breakdown, warnings, gates."""
    from ..read.reader import Evidence
    from ..report.core import BY_KEYS, Gates, report_tables
    from .render import report_output

    fmt = _format(output)
    if by not in BY_KEYS and not (by.startswith("tag:") and len(by) > 4):
        fail(f"--by: expected file, env, env_index, agent, label, all or tag:NAME, got {by!r}")
    if games and by == "agent":
        fail("--games cannot be grouped --by agent: a game has many agents")
    overall, by_label = _parse_failure_rates(max_failure_rate or [])
    gates = Gates(
        min_success_rate=_rate_option("--min-success-rate", min_success_rate),
        max_failure_rate=overall,
        max_failure_rate_by_label=by_label,
        max_truncation_rate=_rate_option("--max-truncation-rate", max_truncation_rate),
        max_error_rate=_rate_option("--max-error-rate", max_error_rate),
        fail_on_incentive_warning=fail_on_incentive_warning,
    )
    # Reading each file's episodes here (they are cached) puts a file damaged past its start
    # with the unreadable ones instead of stopping the report of the others.
    readable, unreadable = _readable(collect(paths), Evidence.episodes)
    if not readable and fmt != "json":  # (JSON is still one document: its unreadable list)
        raise typer.Exit(EXIT_USAGE)
    if games:  # a file without games would count nothing, and every gate would pass
        for path, ev in readable:
            kind = str((ev.run.layout or {}).get("kind", "single"))
            if not kind.startswith("pettingzoo"):
                what = "single-env" if kind == "single" else kind
                fail(f"--games counts PettingZoo games; {path} is a {what} file (drop --games)")
    try:
        result = report_tables(
            [(str(path), ev) for path, ev in readable], by=by, gates=gates, games=games
        )
    except EpisodeAuditError as exc:
        fail(str(exc))
    emit(report_output(result, fmt, unreadable=unreadable))
    for line in result.notes:
        _stderr().print(f"episode-audit: warning: {safe(line)}", markup=False, soft_wrap=True)
    if unreadable:
        raise typer.Exit(EXIT_USAGE)
    if not result.passed:
        raise typer.Exit(EXIT_FINDINGS)


# ----------------------------------------------------------------------------- show


def _parse_slice(value: str | None) -> tuple[int | None, int | None]:
    if value is None:
        return None, None
    start, sep, stop = value.partition(":")
    try:
        a = int(start) if start else None
        b = int(stop) if stop else None
    except ValueError:
        fail(f"--steps: expected A:B (e.g. 0:50), got {value!r}")
    if not sep:
        fail(f"--steps: expected A:B (e.g. 0:50), got {value!r}")
    return a, b


@app.command()
def show(
    path: Annotated[Path, typer.Argument(help="An evidence file.", readable=False)],
    episode: Annotated[
        int | None, typer.Option("--episode", "-e", help="Show this episode's steps.")
    ] = None,
    steps: Annotated[
        str | None, typer.Option(help="Slice of steps A:B (with --episode), e.g. 0:50.")
    ] = None,
    all_episodes: Annotated[
        bool,
        typer.Option(
            "--all-episodes",
            help="List every episode in the summary (default: all up to 12, else the first "
            "and last 5).",
        ),
    ] = False,
    output: FormatOption = "table",
) -> None:
    """Summarize a file (run metadata, spaces, versions, env spec, episodes), or one episode."""
    from ..read.reader import open_evidence
    from .show import episode_output, summary_output

    fmt = _format(output)
    if episode is not None:
        _episode_index(episode)
    start, stop = _parse_slice(steps)
    if steps is not None and episode is None:
        fail("--steps needs --episode N")
    if all_episodes and episode is not None:
        fail("--all-episodes lists the episodes of the file summary; not with --episode N")
    if not path.exists():
        fail(f"{path}: no such file or directory")
    try:
        ev = open_evidence(path)
        if episode is None:
            emit(summary_output(ev, fmt, all_episodes=all_episodes))
        else:
            emit(episode_output(ev, episode, start, stop, fmt))
    except EpisodeAuditError as exc:
        fail(str(exc))


# ----------------------------------------------------------------------------- export


@app.command()
def export(
    paths: PathsArgument,
    out: Annotated[Path, typer.Option("--out", "-o", help="Directory for the Parquet files.")],
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Replace the export in --out (its *.steps.parquet files this export does not "
            "write are removed).",
        ),
    ] = False,
) -> None:
    """Write steps and episodes as Parquet (pandas / polars / DuckDB), with a file column."""
    from ..export import export as run_export

    readable, skipped = _readable(collect(paths))
    if not readable:
        raise typer.Exit(EXIT_USAGE)
    files = [path for path, _ in readable]
    try:
        with progress_bar("exporting", _steps_total(files)) as advance:
            result = run_export(
                files, out, overwrite=overwrite, progress=advance, on_error=_error_line
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    unreadable = len(skipped) + len(result.failed)
    for path, ev in readable:
        if not ev.finished and path not in result.failed:
            why = ev.torn or "no run-end record"
            _stderr().print(
                f"episode-audit: note: {safe(str(path))} is unfinished ({safe(why)}): "
                "exported what it holds, its cut-off episode as incomplete",
                markup=False,
                soft_wrap=True,
            )
    removed = f"; removed {len(result.removed)} from an earlier export" if result.removed else ""
    emit(
        f"wrote {result.episodes} episodes to {result.episodes_file} and {result.steps} steps "
        f"to {len(result.steps_files)} *.steps.parquet file(s) in {out}{removed}"
    )
    if unreadable:
        raise typer.Exit(EXIT_USAGE)


# ----------------------------------------------------------------------------- recover


@app.command()
def recover(
    path: Annotated[
        Path,
        typer.Argument(
            help="A torn evidence file (left by a killed recorder) or a damaged one.",
            readable=False,
        ),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="The finished file to write.")],
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Replace an existing output file (never the input).")
    ] = False,
) -> None:
    """Rewrite a torn or damaged file as a finished, indexed one.

    Every complete, intact chunk is kept; damaged chunks are skipped and the episodes that lost
    evidence named. Exit 1 if anything was or may have been lost.
    """
    from ..recover import recover as run_recover

    if not path.exists():
        fail(f"{path}: no such file or directory")
    try:
        result = run_recover(path, out, overwrite=overwrite)
    except EpisodeAuditError as exc:
        fail(str(exc))
    emit(result.summary())
    if result.lost:
        raise typer.Exit(EXIT_FINDINGS)


# ----------------------------------------------------------------------------- record


@app.command()
def record(
    env_id: Annotated[str, typer.Argument(help="A registered Gymnasium id, e.g. CartPole-v1.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The evidence file to write.")],
    policy: Annotated[
        str,
        typer.Option(
            help="random, scripted or hacker (reference tasks), or MODULE:CALLABLE taking "
            "(env, seed) and returning obs -> action."
        ),
    ] = "random",
    episodes: Annotated[int, typer.Option(help="Number of episodes.", min=1)] = 10,
    seed: Annotated[int, typer.Option(help="Seed of the first episode (then seed+1, ...).")] = 0,
    env_kwargs: Annotated[
        str | None,
        typer.Option(
            help="Keyword arguments for gym.make as JSON, e.g. '{\"proxy_reward\": true}'."
        ),
    ] = None,
    max_episode_steps: Annotated[
        int | None, typer.Option(help="Override the registered time limit.")
    ] = None,
    tag: Annotated[
        list[str] | None,
        typer.Option(
            help="Run tag KEY=VALUE (repeatable), e.g. policy=ppo.", metavar="<key=value>"
        ),
    ] = None,
    import_: Annotated[
        list[str] | None,
        typer.Option(
            "--import", help="Import MODULE first (registers envs; repeatable).", metavar="<module>"
        ),
    ] = None,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Replace an existing file.")
    ] = False,
) -> None:
    """Record episodes of a Gymnasium environment with a built-in or given policy."""
    from ..rollout import record_episodes

    kwargs: dict[str, Any] = {}
    if env_kwargs:
        try:
            kwargs = json.loads(env_kwargs)
        except json.JSONDecodeError as exc:
            fail(f"--env-kwargs: not valid JSON ({exc.msg})")
        if not isinstance(kwargs, dict):
            fail("--env-kwargs: expected a JSON object")
    tags: dict[str, str] = {}
    for item in tag or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            fail(f"--tag: expected KEY=VALUE, got {item!r}")
        tags[key] = value
    try:
        with progress_bar(f"recording {env_id}", episodes) as advance:
            summary = record_episodes(
                env_id,
                out,
                policy=policy,
                episodes=episodes,
                seed=seed,
                env_kwargs=kwargs,
                max_episode_steps=max_episode_steps,
                tags=tags,
                imports=import_ or (),
                overwrite=overwrite,
                on_episode=lambda: advance(1),
            )
    except EpisodeAuditError as exc:
        fail(str(exc))
    emit(str(summary))


def main() -> None:
    """Console-script entry point.

    An operating-system error the commands do not name themselves (a full disk, a permission
    denied on an output path) is one line on stderr and exit 2, not a traceback.
    """
    try:
        app()
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        _stderr().print(
            f"episode-audit: error: {safe(where + (exc.strerror or str(exc)))}",
            markup=False,
            soft_wrap=True,
        )
        raise SystemExit(EXIT_USAGE) from None
