"""The ``episode-audit`` command: a thin Typer layer over the library.

Exit codes (as linters use them): 0 clean, 1 findings / divergence / gate missed / data
lost (recover), 2 usage error or unreadable input. Expected failures print one line on
stderr, never a traceback.
"""

from __future__ import annotations

import importlib
import os
import shlex
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import pyarrow as pa
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from typer.core import TyperArgument, TyperCommand, TyperGroup

from .._jobs import sigint_held
from .._version import __version__
from ..errors import ConfigurationError, EpisodeAuditError, EpisodeAuditWarning
from ..read.arguments import episode_index
from ..read.inputs import Inputs, Unreadable, evidence_files, listed_inputs, open_all
from ..read.opening import broken_link, viewer_export
from ..read.storage import Source, is_url
from .render import OutputFormat, safe, wrapped

if TYPE_CHECKING:
    from ..read import Evidence


class _Group(TyperGroup):
    """The command group; an argument with a metavar shows just that in ``--help``.

    (Typer adds the Python type to an argument's name: ``paths <list[Path]>``.) Every
    ``--help`` exits 0 when its reader has gone (:func:`_help_option`).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for command in [self, *self.commands.values()]:
            command.get_help_option = partial(_help_option, command.get_help_option)  # type: ignore[method-assign]
            for param in command.params:
                if isinstance(param, TyperArgument) and param.metavar:
                    param.display_type_rich = lambda ctx: None  # type: ignore[method-assign]


def _help_option(get: Callable[[Any], Any], ctx: Any) -> Any:
    """A command's ``--help`` option (``get`` makes it) whose help, into a closed pipe, exits 0.

    (``episode-audit --help | head -3``: Click exits 1 when stdout's reader has gone, which a
    shell with ``set -o pipefail`` reads as a failure.)
    """
    option = get(ctx)
    if option is not None and not getattr(option, "_quiet_when_closed", False):
        option.callback = partial(_shown_or_closed, option.callback)
        option._quiet_when_closed = True
    return option


def _shown_or_closed(show: Callable[..., Any], ctx: Any, *args: Any) -> Any:
    """``show(ctx, ...)`` (it prints on stdout and exits 0); its reader gone: silent, exit 0."""
    try:
        return show(ctx, *args)
    except BrokenPipeError:
        _silenced(sys.stdout)
        ctx.exit(0)


app = typer.Typer(
    cls=_Group,
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


class _Console(Console):
    """A Rich console whose stream, once its reader has gone (``| head -1``), is left silent.

    Rich's own exits 1 there, which a CI job with ``set -o pipefail`` reads as findings. Here
    the stream's file descriptor becomes ``/dev/null`` (so nothing more is said, and the
    interpreter's flush at exit does not fail again): the command finishes its work and exits
    with its verdict's code.
    """

    def on_broken_pipe(self) -> None:
        self.quiet = True
        _silenced(self.file)


def _silenced(stream: Any) -> None:
    """``stream``'s file descriptor becomes ``/dev/null``: what is still written goes nowhere."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # (no descriptor: nothing to keep quiet)
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, fd)
    finally:
        os.close(null)


def _stdout() -> Console:
    # Plain output when not a terminal: no colour, and wide enough for CI logs (200 columns,
    # unless COLUMNS says otherwise); no emoji codes (a label ``:warning:`` prints as written,
    # not as an emoji)
    sized = sys.stdout.isatty() or os.environ.get("COLUMNS", "").isdigit()
    return _Console(highlight=False, emoji=False, width=None if sized else 200)


def _stderr() -> Console:
    return _Console(stderr=True, highlight=False, emoji=False)


def _say(kind: str, message: object) -> None:
    """A line on stderr: ``episode-audit: KIND: message`` (control characters escaped).

    Wrapped at the terminal's width (or ``COLUMNS``'), never inside a word (:func:`wrapped`);
    one line in a log. While a progress bar is shown, through its console: the line goes above
    the bar, on a line of its own (another console would write it after the bar's text).
    """
    console = _live[-1] if _live else _stderr()
    text = wrapped(f"episode-audit: {kind}: {safe(message)}", _text_width(console))
    console.print(text, markup=False, soft_wrap=True)


