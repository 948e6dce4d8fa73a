"""What differs between the runs of the two sides: task, env kwargs, time limit, versions.

Reward wrappers under the recorder too, with their recorded settings: where they differ, the
returns are in other units.

:func:`mismatches` lists each difference as a :class:`Mismatch`; a different env id means a
different task, which :func:`~.core.compare` refuses unless told ``different_tasks=True``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..format.wrappers import limits_text, worker_sub_envs
from ..read import Evidence
from ..report.wrapped import file_setup

__all__ = [
    "UNREAD_LIMITS",
    "Mismatch",
    "field_mismatches",
    "limits_note",
    "mismatches",
    "run_fields",
]

UNREAD_LIMITS = "unread_limits"
"""The field of a file whose sub-envs ran in workers (their vector class): its recorded time
limit is the outermost ``TimeLimit``'s, wherever it sat (``wrappers.worker_sub_envs``), so the
sides' limits are not compared (:func:`limits_note`)."""
_LIMITS = "max_episode_steps"


@dataclass(frozen=True)
class Mismatch:
    """One field whose values differ between the sides (each side's values, sorted)."""

    field: str
    baseline: list[str]
    candidate: list[str]

    @property
    def task(self) -> bool:
        """Whether the sides run different tasks (env ids)."""
        return self.field == "env_id"

    def __str__(self) -> str:
        return (
            f"{self.field} differs: baseline {', '.join(self.baseline) or '(none)'}; "
            f"candidate {', '.join(self.candidate) or '(none)'}"
        )


def run_fields(ev: Evidence) -> dict[str, str]:
    """The fields of a file's run that the sides are compared on, as strings."""
    run = ev.run
    spec = run.env_spec or {}
    out = {
        "env_id": str(run.env_id),
        "env_kwargs": json.dumps(spec.get("kwargs") or {}, sort_keys=True, default=str),
        _LIMITS: limits_text(spec),
        "reward_wrappers": file_setup(ev) or "(none)",
    }
    if worker_sub_envs(run.layout) is not None:
        out[UNREAD_LIMITS] = str(run.layout.get("vector_class"))[:80]
    for name, version in sorted((run.versions or {}).items()):
        if name not in ("python", "episode_audit"):
            out[f"version:{name}"] = str(version)
    return out


def mismatches(
    baseline: Sequence[tuple[str, Evidence]], candidate: Sequence[tuple[str, Evidence]]
) -> list[Mismatch]:
    """The fields whose sets of values differ between the sides' files, env id first."""
    return field_mismatches(
        [run_fields(ev) for _, ev in baseline], [run_fields(ev) for _, ev in candidate]
    )


def field_mismatches(
    baseline: Sequence[dict[str, str]], candidate: Sequence[dict[str, str]]
) -> list[Mismatch]:
    """:func:`mismatches` of the sides' files given by their :func:`run_fields`.

    A library's version is compared only when both sides recorded it: a recorder records the
    libraries its process had imported, so one missing on a side says nothing of its version.
    The time limits are not compared when a file's sub-envs ran in workers (:func:`limits_note`).
    """
    unread = any(UNREAD_LIMITS in fields for fields in [*baseline, *candidate])
    base: dict[str, set[str]] = {}
    cand: dict[str, set[str]] = {}
    for into, files in ((base, baseline), (cand, candidate)):
        for fields in files:
            for name, value in fields.items():
                into.setdefault(name, set()).add(value)
    names = sorted(set(base) | set(cand), key=_order)
    return [
        Mismatch(name, sorted(base.get(name, ())), sorted(cand.get(name, ())))
        for name in names
        if base.get(name, set()) != cand.get(name, set())
        and not (name.startswith("version:") and not (name in base and name in cand))
        and name != UNREAD_LIMITS
        and not (name == _LIMITS and unread)
    ]


def limits_note(
    baseline: Sequence[dict[str, str]], candidate: Sequence[dict[str, str]]
) -> str | None:
    """Why the sides' time limits were not compared (a line), or ``None`` when they were.

    A file whose sub-envs ran in ``AsyncVectorEnv`` / ``SubprocVecEnv`` workers records the
    outermost ``TimeLimit``'s limit only, not one inside it nor whether it sat over a frame
    skip: its limit is not evidence of the limits its episodes ran under.
    """
    workers = {
        side: sorted({f[UNREAD_LIMITS] for f in files if UNREAD_LIMITS in f})
        for side, files in (("baseline", baseline), ("candidate", candidate))
    }
    said = [f"the {side}'s in {', '.join(names)}" for side, names in workers.items() if names]
    if not said:
        return None
    recorded = "; ".join(
        f"{side} {', '.join(sorted({f.get(_LIMITS, '') for f in files}))}"
        for side, files in (("baseline", baseline), ("candidate", candidate))
    )
    return (
        f"time limits not compared: sub-envs ran in worker processes ({' and '.join(said)}), "
        "whose TimeLimits the recorder cannot all read, nor where they sat (recorded "
        f"max_episode_steps: {recorded})"
    )


def _order(name: str) -> Any:
    fixed = ("env_id", "env_kwargs", "max_episode_steps", "reward_wrappers")
    return (fixed.index(name), "") if name in fixed else (len(fixed), name)
