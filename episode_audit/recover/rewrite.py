"""Recovery step by step: open the input, copy what is intact, finish and publish the output."""

from __future__ import annotations

import json
import os
import shutil
from datetime import datetime, timezone
from pathlib import Path

import pyarrow.compute as pc
from mcap.records import Header

from .._version import __version__
from ..errors import ConfigurationError, CorruptEvidenceError, EvidenceError
from ..format import names as fmt
from ..format.paths import path_argument
from ..format.run_end import RunEnd
from ..read import RECOVER_HINT, DamagedRegion, Evidence, FileEnd, iter_records, open_evidence
from ..read.layout import _MAGIC
from ..read.liveness import still_written, writer_of
from ..read.storage import RemoteFile, as_output, is_url
from ..record.published import no_space
from ..record.writer import EvidenceWriter
from .copying import RecordCopy
from .files import Temporary, check_paths, temporary
from .kept import Kept
from .remote import recover_remote
from .result import CLOSING_MAGIC, RecoveryResult, record_name

__all__ = ["recover"]


def recover(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    overwrite_option: str = "overwrite=True",
) -> RecoveryResult:
    """Rewrite the evidence file ``path`` as a finished, indexed file ``out``.

    Every complete, intact chunk is kept, with the run metadata; damaged chunks and the torn
    tail are dropped; the run-end record has ``status=recovered`` and says what was dropped
    (see ``docs/format.md``).
    Episodes without an end record stay ``incomplete`` (``ended`` false), as a reader of the
    torn file sees them. A finished input that reads whole (as ``check`` reads it) is copied
    unchanged; one whose content the reader refuses is refused with the reader's error. The
    input is never changed; the output is written next to ``out`` and renamed into place once
    finished. Either may be a URL (``s3://`` …, ``docs/storage.md``): a remote input is
    downloaded to a temporary file first, and a remote output uploaded once finished.

    Raises :class:`~episode_audit.errors.ConfigurationError` when ``path`` or ``out`` is not a
    path (:func:`~episode_audit.format.paths.path_argument`), when ``out`` is the input, exists
    (without ``overwrite``; the error names it ``overwrite_option``, ``--overwrite`` on the
    command line) or cannot be created, when either file is still being written by a
    live recorder (``path`` is then not torn: its ``close()`` will finish it), and
    :class:`~episode_audit.errors.EvidenceError` (and its subclasses) when the input is not
    readable evidence, or is a torn file that holds nothing to recover (its run metadata, no
    episode, reset or step: no output is written then).

    >>> import tempfile, pathlib, gymnasium as gym, numpy as np
    >>> from episode_audit import RecordEvidence, open_evidence
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> env = RecordEvidence(gym.make("Pendulum-v1"), d / "run.mcap", block_steps=8)
    >>> _ = env.reset(seed=0)
    >>> for _ in range(20):
    ...     _ = env.step(np.zeros(1, np.float32))
    >>> env.flush()  # (the loop's own flushes write in the background: this waits)
    >>> data = (d / "run.mcap").read_bytes()   # 20 steps flushed; as a killed process leaves it
    >>> _ = (d / "torn.mcap").write_bytes(data[:-10])
    >>> env.close()
    >>> result = recover(d / "torn.mcap", d / "fixed.mcap")
    >>> result.lost, result.steps, result.cut_off_episodes
    (True, 20, (0,))
    >>> open_evidence(d / "fixed.mcap").run_end["status"]
    'recovered'
    """
    path, out = path_argument("path", path), path_argument("out", out)
    target = as_output(out)  # (``s3:/b/x``, a slash short of a URL, refused)
    if is_url(path) or isinstance(target, RemoteFile):  # (through a local temporary copy)
        return recover_remote(path, out, overwrite, recover, overwrite_option)
    src, dst = Path(path), Path(target)
    check_paths(src, dst, overwrite, overwrite_option)
    ev = _open_input(src)
    _refuse_live(ev, dst)
    tmp = temporary(dst, overwrite_option)
    try:
        if ev.finished and not (ev.summary_damage or ev.run_end_damage) and _intact(src, ev):
            result = _copy_unchanged(src, ev, tmp.path, dst)
        else:
            result = _rewrite(src, tmp, dst, ev.summary_damage)
            check = open_evidence(tmp.path)
            if not check.finished:  # pragma: no cover - the writer finished it just now
                raise CorruptEvidenceError(dst, f"the recovered file is unfinished: {check.torn}")
        tmp.publish(overwrite)
    except OSError as exc:
        full = no_space(dst, exc)
        if full is None:
            raise
        raise full from None
    finally:
        tmp.discard()
    return result


