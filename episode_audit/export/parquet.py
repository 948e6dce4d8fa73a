"""Export evidence to Parquet for pandas, polars and DuckDB.

For each input file ``run.mcap``, :func:`export` writes ``run.steps.parquet`` (one row per step,
streamed block by block) and adds its episodes to ``episodes.parquet`` (all files together), both
with a ``file`` column and the run's ``env_id`` and tags (``tag:NAME``, one column per tag) last;
:class:`ExportResult` says what it wrote. Output names come from the
input paths only, never from file content. Columns and queries: ``docs/cli.md`` ("export").
"""

from __future__ import annotations

import itertools
import os
import tempfile
from collections.abc import Callable, Container, Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.fs as pafs
import pyarrow.parquet as pq

from .._jobs import map_ordered
from ..errors import ConfigurationError, EvidenceError
from ..format.columns import counted
from ..format.records import unstarted
from ..read import open_evidence
from ..read.arguments import path_list
from ..read.storage import RemoteFile, Source, as_output, as_source, exists, upload
from ..record.lock import output_kind, remove_empty
from ..record.published import no_space
from ._output import episode_count, refuse_evidence

__all__ = ["ExportResult", "export"]


@dataclass
class ExportResult:
    """What :func:`export` wrote."""

    episodes_file: Source
    steps_files: list[Source] = field(default_factory=list)
    episodes: int = 0
    """Rows of ``episodes.parquet``: every episode, unstarted ones too."""
    steps: int = 0
    failed: list[Source] = field(default_factory=list)
    """Inputs that could not be read to the end (only with ``on_error``); nothing of theirs
    is in the output."""
    removed: list[Source] = field(default_factory=list)
    """With ``overwrite``: ``*.steps.parquet`` files of an earlier export that this one did not
    write, removed so that ``read_parquet('DIR/*.steps.parquet')`` reads this export only."""
    unfinished: list[tuple[Source, str]] = field(default_factory=list)
    """Inputs exported while unfinished (still being written, or torn), and why."""
    cut_off: dict[Source, int] = field(default_factory=dict)
    """Per unfinished input, its episodes the file cut off (no end record): ``incomplete``."""
    unstarted: int = 0
    """Of :attr:`episodes`, those reset and never stepped (``show`` and ``report`` count them
    apart)."""

    @property
    def notes(self) -> list[str]:
        """A line for each unfinished input: what of it was exported."""
        return [
            f"{path} is unfinished ({why}): exported what it holds{_as_incomplete(cut)}"
            for path, why in self.unfinished
            for cut in [self.cut_off.get(path, 0)]
        ]

    def summary(self) -> str:
        """Lines for people: what was written where (episodes, then steps)."""
        removed = (
            f"\nremoved {len(self.removed)} *.steps.parquet file(s) of an earlier export"
            if self.removed
            else ""
        )
        return (
            f"wrote {episode_count(self.episodes, self.unstarted)} to {self.episodes_file}\n"
            f"and {counted(self.steps, 'step')} to {len(self.steps_files)} *.steps.parquet "
            f"file(s) in {self.episodes_file.parent}{removed}"
        )


def _as_incomplete(cut: int) -> str:
    """How a note says what became of an unfinished input's ``cut`` cut-off episodes.

    >>> _as_incomplete(0), _as_incomplete(1), _as_incomplete(2)
    ('', ', its cut-off episode as incomplete', ', its 2 cut-off episodes as incomplete')
    """
    if cut == 0:
        return ""
    if cut == 1:
        return ", its cut-off episode as incomplete"
    return f", its {cut} cut-off episodes as incomplete"


class _Exported(NamedTuple):
    """One input's part of the export."""

    episodes: pa.Table
    steps: int
    unfinished: str | None
    """Why the input is unfinished (``None``: finished)."""
    cut_off: int
    """Episodes without an end record (a torn or live file's last ones)."""


