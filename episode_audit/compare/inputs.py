"""The library behind ``episode-audit compare``: its inputs and options, compared.

:func:`compare_inputs` takes the options as the command line gives them
(``--max-failure-increase`` as ``RATE`` or ``LABEL=RATE`` strings), checks them in its words,
opens the files each side's paths name (directories are searched for ``*.mcap``; unreadable
files are listed, not compared) and compares them with :func:`~.core.compare_tables`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..errors import ConfigurationError, EpisodeAuditError
from ..read import Evidence
from ..read.inputs import Unreadable, evidence_files, open_all
from ..report.gates import is_rate
from .core import Comparison, compare_tables
from .groups import RATE_MARGIN, CompareGates

__all__ = ["InputsComparison", "compare_inputs", "gates_from_options"]


@dataclass(frozen=True)
class InputsComparison:
    """The comparison of the readable inputs, and the inputs that could not be read."""

    comparison: Comparison
    unreadable: list[Unreadable]


def compare_inputs(
    baseline: Sequence[str | os.PathLike[str]],
    candidate: Sequence[str | os.PathLike[str]],
    *,
    by: str = "all",
    max_success_drop: float | None = None,
    max_failure_increase: Sequence[str] = (),
    max_return_drop: float | None = None,
    different_tasks: bool = False,
    rate_margin: float = RATE_MARGIN,
    on_error: Callable[[EpisodeAuditError], None] | None = None,
) -> InputsComparison:
    """Compare the evidence files ``candidate`` names with those ``baseline`` names.

    Each problem with the options is a :class:`~episode_audit.errors.ConfigurationError`
    naming the option; a file that cannot be read is handed to ``on_error`` and listed in
    :attr:`InputsComparison.unreadable`.
    """
    gates = gates_from_options(
        max_success_drop=max_success_drop,
        max_failure_increase=max_failure_increase,
        max_return_drop=max_return_drop,
    )
    if not (is_rate(rate_margin) and rate_margin > 0):
        raise ConfigurationError(f"--rate-margin: expected a rate in (0, 1], got {rate_margin}")
    if not candidate:
        raise ConfigurationError("--candidate: expected at least one file or directory")
    opened: list[list[tuple[str, Evidence]]] = []
    unreadable: list[Unreadable] = []
    for side, paths in (("baseline", baseline), ("candidate", candidate)):
        files = evidence_files(list(paths))
        readable, bad = open_all(files, Evidence.episodes, on_error=on_error)
        if files and not readable:
            raise ConfigurationError(
                f"the {side}: none of its {len(files)} evidence file(s) could be read "
                "(the lines above say why); give readable files"
            )
        opened.append([(str(path), ev) for path, ev in readable])
        unreadable += bad
    comparison = compare_tables(
        opened[0],
        opened[1],
        by=by,
        gates=gates,
        different_tasks=different_tasks,
        rate_margin=rate_margin,
    )
    return InputsComparison(comparison, unreadable)


def gates_from_options(
    *,
    max_success_drop: float | None = None,
    max_failure_increase: Sequence[str] = (),
    max_return_drop: float | None = None,
) -> CompareGates:
    """The :class:`~.groups.CompareGates` of the command line's options, checked in their words.

    >>> gates_from_options(max_failure_increase=["0.1", "collision=0.02"])
    ... # doctest: +NORMALIZE_WHITESPACE
    CompareGates(max_success_drop=None, max_failure_increase=0.1,
                 max_failure_increase_by_label={'collision': 0.02}, max_return_drop=None)
    >>> try:
    ...     gates_from_options(max_failure_increase=["collision=2"])
    ... except ConfigurationError as exc:
    ...     print(exc)
    --max-failure-increase: expected a rate between 0 and 1, got '2'
    """
    if max_success_drop is not None and not is_rate(max_success_drop):
        raise ConfigurationError(
            f"--max-success-drop: expected a rate between 0 and 1, got {max_success_drop}"
        )
    if max_return_drop is not None and not (
        math.isfinite(max_return_drop) and max_return_drop >= 0
    ):
        raise ConfigurationError(
            f"--max-return-drop: expected a finite number >= 0, got {max_return_drop}"
        )
    overall: float | None = None
    by_label: dict[str, float] = {}
    for value in max_failure_increase:
        label, sep, rate = value.rpartition("=")
        try:
            number = float(rate)
        except ValueError:
            raise ConfigurationError(
                f"--max-failure-increase: expected RATE or LABEL=RATE, got {value!r}"
            ) from None
        if not is_rate(number):
            raise ConfigurationError(
                f"--max-failure-increase: expected a rate between 0 and 1, got {rate!r}"
            )
        if sep and not label:
            raise ConfigurationError(
                f"--max-failure-increase: expected RATE or LABEL=RATE, got {value!r} (no label)"
            )
        if sep:
            by_label[label] = number
        else:
            overall = number
    return CompareGates(max_success_drop, overall, by_label, max_return_drop)
