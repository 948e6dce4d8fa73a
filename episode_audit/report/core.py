"""A report of evidence files: their groups of episodes and the gates checked against each.

:func:`report` opens files and reports them; :func:`report_tables` reports files already
opened; both return a :class:`Report`. Rates, denominators, warnings and the JSON shape:
``docs/reporting.md``.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import pyarrow.compute as pc

from .._jobs import map_ordered
from ..errors import ConfigurationError
from ..format.run_end import RunEnd
from ..read import Evidence, open_evidence
from ..read.arguments import path_list
from .collect import NONE_KEY, FileRows, check_by, file_key, file_rows, joined
from .gates import GateResult, Gates, check_gateable, check_gates, unmatched_labels, unmatched_why
from .groups import GroupReport, group_reports
from .wrapped import Chain, Wrapped, file_chain

__all__ = [
    "BY_LABEL_NOTE",
    "DROPPED_TITLE",
    "UNFINISHED_TITLE",
    "FilePart",
    "Report",
    "check_runs_apart",
    "file_part",
    "missing_tag",
    "missing_tag_note",
    "report",
    "report_parts",
    "report_tables",
    "run_identity",
]


BY_LABEL_NOTE = (
    "by label: each group holds one outcome, so its success, failure and truncation rates "
    "(0 or 1 by construction) and incentive warnings (which set a group's outcomes against "
    "each other) are not computed; report by file, env, all or tag:NAME for them"
)
"""The note of a report grouped by label."""

UNFINISHED_TITLE = "Unfinished files (still being written, or torn): counts so far"
"""The title of the table of :attr:`Report.unfinished` (terminal, Markdown and HTML)."""

DROPPED_TITLE = "Files missing what their recorder dropped: counts over what they hold"
"""The title of the table of :attr:`Report.dropped` (terminal, Markdown and HTML)."""


@dataclass
class Report:
    """Groups of episodes with their rates, and the gates checked against each group.

    :meth:`to_dict` returns the JSON shape of ``docs/reporting.md`` (stable; new keys may be
    added, none removed). An unfinished file (its writer is still running, or was killed) is
    reported with what was flushed so far; ``unfinished`` names it, so a rate over a live file
    is never mistaken for a final one. A finished file whose recorder dropped what it could
    not write (a full disk) is reported with what it holds; ``dropped`` names it and says what
    was dropped. ``wrapped`` counts the files recorded over reward wrappers, whose returns are
    not the env's (:attr:`reward_note` says so).
    """

    by: str
    groups: list[GroupReport]
    gates: list[GateResult]
    unfinished: list[tuple[str, str]] = field(default_factory=list)
    unit: str = "episode"
    unmatched_labels: list[str] = field(default_factory=list)
    missing_tag: str | None = None
    wrapped: Wrapped = field(default_factory=Wrapped)
    """The files recorded over reward wrappers, whose returns are not the env's."""
    dropped: list[tuple[str, str]] = field(default_factory=list)
    """``(file, what)`` of the files whose recorder dropped rows or records it could not write."""

    @property
    def reward_note(self) -> str | None:
        """One line (80 columns) when some files' returns are a reward wrapper's, else ``None``.

        Said once in each output: under the outcomes table, in JSON as ``reward_wrappers``
        (:meth:`to_dict`), among the HTML page's notes.
        """
        return self.wrapped.note()

    @property
    def notes(self) -> list[str]:
        """What the report's options matched nothing of, and what it could not use, a line each.

        A per-label failure gate on a label no failure has; ``by="label"``, whose groups have
        no rates nor warnings (:data:`BY_LABEL_NOTE`); ``by="tag:NAME"`` with a tag no file
        has; a group whose returns are in different units (reward wrappers); a group with
        returns that are not finite.
        """
        seen = sorted({label for group in self.groups for label in group.failures})
        labels = ", ".join(map(repr, seen)) if seen else "none"
        notes = [
            f"gate max_failure_rate:{label}: {unmatched_why(label)} (labels seen: {labels})"
            for label in self.unmatched_labels
        ]
        if self.by == "label":
            notes.append(BY_LABEL_NOTE)
        if self.missing_tag is not None:
            notes.append(missing_tag_note(self.missing_tag))
        for group in self.groups:
            if group.mixed_rewards:
                notes.append(
                    f"group {group.key}: its files were recorded over different reward wrappers "
                    "or settings (or some over none), so its returns are in different units: no "
                    "return mean, and no incentive warning that compares returns"
                )
            if group.nonfinite_returns:
                notes.append(
                    f"group {group.key}: {group.nonfinite_returns} of {group.ended} ended "
                    "episodes have a return that is not finite (NaN or infinite): the return's "
                    "mean and spread are not finite, and the incentive warnings leave those "
                    "episodes out (`episode-audit check` finds them)"
                )
        return notes

    @property
    def passed(self) -> bool:
        """Whether every gate passed for every group (``True`` when there are no gates)."""
        return all(g.passed for g in self.gates)

    def to_dict(self) -> dict[str, Any]:
        """Return the report in the JSON shape of ``docs/reporting.md``."""
        return {
            "by": self.by,
            "passed": self.passed,
            "groups": [g.to_dict() for g in self.groups],
            "gates": [
                {"gate": g.gate, "group": g.group, "passed": g.passed, "message": g.message}
                for g in self.gates
            ],
            "unfinished": [{"file": name, "why": why} for name, why in self.unfinished],
            "unit": self.unit,
            "unmatched_labels": list(self.unmatched_labels),
            "notes": self.notes,
            "reward_wrappers": self.wrapped.to_json(),
            "dropped": [{"file": name, "what": what} for name, what in self.dropped],
        }