def export(
    paths: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
) -> ExportResult:
    """Write the steps and episodes of ``paths`` as Parquet files into ``out_dir``.

    ``paths`` and ``out_dir`` may be URLs (``s3://bucket/prefix`` …), reached through
    ``filesystem`` or one made with ``storage_options`` (``docs/storage.md``): the export is
    written to a local temporary directory, then each finished file is uploaded.

    Existing output files are not replaced unless ``overwrite=True``, which replaces the export
    in ``out_dir``: ``*.steps.parquet`` files there that this export does not write (an earlier
    export's) are removed (:attr:`ExportResult.removed`); ``overwrite_option`` is how the error
    for an existing file names that option (``--overwrite`` on the command line). An input that
    cannot be read to the end (e.g. a damaged chunk) raises
    :class:`~episode_audit.errors.EvidenceError`; with ``on_error``, it is handed the error
    instead, the input is listed in :attr:`ExportResult.failed` with nothing of it in the output,
    and the others are exported.

    ``jobs`` worker processes (``None``: one per usable core) or Ray tasks on ``ray_address``
    export a file each (see :mod:`episode_audit._jobs`); Ray workers must see ``out_dir``.
    The output is the same as with ``jobs=1`` (without ``on_error``, files after an unreadable
    one may have been written by then). ``out_dir`` and its missing parents are created; an
    export that fails removes those of them it left empty.

    >>> import tempfile, pathlib, gymnasium as gym
    >>> from episode_audit import RecordEvidence
    >>> tmp = pathlib.Path(tempfile.mkdtemp())
    >>> with RecordEvidence(gym.make("CartPole-v1"), tmp / "run.mcap") as env:
    ...     _ = env.reset(seed=0)
    ...     _ = env.step(0)
    >>> result = export([tmp / "run.mcap"], tmp / "out")
    >>> pq.read_table(result.steps_files[0]).column("file").to_pylist() == [str(tmp / "run.mcap")]
    True
    """
    options = {"filesystem": filesystem, "storage_options": storage_options}
    sources = [as_source(p, **options) for p in path_list(paths)]
    target = as_output(out_dir, **options)
    if isinstance(target, RemoteFile):
        return _export_to_url(
            sources, target, overwrite, overwrite_option, progress, on_error, jobs, ray_address
        )
    out, made = _output_directory(target)
    try:
        return _export_local(
            sources, out, overwrite, overwrite_option, progress, on_error, jobs, ray_address
        )
    except BaseException:
        remove_empty(made)  # (a failed export leaves no folder of its own making behind)
        raise


def _export_local(
    sources: list[Source],
    out: Path,
    overwrite: bool,
    overwrite_option: str,
    progress: Callable[[int], None] | None,
    on_error: Callable[[EvidenceError], None] | None,
    jobs: int | None,
    ray_address: str | None,
) -> ExportResult:
    """:func:`export` into the local directory ``out`` (it exists)."""
    episodes_file = out / "episodes.parquet"
    result = ExportResult(episodes_file)
    targets = [out / f"{name}.steps.parquet" for name in _step_file_names(sources)]
    _check_outputs([episodes_file, *targets], overwrite, overwrite_option)
    if overwrite:  # (the earlier export's steps files this one removes)
        for stale in _stale(out, set(targets)):
            refuse_evidence(stale)
    episode_tables: list[pa.Table] = []
    pairs = list(zip(sources, targets, strict=True))
    done = map_ordered(_export_pair, pairs, jobs=jobs, ray_address=ray_address, progress=progress)
    for (source, target), exported in zip(pairs, done, strict=True):
        if isinstance(exported, EvidenceError):
            if on_error is None:
                raise exported
            on_error(exported)
            result.failed.append(source)
            continue
        episode_tables.append(exported.episodes)
        result.steps += exported.steps
        result.steps_files.append(target)
        if exported.unfinished is not None:
            result.unfinished.append((source, exported.unfinished))
            result.cut_off[source] = exported.cut_off
    # files with different tags: a tag column a file lacks is null for its episodes
    episodes = (
        pa.concat_tables(episode_tables, promote_options="default")
        if episode_tables
        else pa.table({})
    )
    with _written(episodes_file):
        pq.write_table(episodes, _local(episodes_file), compression="zstd", filesystem=_LOCAL)
    result.episodes = episodes.num_rows
    result.unstarted = int(unstarted(episodes).sum()) if episodes.num_rows else 0
    if overwrite:  # the export in out_dir is this one: an earlier one's steps files go
        result.removed = _remove_stale(out, set(result.steps_files))
    return result


def _check_outputs(files: list[Path], overwrite: bool, option: str) -> None:
    """Refuse outputs that are special files, evidence, or exist when not to be overwritten.

    Evidence: an evidence file or a live recorder's (:func:`._output.refuse_evidence`).

    ``option``: how the error names the ``overwrite`` option (``--overwrite`` on the command
    line).
    """
    _refuse_special_files(files)
    for file in files:
        if file.exists():
            refuse_evidence(file)
    if not overwrite:
        existing = [f for f in files if f.exists()]
        if existing:
            raise ConfigurationError(
                f"{existing[0]}: exists; pass {option} to replace exported files"
            )


