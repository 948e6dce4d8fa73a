"""Export evidence to Parquet for pandas, polars and DuckDB.

For each input file ``run.mcap``, :func:`export` writes ``run.steps.parquet`` (one row per step,
streamed block by block) and adds its episodes to ``episodes.parquet`` (all files together), both
with a ``file`` column; :class:`ExportResult` says what it wrote. Output names come from the
input paths only, never from file content. Columns and queries: ``docs/cli.md`` ("export").
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from .errors import ConfigurationError, EvidenceError
from .read import open_evidence
from .record.lock import output_kind

__all__ = ["ExportResult", "export"]


@dataclass
class ExportResult:
    """What :func:`export` wrote."""

    episodes_file: Path
    steps_files: list[Path] = field(default_factory=list)
    episodes: int = 0
    steps: int = 0
    failed: list[Path] = field(default_factory=list)
    """Inputs that could not be read to the end (only with ``on_error``); nothing of theirs
    is in the output."""
    removed: list[Path] = field(default_factory=list)
    """With ``overwrite``: ``*.steps.parquet`` files of an earlier export that this one did not
    write, removed so that ``read_parquet('DIR/*.steps.parquet')`` reads this export only."""
    unfinished: list[tuple[Path, str]] = field(default_factory=list)
    """Inputs exported while unfinished (still being written, or torn), and why."""

    @property
    def notes(self) -> list[str]:
        """A line for each unfinished input: what of it was exported."""
        return [
            f"{path} is unfinished ({why}): exported what it holds, its cut-off episode as "
            "incomplete"
            for path, why in self.unfinished
        ]

    def summary(self) -> str:
        """One line for people: what was written where."""
        removed = f"; removed {len(self.removed)} from an earlier export" if self.removed else ""
        return (
            f"wrote {self.episodes} episodes to {self.episodes_file} and {self.steps} steps "
            f"to {len(self.steps_files)} *.steps.parquet file(s) in {self.episodes_file.parent}"
            f"{removed}"
        )


class _Exported(NamedTuple):
    """One input's part of the export."""

    episodes: pa.Table
    steps: int
    unfinished: str | None
    """Why the input is unfinished (``None``: finished)."""


def export(
    paths: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    on_error: Callable[[EvidenceError], None] | None = None,
) -> ExportResult:
    """Write the steps and episodes of ``paths`` as Parquet files into ``out_dir``.

    Existing output files are not replaced unless ``overwrite=True``, which replaces the export
    in ``out_dir``: ``*.steps.parquet`` files there that this export does not write (an earlier
    export's) are removed (:attr:`ExportResult.removed`). An input that cannot
    be read to the end (e.g. a damaged chunk) raises :class:`~episode_audit.errors.EvidenceError`;
    with ``on_error``, it is handed the error instead, the input is listed in
    :attr:`ExportResult.failed` with nothing of it in the output, and the others are exported.

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
    out = _output_directory(Path(out_dir))
    result = ExportResult(out / "episodes.parquet")
    sources = [Path(p) for p in paths]
    targets = [out / f"{name}.steps.parquet" for name in _step_file_names(sources)]
    _refuse_special_files([result.episodes_file, *targets])
    if not overwrite:
        existing = [t for t in [result.episodes_file, *targets] if t.exists()]
        if existing:
            raise ConfigurationError(
                f"{existing[0]}: exists; pass --overwrite to replace exported files"
            )
    episode_tables: list[pa.Table] = []
    for source, target in zip(sources, targets, strict=True):
        try:
            exported = _export_one(source, target, progress)
        except EvidenceError as exc:
            if on_error is None:
                raise
            on_error(exc)
            result.failed.append(source)
            continue
        episode_tables.append(exported.episodes)
        result.steps += exported.steps
        result.steps_files.append(target)
        if exported.unfinished is not None:
            result.unfinished.append((source, exported.unfinished))
    episodes = pa.concat_tables(episode_tables) if episode_tables else pa.table({})
    pq.write_table(episodes, result.episodes_file, compression="zstd")
    result.episodes = episodes.num_rows
    if overwrite:  # the export in out_dir is this one: an earlier one's steps files go
        result.removed = _remove_stale(out, set(result.steps_files))
    return result


def _output_directory(out: Path) -> Path:
    """``out``, created if needed; a path that is not a directory is a usage error."""
    if out.exists() and not out.is_dir():
        raise ConfigurationError(f"{out}: not a directory; --out names the directory to write to")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigurationError(f"{out}: cannot create the directory: {exc.strerror}") from None
    return out


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


def _step_file_names(sources: Sequence[Path]) -> list[str]:
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


def _remove_stale(out: Path, written: set[Path]) -> list[Path]:
    """Remove the ``*.steps.parquet`` files in ``out`` this export did not write."""
    removed: list[Path] = []
    for stale in sorted(out.glob("*.steps.parquet")):
        if stale not in written and stale.is_file():
            stale.unlink()
            removed.append(stale)
    return removed


def _export_one(source: Path, target: Path, progress: Callable[[int], None] | None) -> _Exported:
    """Write ``source``'s steps to ``target``; return its episodes (with ``file``), steps, state.

    On any failure no ``target`` is left behind: a half-written file must not look complete.
    """
    ev = open_evidence(source)
    unfinished = None if ev.finished else ev.torn or "no run-end record"
    label = str(source)
    episodes = ev.episodes()
    # Vector and PettingZoo files: each step row names its sub-env and agent too.
    multi = (ev.run.layout or {}).get("kind", "single") != "single"
    env_index = episodes.column("env_index").combine_chunks()
    agent = episodes.column("agent").combine_chunks()
    writer: pq.ParquetWriter | None = None
    steps = 0
    try:
        for batch in ev.iter_step_batches():
            table = _with_file(batch, label)
            if multi:
                table = _with_stream(table, episodes, env_index, agent)
            if writer is None:
                writer = pq.ParquetWriter(target, table.schema, compression="zstd")
            writer.write_table(table)
            steps += table.num_rows
            if progress is not None:
                progress(table.num_rows)
    except BaseException:
        if writer is not None:
            writer.close()
            target.unlink(missing_ok=True)
        raise
    if writer is not None:
        writer.close()
    else:  # no steps at all: still write an empty, typed file
        pq.write_table(_with_file(ev.steps_schema.empty_table(), label), target)
    return _Exported(_with_file(episodes, label), steps, unfinished)


def _with_file(batch: pa.RecordBatch | pa.Table, name: str) -> pa.Table:
    table = pa.Table.from_batches([batch]) if isinstance(batch, pa.RecordBatch) else batch
    return table.add_column(0, "file", pa.array([name] * table.num_rows, pa.string()))


def _with_stream(
    table: pa.Table, episodes: pa.Table, env_index: pa.Array, agent: pa.Array
) -> pa.Table:
    """Add each step's ``env_index`` and ``agent`` (from its episode) after ``file``."""
    where = pc.index_in(table.column("episode"), value_set=episodes.column("episode"))
    table = table.add_column(1, "env_index", pc.take(env_index, where))
    return table.add_column(2, "agent", pc.take(agent, where))
