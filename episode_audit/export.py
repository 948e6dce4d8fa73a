"""Export evidence to Parquet for pandas, polars and DuckDB.

For each input file ``run.mcap``, :func:`export` writes ``run.steps.parquet`` (one row per step)
and adds its episodes to ``episodes.parquet`` (one row per episode, all files together). Both carry
a ``file`` column naming the evidence file; steps of vector and PettingZoo files also carry their
episode's ``env_index`` and ``agent``. Steps are streamed block by block, so memory stays flat.
Output names come from the input paths only, never from file content.

Query every file at once with DuckDB: ``SELECT * FROM read_parquet('out/*.steps.parquet',
union_by_name=true)``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from .errors import ConfigurationError, EvidenceError
from .read import open_evidence

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
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigurationError(f"{out}: not a directory; --out names the directory to write to")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigurationError(f"{out}: cannot create the directory: {exc.strerror}") from None
    result = ExportResult(out / "episodes.parquet")
    targets: list[Path] = [result.episodes_file]
    sources = [Path(p) for p in paths]
    used: set[str] = set()
    names: list[str] = []
    for source in sources:
        stem = source.stem
        name = stem
        k = 1
        while name in used:
            k += 1
            name = f"{stem}-{k}"
        used.add(name)
        names.append(name)
        targets.append(out / f"{name}.steps.parquet")
    if not overwrite:
        existing = [t for t in targets if t.exists()]
        if existing:
            raise ConfigurationError(
                f"{existing[0]}: exists; pass --overwrite to replace exported files"
            )
    episode_tables: list[pa.Table] = []
    for source, name in zip(sources, names, strict=True):
        target = out / f"{name}.steps.parquet"
        try:
            episodes, steps = _export_one(source, target, progress)
        except EvidenceError as exc:
            if on_error is None:
                raise
            on_error(exc)
            result.failed.append(source)
            continue
        episode_tables.append(episodes)
        result.steps += steps
        result.steps_files.append(target)
    episodes = pa.concat_tables(episode_tables) if episode_tables else pa.table({})
    pq.write_table(episodes, result.episodes_file, compression="zstd")
    result.episodes = episodes.num_rows
    if overwrite:  # the export in out_dir is this one: an earlier one's steps files go
        written = set(result.steps_files)
        for stale in sorted(out.glob("*.steps.parquet")):
            if stale not in written and stale.is_file():
                stale.unlink()
                result.removed.append(stale)
    return result


def _export_one(
    source: Path, target: Path, progress: Callable[[int], None] | None
) -> tuple[pa.Table, int]:
    """Write ``source``'s steps to ``target``; return its episodes (with ``file``) and steps.

    On any failure no ``target`` is left behind: a half-written file must not look complete.
    """
    ev = open_evidence(source)
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
    return _with_file(episodes, label), steps