def _export_to_url(
    sources: list[Source],
    out: RemoteFile,
    overwrite: bool,
    option: str,
    progress: Callable[[int], None] | None,
    on_error: Callable[[EvidenceError], None] | None,
    jobs: int | None = 1,
    ray_address: str | None = None,
) -> ExportResult:
    """Export into a local temporary directory, then upload each file to ``out``.

    ``option``: how the error for an existing file names ``overwrite`` (``--overwrite``).
    """
    fs = out.fs
    names = ["episodes.parquet", *(f"{n}.steps.parquet" for n in _step_file_names(sources))]
    remote = {
        name: RemoteFile(f"{out.url.rstrip('/')}/{name}", fs, f"{out.fs_path}/{name}")
        for name in names
    }
    if not overwrite:
        for target in remote.values():
            if exists(target):
                raise ConfigurationError(
                    f"{target}: exists; pass {option} to replace exported files"
                )
    with tempfile.TemporaryDirectory(prefix="episode-audit-export-") as tmp:
        local = export(
            sources,
            tmp,
            overwrite=True,
            progress=progress,
            on_error=on_error,
            jobs=jobs,
            ray_address=ray_address,
        )
        uploaded = [local.episodes_file, *local.steps_files]
        for path in uploaded:
            upload(Path(path), remote[Path(path).name])
    written = {remote[Path(p).name].fs_path for p in local.steps_files}
    result = ExportResult(
        remote["episodes.parquet"],
        [remote[Path(p).name] for p in local.steps_files],
        local.episodes,
        local.steps,
        local.failed,
        unfinished=local.unfinished,
        cut_off=local.cut_off,
        unstarted=local.unstarted,
    )
    if overwrite:
        result.removed = _remove_stale_remote(out, written)
    return result


def _remove_stale_remote(out: RemoteFile, written: set[str]) -> list[Source]:
    """Remove the ``*.steps.parquet`` objects under ``out`` that this export did not write."""
    fs = out.fs
    removed: list[Source] = []
    for stale in sorted(fs.glob(f"{out.fs_path.rstrip('/')}/*.steps.parquet")):
        if stale not in written:
            fs.rm_file(stale)
            removed.append(RemoteFile(fs.unstrip_protocol(stale), fs, stale))
    return removed


def _output_directory(out: Path) -> tuple[Path, list[Path]]:
    """``out``, created if needed, and the folders this made (outermost first).

    A path that is not a directory is a usage error.
    """
    if out.exists() and not out.is_dir():
        raise ConfigurationError(f"{out}: not a directory; --out names the directory to write to")
    made = [folder for folder in (out, *out.parents) if not folder.exists()][::-1]
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigurationError(f"{out}: cannot create the directory: {exc.strerror}") from None
    return out, made


def _refuse_special_files(targets: Sequence[Path]) -> None:
    """An output name taken by a directory, FIFO, device or socket is a usage error.

    Writing to a FIFO waits for a reader (``--overwrite`` would hang), a device swallows the
    export: each is refused before anything is written.
    """
    for target in targets:
        kind = output_kind(target)
        if kind is not None:
            raise ConfigurationError(
                f"{target}: is {kind}, not a regular file; export writes a file of that name "
                "— remove it, or choose another --out"
            )


def _step_file_names(sources: Sequence[Source]) -> list[str]:
    """Each input's steps file name: its stem, then ``stem-2``, ``stem-3``, … for repeats.

    >>> _step_file_names([Path("a/run.mcap"), Path("b/run.mcap"), Path("x.mcap")])
    ['run', 'run-2', 'x']
    """
    used: set[str] = set()
    names: list[str] = []
    for source in sources:
        stem = name = source.stem
        k = 1
        while name in used:
            k += 1
            name = f"{stem}-{k}"
        used.add(name)
        names.append(name)
    return names


def _stale(out: Path, written: Container[Source]) -> list[Path]:
    """The ``*.steps.parquet`` files in ``out`` other than ``written``."""
    return [
        stale
        for stale in sorted(out.glob("*.steps.parquet"))
        if stale not in written and stale.is_file()
    ]


def _remove_stale(out: Path, written: Container[Source]) -> list[Source]:
    """Remove the ``*.steps.parquet`` files in ``out`` this export did not write."""
    removed: list[Source] = []
    for stale in _stale(out, written):
        stale.unlink()
        removed.append(stale)
    return removed


def _export_pair(
    pair: tuple[Source, Path], progress: Callable[[int], None] | None
) -> _Exported | EvidenceError:
    """Export one input to its steps file, or say why it could not be (in a worker, maybe)."""
    try:
        return _export_one(*pair, progress)
    except EvidenceError as exc:
        return exc