def _open_input(src: Path) -> Evidence:
    """Open the input; one whose first chunk is damaged has no channel definitions left."""
    try:
        return open_evidence(src)
    except CorruptEvidenceError as exc:
        if not exc.problem.endswith(RECOVER_HINT):
            raise
        # (an unfinished file: only its first chunk was read, for the channel definitions)
        raise CorruptEvidenceError(
            src,
            f"{exc.problem.removesuffix(RECOVER_HINT)}: it holds the channel definitions and "
            "the file has no summary that repeats them, so no chunk can be decoded",
        ) from None


def _refuse_live(ev: Evidence, dst: Path) -> None:
    """A file a live recorder still writes is not torn: neither input nor output of a recovery."""
    if ev.writer is not None:
        raise ConfigurationError(
            f"{ev.path}: is {still_written(ev.writer)}, not torn; wait for it to close (its "
            "close() finishes the file: nothing to recover), or stop that recorder first"
        )
    writer = writer_of(dst)
    if writer is not None:
        raise ConfigurationError(
            f"{dst}: is {still_written(writer)}; recovery never replaces a live recorder's "
            "file — choose another output path"
        )


def _intact(path: Path, ev: Evidence) -> bool:
    """Whether the finished file ``path`` (opened as ``ev``) reads whole, as the audit reads it.

    A walk over every record meets no damage, and a full read (every block decoded and
    checked, the spaces' codecs built) raises nothing. Damage a recovery can skip gives
    False; anything else the reader refuses is raised, as the other commands raise it:
    copying the file would not make it readable.
    """
    if any(isinstance(item, DamagedRegion) for item in iter_records(path, skip_damaged=True)):
        return False
    try:  # in the order ``check`` reads a file, so that the first problem is the same
        ev.observation_codec  # noqa: B018 - built (and checked) on first use
        ev.action_codec  # noqa: B018
        ev.steps_schema  # noqa: B018
        for _ in ev.iter_step_batches():
            pass
        ev.resets()
        ev.episodes()
    except CorruptEvidenceError as exc:
        if exc.problem.endswith(RECOVER_HINT):
            return False
        raise
    return True


def _copy_unchanged(src: Path, ev: Evidence, tmp: Path, dst: Path) -> RecoveryResult:
    """A finished, intact input (``ev``, opened from ``src``): copied byte for byte."""
    try:
        shutil.copyfile(src, tmp)
    except OSError as exc:
        full = no_space(dst, exc)
        raise full or ConfigurationError(f"{dst}: cannot write: {exc.strerror}") from None
    lengths = ev.episodes()["length"]
    steps = int(pc.sum(lengths).as_py() or 0)
    size = src.stat().st_size
    return RecoveryResult(src, dst, True, 0, 0, len(lengths), steps, (), 0, None, size)


def _rewrite(src: Path, tmp: Temporary, dst: Path, summary_damage: str | None) -> RecoveryResult:
    """Copy ``src``'s complete, intact records into the new file ``tmp`` and finish it."""
    records = iter_records(src, skip_damaged=True)
    header = next(records)
    if not isinstance(header, Header):  # open_evidence found one: the walk does too
        raise CorruptEvidenceError(src, "the first record is not an MCAP header")
    writer = EvidenceWriter(tmp.path, library=header.library, overwrite=True)  # (ours)
    try:
        copy = RecordCopy(src, writer)
        end = copy.copy(records)
        _refuse_empty(src, copy)
        # What the output holds so far (an unfinished file, read as a torn one) says which
        # episodes were cut off, and with damage, which lost evidence.
        try:
            kept = Kept.of(
                tmp.path, copy.damage, closed=copy.closed, run_end=RunEnd.of(copy.run_end)
            )
        except EvidenceError as exc:  # what it copied from src: name src
            raise type(exc)(src, exc.problem) from None
        result = _result(src, dst, copy, end, kept, summary_damage)
        writer.finish(_run_end(src, copy, kept, result))
    except BaseException:
        writer.abandon()
        raise
    return result


