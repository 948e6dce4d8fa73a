"""The library behind ``episode-audit report``: a command's inputs and options, reported.

:func:`report_inputs` takes the options as the command line gives them (``--max-failure-rate``
as ``RATE`` or ``LABEL=RATE`` strings) and checks them in its words, opens the files the paths
name (going past the unreadable ones), checks that ``--games`` fits them, and reports them with
:func:`~.core.report_tables`: an :class:`InputsReport`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from .._jobs import map_ordered
from ..errors import ConfigurationError, EpisodeAuditError
from ..read import open_evidence
from ..read.inputs import Unreadable, listed_inputs
from ..read.storage import Source
from .collect import is_by
from .core import FilePart, Report, file_part, report_parts
from .gates import Gates, check_gateable, is_rate

__all__ = ["InputsReport", "failure_rates", "gates_from_options", "report_inputs"]


@dataclass(frozen=True)
class InputsReport:
    """The report of the readable inputs, and the inputs that could not be read."""

    report: Report
    unreadable: list[Unreadable]
    readable: int
    """How many inputs were read (the report is of those)."""
    files: list[Source] = field(default_factory=list)
    """The inputs that were read, in order."""
    parts: list[FilePart] = field(default_factory=list)
    """What the report took from each input read, in order (the HTML report's episodes:
    :func:`~.html.write_report_html` lists them without reading a file again)."""
    exports: list[Source] = field(default_factory=list)
    """The viewer exports found in the directories given, left out (not evidence)."""


def report_inputs(
    paths: Sequence[str | os.PathLike[str]],
    *,
    by: str = "file",
    games: bool = False,
    min_success_rate: float | None = None,
    max_failure_rate: Sequence[str] = (),
    max_truncation_rate: float | None = None,
    max_error_rate: float | None = None,
    fail_on_incentive_warning: bool = False,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
    filesystem: Any = None,
    storage_options: dict[str, Any] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> InputsReport:
    """Report the evidence files ``paths`` name (directories are searched for ``*.mcap``).

    The viewer exports found in directories are left out (:attr:`InputsReport.exports`).
    ``paths`` may be URLs, read through ``filesystem`` or ``storage_options``
    (:func:`~episode_audit.read.evidence_files`).

    The options are those of ``episode-audit report``, checked in that order, each problem a
    :class:`~episode_audit.errors.ConfigurationError` naming the option. A file that cannot be
    read (its episodes included) is handed to ``on_error`` and listed in
    :attr:`InputsReport.unreadable`, so one bad file costs the others nothing. ``jobs`` and
    ``ray_address`` spread the reading of the files as :func:`~episode_audit.check.check` does;
    ``progress`` is called with 1 as each file is read (as a run of files is, from workers).
    """
    if not is_by(by):
        raise ConfigurationError(
            f"--by: expected file, env, env_index, agent, label, all or tag:NAME, got {by!r}"
        )
    if games and by == "agent":
        raise ConfigurationError("--games cannot be grouped --by agent: a game has many agents")
    gates = gates_from_options(
        min_success_rate=min_success_rate,
        max_failure_rate=max_failure_rate,
        max_truncation_rate=max_truncation_rate,
        max_error_rate=max_error_rate,
        fail_on_incentive_warning=fail_on_incentive_warning,
    )
    check_gateable(by, gates)
    inputs = listed_inputs(paths, filesystem=filesystem, storage_options=storage_options)
    files = inputs.files
    parts: list[FilePart] = []
    read_files: list[Source] = []
    unreadable: list[Unreadable] = []
    one = partial(_file_part, by=by, games=games)
    kinds: list[str] = []
    read = map_ordered(one, files, jobs=jobs, ray_address=ray_address, progress=progress)
    for path, got in zip(files, read, strict=True):
        if isinstance(got, EpisodeAuditError):
            if on_error is not None:
                on_error(got)
            unreadable.append(Unreadable.of(path, got))
        else:
            parts.append(got[0])
            read_files.append(path)
            kinds.append(got[1])
    if games:  # a file without games would count nothing, and every gate would pass
        for part, kind in zip(parts, kinds, strict=True):
            _check_games_fit(part.name, kind)
    result = report_parts(parts, by=by, gates=gates, games=games)
    return InputsReport(result, unreadable, len(parts), read_files, parts, inputs.exports)


def _file_part(
    path: Source, progress: Callable[[int], None] | None, *, by: str, games: bool
) -> tuple[FilePart, str] | EpisodeAuditError:
    """One input's part of the report and its layout kind, or why it cannot be read.

    (Run in a worker, maybe.)

    Reading the file's episodes here puts a file damaged past its start with the unreadable
    ones instead of stopping the report of the others.
    """
    try:
        ev = open_evidence(path)
        part = file_part(str(path), ev, by, games)
    except EpisodeAuditError as exc:
        return exc
    finally:
        if progress is not None:
            progress(1)
    return part, str((ev.run.layout or {}).get("kind", "single"))


def gates_from_options(
    *,
    min_success_rate: float | None = None,
    max_failure_rate: Sequence[str] = (),
    max_truncation_rate: float | None = None,
    max_error_rate: float | None = None,
    fail_on_incentive_warning: bool = False,
) -> Gates:
    """The :class:`~.gates.Gates` of the command line's options, checked in their words.

    ``max_failure_rate`` holds ``RATE`` (overall) and ``LABEL=RATE`` (one label) strings.

    >>> gates_from_options(max_failure_rate=["0.2", "collision=0.05"]).max_failure_rate_by_label
    {'collision': 0.05}
    >>> try:
    ...     gates_from_options(max_failure_rate=["=0.1"])
    ... except ConfigurationError as exc:
    ...     print(exc)
    --max-failure-rate: expected RATE or LABEL=RATE, got '=0.1' (no label)
    """
    overall, by_label = failure_rates(max_failure_rate)
    return Gates(
        min_success_rate=_rate_option("--min-success-rate", min_success_rate),
        max_failure_rate=overall,
        max_failure_rate_by_label=by_label,
        max_truncation_rate=_rate_option("--max-truncation-rate", max_truncation_rate),
        max_error_rate=_rate_option("--max-error-rate", max_error_rate),
        fail_on_incentive_warning=fail_on_incentive_warning,
    )


def failure_rates(
    values: Sequence[str], option: str = "--max-failure-rate"
) -> tuple[float | None, dict[str, float]]:
    """``option``'s values (``RATE`` or ``LABEL=RATE``): the overall rate and those by label.

    Each checked in the option's words; a rate given twice (overall, or for one label) is
    refused, naming both values: the second would silently replace the first.

    >>> failure_rates(["0.1", "fell=0.2", "fell=0.5"])
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: --max-failure-rate: given twice for the label \
'fell' ('fell=0.2' and 'fell=0.5'); give each gate once
    """
    given: dict[str, str] = {}
    overall: float | None = None
    by_label: dict[str, float] = {}
    for value in values:
        label, sep, rate = value.rpartition("=")
        try:
            number = float(rate)
        except ValueError:
            raise ConfigurationError(
                f"{option}: expected RATE or LABEL=RATE, got {value!r}"
            ) from None
        if not is_rate(number):
            raise ConfigurationError(f"{option}: expected a rate between 0 and 1, got {rate!r}")
        if sep and not label:
            raise ConfigurationError(
                f"{option}: expected RATE or LABEL=RATE, got {value!r} (no label)"
            )
        what = f"the label {label!r}" if sep else "all failures"
        if what in given:
            raise ConfigurationError(
                f"{option}: given twice for {what} ({given[what]!r} and {value!r}); give each "
                "gate once"
            )
        given[what] = value
        if sep:
            by_label[label] = number
        else:
            overall = number
    return overall, by_label


def _rate_option(name: str, value: float | None) -> float | None:
    if value is not None and not is_rate(value):
        raise ConfigurationError(f"{name}: expected a rate between 0 and 1, got {value}")
    return value


def _check_games_fit(path: str, kind: str) -> None:
    """``--games`` counts PettingZoo games: a file of another ``kind`` has none."""
    if not kind.startswith("pettingzoo"):
        what = "single-env" if kind == "single" else kind
        raise ConfigurationError(
            f"--games counts PettingZoo games; {path} is a {what} file (drop --games)"
        )