def _text_width(console: Console) -> int | None:
    """The width text for people is wrapped at on ``console``: a terminal's, or ``COLUMNS``.

    ``None`` (not wrapped) otherwise: a log's line is a message.
    """
    sized = console.is_terminal or os.environ.get("COLUMNS", "").isdigit()
    return console.width if sized else None


_live: list[Console] = []
"""The console of the progress bar shown (:func:`progress_bar`), if one is."""


def fail(message: str, code: int = EXIT_USAGE) -> NoReturn:
    """Print one line on stderr and exit.

    After a Ctrl-C or ``SIGTERM`` the work swallowed, the failure is the stop's doing (the
    workers a process group's ``SIGTERM`` ended): :func:`interruptible` says the stop instead.
    """
    if _stopped:
        raise KeyboardInterrupt
    _said["failure"] = message
    _say("error", message)
    raise typer.Exit(code)


def warn(message: str) -> None:
    """Print a warning line on stderr (the command goes on)."""
    _say("warning", message)


def note(message: str) -> None:
    """Print a note line on stderr (the command goes on)."""
    _say("note", message)


def existing(path: str | Path, command: str) -> str | Path:
    """``path``, or exit 2: there is no such file, or it is a directory (``command`` takes one).

    A URL is checked by the library, which reads it (``docs/storage.md``).
    """
    if is_url(path):
        return path
    try:
        os.stat(path)
    except OSError as exc:
        why = broken_link(path, exc)
        if why is None and not isinstance(exc, FileNotFoundError | NotADirectoryError):
            raise
        fail(f"{path}: {why or 'no such file or directory'}")
    if Path(path).is_dir():
        some = (p for p in sorted(Path(path).glob("*.mcap")) if not viewer_export(p))
        first = next(some, None)
        example = f" (e.g. {shlex.quote(str(first))})" if first is not None else ""
        fail(
            f"{path}: a directory; {command} reads one evidence file: name one of its .mcap "
            f"files{example}"
        )
    return path


def collect(paths: Sequence[str | Path]) -> list[Source]:
    """The evidence files ``paths`` name (see :func:`~episode_audit.read.evidence_files`).

    URLs (``s3://`` …) are listed through ``fsspec`` (``docs/storage.md``). The viewer
    exports found in directories are left out, and a note line says how many.
    """
    try:
        inputs = listed_inputs(paths)
    except ConfigurationError as exc:
        fail(str(exc))
    exports_note(inputs.exports)
    return inputs.files


def exports_note(exports: Sequence[Source]) -> None:
    """The note line saying how many viewer exports a listing left out, if it left any."""
    line = Inputs([], list(exports)).exports_note()
    if line is not None:
        note(line)


def lister(paths: Sequence[str]) -> Callable[[], list[Source] | None]:
    """``paths``' evidence files, listed when first asked and then kept (one listing a command).

    ``None`` if they cannot be listed: the command's own listing says why.
    """
    kept: list[list[Source] | None] = []

    def files() -> list[Source] | None:
        if not kept:
            try:
                kept.append(evidence_files(paths))
            except EpisodeAuditError:
                kept.append(None)
        return kept[0]

    return files


def listed_count(files: Callable[[], list[Source] | None]) -> int | None:
    """How many files :func:`lister` found (``None`` if it could not list them)."""
    found = files()
    return None if found is None else len(found)


def listed_jobs(jobs: int | None, files: Callable[[], list[Source] | None]) -> int | None:
    """``report`` / ``compare``'s ``--jobs`` for the files :func:`lister` found.

    Below :data:`SMALL_TABLES` one process; ``None`` (every usable core) if they cannot be
    listed.
    """
    if jobs is not None:
        return jobs
    found = files()
    return None if found is None else jobs_for(jobs, found, SMALL_TABLES)


@contextmanager
def failure_document(
    command: str, output: OutputFormat, unreadable: Sequence[Unreadable] = ()
) -> Iterator[None]:
    """In JSON and JUnit formats, a failure (exit 2) before any output also prints a document.

    A CI job that saves the command's stdout (``check.xml``) then holds the error, not nothing
    (:func:`~episode_audit.cli.render.failure.error_output`), with ``unreadable`` as it is then.
    """
    emitted, _said["failure"] = _said["emitted"], None
    try:
        yield
    except typer.Exit as exc:
        message, silent = _said["failure"], _said["emitted"] == emitted
        if output in ("json", "junit") and exc.exit_code == EXIT_USAGE and message and silent:
            from .render.failure import error_output

            emit(error_output(command, message, output, unreadable))
        raise