def report_tables(
    sources: Iterable[tuple[str, Evidence]],
    *,
    by: str = "file",
    gates: Gates | None = None,
    games: bool = False,
) -> Report:
    """Report the episodes of opened evidence files, given as ``(name, evidence)`` pairs.

    ``name`` is the group key for ``by="file"``. See :func:`report` for ``by``, ``gates`` and
    ``games``.
    """
    check_by(by)
    parts = [file_part(name, ev, by, games) for name, ev in sources]
    return report_parts(parts, by=by, gates=gates, games=games)


@dataclass(frozen=True)
class FilePart:
    """What a report takes from one file (:func:`file_part`), small enough to send back."""

    name: str
    rows: FileRows
    unfinished: str | None
    """Why the file is unfinished (``None``: finished)."""
    tags: frozenset[str]
    """The names of the file's run tags."""
    reward_wrappers: Chain = ()
    """The reward wrappers the file was recorded over (:func:`~.wrapped.file_chain`)."""
    dropped: str | None = None
    """What the file's recorder dropped, in words (``None``: nothing)."""
    key: str | None = None
    """The group every episode of the file is in, when the grouping gives a file one
    (:func:`~.collect.file_key`): a file that holds none is a group of 0 episodes then."""
    run: str = ""
    """The identity of the file's run (:func:`run_identity`; ``""``: unknown)."""


def file_part(name: str, ev: Evidence, by: str, games: bool = False) -> FilePart:
    """The part of a report that comes from the file ``ev`` (``name``: its key by file)."""
    unfinished = None if ev.finished else ev.torn or "no run-end record"
    tags = frozenset(map(str, ev.run.tags or {}))
    rows = file_rows(name, ev, by, games)
    if unfinished is not None and ev.writer is None and _holds_nothing(ev, rows):
        unfinished += f"; {LOST}"
    lost = RunEnd.of(ev.run_end).lost
    dropped = (
        f"the recorder dropped {lost} it could not write (episode-audit check says why)"
        if lost
        else None
    )
    return FilePart(
        name, rows, unfinished, tags, file_chain(ev), dropped, file_key(name, ev, by),
        run_identity(ev),
    )  # fmt: skip


def run_identity(ev: Evidence) -> str:
    """The identity of the run ``ev`` recorded (``""``: unknown, or nothing to count twice).

    A digest of its run metadata (written once, with the time the run began to the
    microsecond) and of its first episode's start time in nanoseconds: a copy of the file, and
    a copy ``episode-audit recover`` made of it, keep both as they were; runs that workers
    started at once with one configuration (the same metadata to the microsecond) do not
    share the nanosecond their first episode began. Two files of one identity hold the same
    run: counted together, its episodes count twice (:func:`check_runs_apart`). A file without
    a start time (another writer's), or without an episode, has none.
    """
    episodes = ev.episodes()
    if not ev.run.start_time or not episodes.num_rows:
        return ""
    first = pc.min(episodes.column("start_time_ns")).as_py()
    metadata = json.dumps(ev.run.to_metadata(), sort_keys=True)
    return hashlib.sha256(f"{metadata}\n{first}".encode()).hexdigest()[:32]


def check_runs_apart(parts: Sequence[FilePart], whose: str = "") -> None:
    """Refuse two files of one run (:class:`ConfigurationError`): their episodes would count twice.

    A torn file and the copy ``episode-audit recover`` made of it, or a plain copy; ``whose``
    (``"the baseline's "``) says where they were given.
    """
    first: dict[str, str] = {}
    for part in parts:
        if not part.run:
            continue
        seen = first.setdefault(part.run, part.name)
        if seen != part.name:
            raise ConfigurationError(
                f"{whose}{seen} and {part.name} hold the same run (the same run metadata: a "
                "copy, or a recovered copy beside its torn original), whose episodes would "
                "count twice; pass one of them"
            )


LOST = "no recorder is writing it and it holds no complete chunk: no episode survives"
"""What a torn file that holds nothing adds to why it is unfinished (its evidence is gone)."""