def _export_one(source: Source, target: Path, progress: Callable[[int], None] | None) -> _Exported:
    """Write ``source``'s steps to ``target``; return its episodes (with ``file``), steps, state.

    On any failure no ``target`` is left behind: a half-written file must not look complete.
    """
    ev = open_evidence(source)
    unfinished = None if ev.finished else ev.torn or "no run-end record"
    label = str(source)
    run_columns = _run_columns(ev.run.env_id, ev.run.tags)
    episodes = ev.episodes()
    # Vector and PettingZoo files: each step row names its sub-env and agent too.
    multi = (ev.run.layout or {}).get("kind", "single") != "single"
    env_index = episodes.column("env_index").combine_chunks()
    agent = episodes.column("agent").combine_chunks()
    writer: pq.ParquetWriter | None = None
    steps = 0
    batches = ev.iter_step_batches()
    first = next(batches, None)  # (read before the target is touched: a bad input leaves it)
    with _written(target):
        for batch in batches if first is None else itertools.chain([first], batches):
            table = _with_file(batch, label)
            if multi:
                table = _with_stream(table, episodes, env_index, agent)
            table = _with_run(table, run_columns)
            if writer is None:
                writer = pq.ParquetWriter(
                    _local(target), table.schema, compression="zstd", filesystem=_LOCAL
                )
            try:
                writer.write_table(table)
            except BaseException:
                with suppress(OSError):  # (its error in closing: the same failure, again)
                    writer.close()
                raise
            steps += table.num_rows
            if progress is not None:
                progress(table.num_rows)
        if writer is not None:
            writer.close()
        else:  # no steps at all: still write an empty, typed file
            empty = _with_file(ev.steps_schema.empty_table(), label)
            pq.write_table(_with_run(empty, run_columns), _local(target), filesystem=_LOCAL)
    cut_off = episodes.column("ended").to_pylist().count(False) if unfinished else 0
    return _Exported(
        _with_run(_with_file(episodes, label), run_columns), steps, unfinished, cut_off
    )


_LOCAL = pafs.LocalFileSystem()
"""The file system pyarrow writes the tables to, given explicitly: see :func:`_local`."""


def _local(path: Path) -> str:
    """``path`` as pyarrow's local file system takes it: absolute.

    Given a relative path such as ``exp-12:30/run.steps.parquet``, pyarrow reads a URI of the
    scheme ``exp-12``, even with ``filesystem=``.
    """
    return os.path.abspath(path)


@contextmanager
def _written(target: Path) -> Iterator[None]:
    """Write ``target`` in the block: on any failure no ``target`` is left behind.

    A disk with no space left is a :class:`~episode_audit.errors.ConfigurationError` naming
    ``target`` (:func:`~episode_audit.record.published.no_space`).
    """
    try:
        yield
    except BaseException as exc:
        target.unlink(missing_ok=True)  # (half written: it must not look complete)
        full = no_space(target, exc) if isinstance(exc, OSError) else None
        if full is None:
            raise
        raise full from None


def _with_file(batch: pa.RecordBatch | pa.Table, name: str) -> pa.Table:
    table = pa.Table.from_batches([batch]) if isinstance(batch, pa.RecordBatch) else batch
    return table.add_column(0, "file", pa.array([name] * table.num_rows, pa.string()))


def _run_columns(env_id: str | None, tags: dict[str, str]) -> list[tuple[str, str | None]]:
    """The run's columns: ``env_id``, then ``tag:NAME`` for each tag, in name order.

    >>> _run_columns("CartPole-v1", {"seed": "3", "policy": "ppo"})
    [('env_id', 'CartPole-v1'), ('tag:policy', 'ppo'), ('tag:seed', '3')]
    """
    return [("env_id", env_id), *((f"tag:{k}", tags[k]) for k in sorted(tags))]


def _with_run(table: pa.Table, columns: list[tuple[str, str | None]]) -> pa.Table:
    """``table`` with the run's columns added last (one value repeated on every row).

    A tag whose column name is already taken by a step or episode column is left out there.
    """
    for name, value in columns:
        if name not in table.column_names:
            table = table.append_column(
                name, pa.repeat(pa.scalar(value, pa.string()), table.num_rows)
            )
    return table


def _with_stream(
    table: pa.Table, episodes: pa.Table, env_index: pa.Array, agent: pa.Array
) -> pa.Table:
    """Add each step's ``env_index`` and ``agent`` (from its episode) after ``file``."""
    where = pc.index_in(table.column("episode"), value_set=episodes.column("episode"))
    table = table.add_column(1, "env_index", pc.take(env_index, where))
    return table.add_column(2, "agent", pc.take(agent, where))