_UsageError: type[Exception] = typer.BadParameter.__mro__[1]
"""Click's ``UsageError`` (``typer.BadParameter``'s base: Typer bundles Click, or uses it)."""


class DocumentedCommand(TyperCommand):
    """A command with ``--format``: a usage error found while parsing also prints a document.

    Click refuses a bad option value (``--jobs 0``) before the command runs, so
    :func:`failure_document` never sees it: in JSON and JUnit this prints the error document
    first (a CI job's ``check.xml`` then holds the error, not nothing); Click then says it on
    stderr and exits 2 as always.
    """

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        given = ctx.meta[_ARGS] = list(args)  # (Click's parser empties ``args``)
        with self._documented(given):
            return list(super().parse_args(ctx, args))

    def invoke(self, ctx: Any) -> Any:
        with self._documented(ctx.meta.get(_ARGS, [])):  # (Typer checks some values here)
            return super().invoke(ctx)

    @contextmanager
    def _documented(self, args: list[str]) -> Iterator[None]:
        try:
            yield
        except _UsageError as exc:
            format_message = getattr(exc, "format_message", None)
            self._document(args, format_message() if format_message else str(exc))
            raise

    def refuse(self, args: list[str], message: str) -> NoReturn:
        """Refuse the arguments while parsing them: the document, then :func:`fail`."""
        self._document(args, message)
        fail(message)

    def _document(self, args: list[str], message: str) -> None:
        output = _format_in(args)
        if output in _DOCUMENTED:
            from .render.failure import error_output

            emit(error_output(str(self.name), message, _DOCUMENTED[output]))


_ARGS = "episode_audit.args"  # (the command's arguments, in its context's meta)
_DOCUMENTED: dict[str, OutputFormat] = {"json": "json", "junit": "junit"}


def _format_in(args: Sequence[str]) -> str | None:
    """The value of the last ``-f`` / ``--format`` in a command's arguments, if any."""
    found = None
    for i, arg in enumerate(args):
        if arg == "--":
            break
        if arg in ("-f", "--format") and i + 1 < len(args):
            found = args[i + 1]
        elif arg.startswith("--format="):
            found = arg.partition("=")[2]
        elif arg.startswith("-f") and not arg.startswith("--") and len(arg) > 2:
            found = arg[2:]
    return found


@contextmanager
def progress_bar(
    description: str, total: int | Callable[[], int | None] | None
) -> Iterator[Callable[[int], None]]:
    """A Rich progress bar on stderr when it is a terminal; a no-op otherwise.

    ``total`` may be a function, called only when there is a bar to show. Meanwhile the lines
    :func:`fail`, :func:`warn` and :func:`note` print go above the bar.
    """
    console = _stderr()
    if not console.is_terminal:
        yield lambda n: None
        return
    if callable(total):
        total = total()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(description, total=total)
        _live.append(console)
        try:
            yield lambda n: bar.advance(task, n)
        finally:
            _live.remove(console)


_said: dict[str, Any] = {"emitted": 0, "failure": None}  # (for failure_document)


def emit(output: Any) -> None:
    """Print a renderable (table format) or text (markdown / JSON) on stdout."""
    _said["emitted"] += 1
    console = _stdout()
    if isinstance(output, str):
        console.print(output, markup=False, highlight=False, soft_wrap=True)
    else:  # (not cropped: a renderable's text that must stay whole, e.g. JSON, says no_wrap)
        console.print(output, crop=False)


def said(text: str, paths: Iterable[object] = ()) -> None:
    """Print ``text``, a result's summary for people, on stdout, wrapped as :func:`note`'s.

    Each line made safe; one that starts indented (a command to copy) kept whole, and so is
    each of ``paths`` (the files it names: not broken at a space of theirs).
    """
    lines = "\n".join(safe(line) for line in text.split("\n"))
    emit(wrapped(lines, _text_width(_stdout()), [safe(str(path)) for path in paths]))


def _version(ctx: typer.Context, value: bool) -> None:
    if value:
        _shown_or_closed(lambda ctx: typer.echo(f"episode-audit {__version__}"), ctx)
        raise typer.Exit()


@app.callback()
def main_options(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Show the version and exit."
        ),
    ] = False,
) -> None:
    """Record, replay and audit reinforcement-learning episodes."""
    ctx.with_resource(_warning_lines())