def _holds_nothing(ev: Evidence, rows: FileRows) -> bool:
    """Whether the file holds no episode, reset or step (``rows``: its rows, maybe none)."""
    return rows[0] is None and ev.holds_nothing


def report_parts(
    parts: Sequence[FilePart],
    *,
    by: str = "file",
    gates: Gates | None = None,
    games: bool = False,
) -> Report:
    """Report files from their parts (:func:`file_part`), as :func:`report_tables` does."""
    check_by(by)
    check_gateable(by, gates)
    check_runs_apart(parts)
    unfinished = [(p.name, p.unfinished) for p in parts if p.unfinished is not None]
    groups = group_reports(
        *joined(p.rows for p in parts),
        one_outcome=by == "label",
        empty=[p.key for p in parts if p.key is not None],  # (those of files without episodes)
    )
    return Report(
        by,
        groups,
        check_gates(gates, groups, "file" if by == "file" else "group")
        if gates is not None
        else [],
        unfinished,
        "game" if games else "episode",
        unmatched_labels(gates, groups),
        missing_tag(by, parts),
        Wrapped.of(p.reward_wrappers for p in parts),
        [(p.name, p.dropped) for p in parts if p.dropped is not None],
    )


def missing_tag_note(tag: str) -> str:
    """The note on a ``by="tag:NAME"`` whose tag no file has (:func:`missing_tag`)."""
    return (
        f"by tag:{tag}: no file has the tag {tag!r}, so every episode is in the group "
        f"{NONE_KEY!r}: is the tag spelt as recorded?"
    )


def missing_tag(by: str, parts: Sequence[FilePart]) -> str | None:
    """The tag of ``by="tag:NAME"`` when no file has it (every episode would be ``(none)``)."""
    if not by.startswith("tag:") or not parts:
        return None
    name = by[4:]
    return None if any(name in part.tags for part in parts) else name


def report(
    paths: Iterable[str | os.PathLike[str]],
    *,
    by: str = "file",
    gates: Gates | None = None,
    games: bool = False,
    jobs: int | None = 1,
    ray_address: str | None = None,
) -> Report:
    """Open evidence files and report their episodes, grouped, with gates checked per group.

    ``by`` is ``"file"``, ``"env"`` (the run's env id), ``"env_index"`` (a vector env's
    sub-env index, ``"0"`` for single envs), ``"agent"`` (a PettingZoo agent; ``"(none)"``
    for single-agent files), ``"tag:NAME"`` (a run tag such as
    ``policy`` or ``checkpoint``; ``"(none)"`` when a file lacks it), ``"label"`` (the failure
    label; successes as ``"(success)"``, truncations as ``"(truncated:REASON)"``, and
    ``"(incomplete)"`` / ``"(error)"``: each group one outcome, so no rates nor incentive
    warnings are computed and ``gates`` are refused, :func:`~.gates.check_gateable`) or
    ``"all"``. Torn files count the episodes they hold
    (cut-off ones as incomplete). An unreadable file raises
    :class:`~episode_audit.errors.EvidenceError`. With ``games``, PettingZoo files are
    counted by game instead of by agent-episode, each game's outcome derived from its agents'
    by the rule of :mod:`episode_audit.report.games` (files without games then count nothing).
    ``jobs`` worker processes (``None``: one per usable core) or Ray tasks on ``ray_address``
    read the files (see :mod:`episode_audit._jobs`); the report is the same as with ``jobs=1``.

    Example:
        >>> import tempfile, pathlib, gymnasium as gym
        >>> from episode_audit import RecordEvidence
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.mcap"
        >>> with RecordEvidence(gym.make("CartPole-v1", max_episode_steps=5), path) as env:
        ...     for seed in range(3):
        ...         _ = env.reset(seed=seed)
        ...         for _ in range(5):
        ...             _ = env.step(seed % 2)
        >>> result = report([path], by="env", gates=Gates(max_truncation_rate=0.5))
        >>> (group,) = result.groups
        >>> group.key, group.ended, group.truncations, group.truncation_rate
        ('CartPole-v1', 3, {'time_limit': 3}, 1.0)
        >>> result.passed, result.gates[0].message
        (False, 'truncation rate 1.00 > 0.50 (group CartPole-v1)')
    """
    check_by(by)
    check_gateable(by, gates)
    one = partial(_part_of, by=by, games=games)
    parts = list(map_ordered(one, path_list(paths), jobs=jobs, ray_address=ray_address))
    return report_parts(parts, by=by, gates=gates, games=games)


def _part_of(path: str | os.PathLike[str], progress: object, *, by: str, games: bool) -> FilePart:
    """Open one file and take its part of the report (in a worker, maybe)."""
    return file_part(str(path), open_evidence(path), by, games)