def _refuse_empty(src: Path, copy: RecordCopy) -> None:
    """An unfinished input with no message copied holds nothing to recover: no output is made.

    Its recorder was killed before its first flush (or every chunk it flushed is damaged): no
    episode, reset or step survives, and a copy would be an empty file said to be recovered.
    """
    if copy.messages or copy.closed:
        return
    why = (
        "every chunk it holds is damaged"
        if copy.damaged
        else "its recorder was killed before its first flush"
    )
    raise EvidenceError(
        src,
        f"nothing to recover: the file holds its run metadata but no episode, reset or step "
        f"({why}); no output was written",
    )


def _result(
    src: Path, dst: Path, copy: RecordCopy, end: FileEnd, kept: Kept, summary_damage: str | None
) -> RecoveryResult:
    """What the rewrite kept, and what it dropped at the torn end and in damaged stretches."""
    dropped = end.size - end.offset if not end.footer else 0
    kind = record_name(end.cut_opcode) if dropped and end.cut_opcode is not None else None
    if dropped == len(_MAGIC) and _last_bytes(src, dropped) == _MAGIC:
        kind = CLOSING_MAGIC  # (after a damaged footer: no record, no evidence)
    return RecoveryResult(
        src,
        dst,
        False,
        copy.chunks,
        copy.messages,
        kept.episodes,
        copy.steps,
        kept.cut_off,
        dropped,
        kind,
        end.size - dropped,
        copy.closed,
        tuple(copy.damaged),
        kept.damaged,
        copy.damage == "at the end" and not copy.closed,
        summary_damage,
        copy.run_end_damage,
    )


def _last_bytes(path: Path, n: int) -> bytes:
    """The last ``n`` bytes of the file at ``path`` (``b""`` when it cannot be read)."""
    try:
        with open(path, "rb") as f:
            f.seek(-n, os.SEEK_END)
            return f.read(n)
    except OSError:
        return b""


def _run_end(src: Path, copy: RecordCopy, kept: Kept, result: RecoveryResult) -> dict[str, str]:
    """The output's run-end record: ``status=recovered``, what was kept and what dropped."""
    old = copy.run_end or {}
    return {
        "status": fmt.RUN_STATUS_RECOVERED,
        "episodes": str(kept.episodes),
        "steps": str(copy.steps),
        "blocks": str(copy.blocks),
        "end_time": old.get("end_time") or _iso(copy.last_time),
        "recovered_from": str(src),
        "recovered_by": f"episode-audit {__version__}",
        "recovered_time": datetime.now(timezone.utc).isoformat(),
        "dropped": result.dropped,
        "dropped_bytes": str(result.dropped_bytes),
        "cut_off_episodes": json.dumps(list(kept.cut_off)),
        "damaged": json.dumps(
            [{"offset": d.offset, "length": d.length, "why": d.why} for d in copy.damaged]
        ),
        "damaged_episodes": kept.damaged.to_json(),
        # (said of the original's run: whether its task reports success, and what its recorder
        # failed at and dropped, which the copy is missing too)
        **{key: value for key, value in old.items() if key in _CARRIED},
    }


_CARRIED = frozenset(
    {
        fmt.RUN_END_SUCCESS_REPORTED,
        fmt.RUN_END_TROUBLE,
        fmt.RUN_END_FIRST_TROUBLE,
        fmt.RUN_END_LOST_STEPS,
        fmt.RUN_END_LOST_RESETS,
        fmt.RUN_END_LOST_EPISODES,
    }
)
"""The keys of the original's run-end record its recovered copy keeps."""


def _iso(time_ns: int) -> str:
    return datetime.fromtimestamp(time_ns / 1e9, timezone.utc).isoformat()