@contextmanager
def _warning_lines() -> Iterator[None]:
    """Meanwhile every :class:`~episode_audit.errors.EpisodeAuditWarning` is one ``warning:`` line.

    (:func:`warn`'s, without the ``episode-audit:`` a recorder's message starts with; Python's
    own form is two lines naming the library's source.) Other libraries' warnings are left as
    they are.
    """
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message: Any, category: Any, *args: Any, **kwargs: Any) -> None:
            if issubclass(category, EpisodeAuditWarning):
                warn(str(message).removeprefix(_OURS))
            else:
                shown(message, category, *args, **kwargs)

        warnings.showwarning = show
        yield


_OURS = "episode-audit: "


FormatOption = Annotated[
    str,
    typer.Option(
        "--format",
        "-f",
        help="Output format: table, markdown (CI summaries) or json.",
        metavar="<format>",
    ),
]
CIFormatOption = Annotated[
    str,
    typer.Option(
        "--format",
        "-f",
        help="Output format: table, markdown (CI summaries), json, or junit (CI test reporters).",
        metavar="<format>",
    ),
]
"""``--format`` of the commands whose result a CI job gates on (``check``, ``replay``, ...)."""
# str, not Path: a URL (s3://bucket/key) must reach the library as written
PathsArgument = Annotated[
    list[str],
    typer.Argument(
        help="Evidence files, or directories searched for *.mcap; or URLs (s3://, gs://, "
        "az://, https://) of files or prefixes.",
        metavar="PATHS",
    ),
]


ImportOption = Annotated[
    list[str] | None,
    typer.Option(
        "--import",
        help="Import MODULE first (e.g. a package that registers envs; repeatable).",
        metavar="<module>",
    ),
]


def imported(modules: list[str] | None) -> tuple[str, ...]:
    """The modules ``--import`` names, imported here first, so that an error names ``--import``.

    The library imports them again (already imported: nothing to do), its own errors naming
    its ``imports=`` argument.
    """
    from .._usercode import import_modules

    named = tuple(modules or ())
    try:
        import_modules(named, option="--import")
    except ConfigurationError as exc:
        fail(str(exc))
    return named


JobsOption = Annotated[
    int | None,
    typer.Option(
        "--jobs",
        "-j",
        help="Worker processes, a file (or a batch of episodes) each at a time; default: every "
        "usable core; 1: in this process. Output is the same whatever the number.",
        metavar="<n>",
        min=1,
        show_default=False,
    ),
]
RayOption = Annotated[
    str | None,
    typer.Option(
        "--ray",
        help="Run the work as Ray tasks instead: on the cluster at ADDRESS (auto, ray://HOST:PORT "
        "or HOST:PORT), or on a Ray started here (local). Needs episode-audit[ray].",
        metavar="<address>",
        show_default=False,
    ),
]
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143  # 128 + SIGTERM, as a shell reports a command SIGTERM ended
SMALL_INPUTS = 8 << 20
"""Inputs totalling fewer bytes are read in this process unless ``--jobs`` says otherwise:
starting the workers' fork server (an interpreter importing episode-audit, about a second)
would cost more than it saves."""

SMALL_TABLES = 256 << 20
"""``report`` and ``compare`` read their inputs in this process below this many bytes: their
work per file is small next to sending its tables back from a worker (2 000 CartPole files,
32 MB: 3.9 s in one process, 5.1 s with a worker on 2 cores)."""


def jobs_for(jobs: int | None, files: Sequence[Source], small: int = SMALL_INPUTS) -> int | None:
    """``--jobs`` as given; not given: ``None`` (every usable core), or 1 for small inputs.

    A URL counts as large: its size is not looked up here (one request each).
    """
    if jobs is not None:
        return jobs
    total = 0
    for file in files:
        if not isinstance(file, Path):
            return None
        try:
            total += file.stat().st_size
        except OSError:
            pass
    return 1 if total < small else None


