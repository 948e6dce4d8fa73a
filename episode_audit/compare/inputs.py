"""The library behind ``episode-audit compare``: its inputs and options, compared.

:func:`compare_inputs` takes the options as the command line gives them
(``--max-failure-increase`` as ``RATE`` or ``LABEL=RATE`` strings), checks them in its words,
reads the files each side's paths name (directories are searched for ``*.mcap``; unreadable
files are listed, not compared; ``jobs`` workers read them) and compares them with
:func:`~.core.compare_parts`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

from .._jobs import map_ordered
from ..errors import ConfigurationError, EpisodeAuditError
from ..read import open_evidence
from ..read.inputs import Unreadable, listed_inputs
from ..read.storage import Source
from ..report.inputs import failure_rates
from .core import (
    Comparison,
    SideFile,
    check_apart,
    check_compare_by,
    check_tasks,
    compare_parts,
    side_file,
)
from .groups import RATE_MARGIN, CompareGates, check_limit

__all__ = ["InputsComparison", "compare_inputs", "gates_from_options"]


@dataclass(frozen=True)
class InputsComparison:
    """The comparison of the readable inputs, and the inputs that could not be read."""

    comparison: Comparison
    unreadable: list[Unreadable]
    exports: list[Source] = field(default_factory=list)
    """The viewer exports found in the directories given, left out (not evidence)."""


def compare_inputs(
    baseline: Sequence[str | os.PathLike[str]],
    candidate: Sequence[str | os.PathLike[str]],
    *,
    by: str = "all",
    max_success_drop: float | None = None,
    max_failure_increase: Sequence[str] = (),
    max_return_drop: float | None = None,
    max_error_increase: float | None = None,
    fail_on_new_incentive_warning: bool = False,
    different_tasks: bool = False,
    rate_margin: float = RATE_MARGIN,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
    jobs: int | None = 1,
    ray_address: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> InputsComparison:
    """Compare the evidence files ``candidate`` names with those ``baseline`` names.

    Each problem with the options is a :class:`~episode_audit.errors.ConfigurationError`
    naming the option; a file that cannot be read is handed to ``on_error`` and listed in
    :attr:`InputsComparison.unreadable`. ``jobs`` worker processes (``None``: one per usable
    core) or Ray tasks on ``ray_address`` read the files (see :mod:`episode_audit._jobs`);
    the comparison is the same as with ``jobs=1``. ``progress`` is called with 1 as each file
    is read (as a run of files is, from workers).
    """
    gates = gates_from_options(
        max_success_drop=max_success_drop,
        max_failure_increase=max_failure_increase,
        max_return_drop=max_return_drop,
        max_error_increase=max_error_increase,
        fail_on_new_incentive_warning=fail_on_new_incentive_warning,
    )
    check_limit("--rate-margin", rate_margin, "margin")
    if not candidate:
        raise ConfigurationError("--candidate: expected at least one file or directory")
    check_compare_by(by)
    inputs = [listed_inputs(list(paths)) for paths in (baseline, candidate)]
    files = [side.files for side in inputs]
    check_apart(*files)
    one = partial(_side_file, by=by)
    read = iter(
        list(
            map_ordered(
                one, [*files[0], *files[1]], jobs=jobs, ray_address=ray_address, progress=progress
            )
        )
    )
    parts: list[list[SideFile]] = []
    unreadable: list[Unreadable] = []
    for side, side_files in zip(("baseline", "candidate"), files, strict=True):
        parts.append([])
        for path, got in zip(side_files, read, strict=False):
            if isinstance(got, EpisodeAuditError):
                if on_error is not None:
                    on_error(got)
                unreadable.append(Unreadable.of(path, got))
            else:
                parts[-1].append(got)
        if side_files and not parts[-1]:
            raise ConfigurationError(
                f"the {side}: none of its {len(side_files)} evidence file(s) could be read "
                "(the lines above say why); give readable files"
            )
    check_tasks(parts[0], parts[1], different_tasks, "--different-tasks")
    comparison = compare_parts(
        parts[0],
        parts[1],
        by=by,
        gates=gates,
        different_tasks=different_tasks,
        rate_margin=rate_margin,
    )
    return InputsComparison(comparison, unreadable, inputs[0].exports + inputs[1].exports)


def _side_file(
    path: Source, progress: Callable[[int], None] | None, *, by: str
) -> SideFile | EpisodeAuditError:
    """One input's part of the comparison, or why it cannot be read (in a worker, maybe)."""
    try:
        return side_file(str(path), open_evidence(path), by)
    except EpisodeAuditError as exc:
        return exc
    finally:
        if progress is not None:
            progress(1)


def gates_from_options(
    *,
    max_success_drop: float | None = None,
    max_failure_increase: Sequence[str] = (),
    max_return_drop: float | None = None,
    max_error_increase: float | None = None,
    fail_on_new_incentive_warning: bool = False,
) -> CompareGates:
    """The :class:`~.groups.CompareGates` of the command line's options, checked in their words.

    >>> gates_from_options(max_failure_increase=["0.1", "collision=0.02"])
    ... # doctest: +NORMALIZE_WHITESPACE
    CompareGates(max_success_drop=None, max_failure_increase=0.1,
                 max_failure_increase_by_label={'collision': 0.02}, max_return_drop=None,
                 fail_on_new_incentive_warning=False, max_error_increase=None)
    >>> try:
    ...     gates_from_options(max_failure_increase=["collision=2"])
    ... except ConfigurationError as exc:
    ...     print(exc)
    --max-failure-increase: expected a rate between 0 and 1, got '2'
    """
    check_limit("--max-success-drop", max_success_drop, "rate")
    check_limit("--max-return-drop", max_return_drop, "amount")
    check_limit("--max-error-increase", max_error_increase, "rate")
    overall, by_label = failure_rates(max_failure_increase, "--max-failure-increase")
    return CompareGates(
        max_success_drop,
        overall,
        by_label,
        max_return_drop,
        fail_on_new_incentive_warning,
        max_error_increase,
    )