@contextmanager
def interruptible() -> Iterator[None]:
    """Ctrl-C or ``SIGTERM``: one line on stderr and exit 130 or 143 (the workers stopped).

    ``SIGTERM`` (a CI job's timeout, ``timeout``, ``docker stop``) stops the command as Ctrl-C
    does: Python's default would end it at once, its worker processes left waiting for work
    and multiprocessing's folder left in the temporary directory. So even when the work
    swallowed the ``KeyboardInterrupt`` (:func:`_pressed`), or then failed for it (a
    ``SIGTERM`` to the process group ends the workers too: a ``WorkerError``). pyarrow
    imports pandas (when installed) the first time it converts a column, and a Ctrl-C during
    that import is lost, or leaves pandas half-imported (a traceback): it is imported first
    here, with Ctrl-C held meanwhile (:func:`~episode_audit._jobs.sigint_held`).
    """
    pressed = _stopped
    pressed.clear()
    main = threading.current_thread() is threading.main_thread()
    # a signal a library turns into another error still stops the command; one whose handler
    # is not Python's default (the caller's own, or ignored) is left as it is
    watched = [n for n, default in _STOPPING if main and signal.getsignal(n) is default]
    for signum in watched:
        signal.signal(signum, partial(_pressed, pressed))
    try:
        with sigint_held():
            _pyarrow_pandas()
        yield
        if pressed:
            raise KeyboardInterrupt
    except BaseException as exc:
        # (an error a swallowed stop led to, a WorkerError of the workers it ended: the stop)
        if not pressed and not isinstance(exc, KeyboardInterrupt):
            raise
        if signal.SIGTERM in pressed:
            _say("error", "terminated (SIGTERM): stopped")
            raise typer.Exit(EXIT_TERMINATED) from None
        _say("error", "interrupted (Ctrl-C): stopped")
        raise typer.Exit(EXIT_INTERRUPTED) from None
    finally:
        for signum, default in _STOPPING:
            if signum in watched:
                signal.signal(signum, default)
        pressed.clear()


_stopped: list[int] = []
"""The stopping signals noted while :func:`interruptible`'s work runs (:func:`_pressed`)."""


_STOPPING: tuple[tuple[int, Any], ...] = (
    (signal.SIGINT, signal.default_int_handler),
    (signal.SIGTERM, signal.SIG_DFL),
)
"""The signals that stop a command, each with Python's default handler."""


def _pressed(pressed: list[int], signum: int, frame: Any) -> None:
    """Ctrl-C or ``SIGTERM``, noted in ``pressed``, then Python's ``KeyboardInterrupt``.

    Raised inside a library it may become another error (an env that "is not installed" when
    ``import mujoco`` was interrupted, a ctypes ``ArgumentError``): a verdict made of those
    would be false, so :func:`interruptible` stops the command all the same.
    """
    pressed.append(signum)
    raise KeyboardInterrupt


def _pyarrow_pandas() -> None:
    """Have pyarrow import pandas now, if it is installed (check, report and replay would)."""
    shim = getattr(getattr(pa, "lib", None), "_pandas_api", None)
    if shim is not None:
        shim.have_pandas  # noqa: B018 - the property imports it
        return
    try:
        importlib.import_module("pandas")
    except ImportError:
        pass


def _format(value: str, *, junit: bool = False) -> OutputFormat:
    if junit and value == "junit":
        return "junit"
    if value not in ("table", "markdown", "json"):
        expected = "table, markdown, json or junit" if junit else "table, markdown or json"
        fail(f"--format: expected {expected}, got {value!r}")
    return value  # type: ignore[return-value]


def _error_line(exc: EpisodeAuditError) -> None:
    _say("error", exc)


def _unreadable(path: Path, exc: EpisodeAuditError, into: list[Unreadable]) -> None:
    """An input that could not be read: its stderr line, and its entry for the JSON."""
    _error_line(exc)
    into.append(Unreadable.of(path, exc))


def _readable(
    files: Sequence[Source], load: Callable[[Evidence], object] | None = None
) -> tuple[list[tuple[Source, Evidence]], list[Unreadable]]:
    """The files that open as evidence (and whose ``load`` reads), opened; and the others.

    One stderr line for each file that does not, so one bad file costs the others nothing.
    """
    return open_all(files, load, on_error=_error_line)


def _episode_index(index: int) -> int:
    try:
        return episode_index("--episode", index)
    except ConfigurationError as exc:
        fail(str(exc))


def main() -> None:
    """Console-script entry point.

    An operating-system error the commands do not name themselves (a full disk, a permission
    denied on an output path) is one line on stderr and exit 2, not a traceback.
    """
    try:
        app()
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        _say("error", where + (exc.strerror or str(exc)))
        raise SystemExit(EXIT_USAGE) from None
