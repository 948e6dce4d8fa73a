"""File-level facts: how the file was written, finished, recovered and what it allows.

:func:`check_file_facts` runs before the steps (``recorder_trouble``, ``file_recovered``,
``evidence_damaged``, ``summary_damaged``, ``run_end_damaged``, ``missing_env_spec``, a vector
file's ``not_replayable`` and those of :mod:`.replayable`, ``format_version``);
:func:`check_unfinished` after them (``file_unfinished``, which says whether the file held
anything).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..format import names as fmt
from ..format.records import listing
from ..format.run_end import RunEnd
from ..format.unrecorded import spec_placeholders, unrecorded
from ..format.wrappers import declared_transparent, plan_wrappers
from ..read.liveness import still_written
from ._state import FileState
from .registry import (
    EVIDENCE_DAMAGED,
    FILE_RECOVERED,
    FILE_UNFINISHED,
    FORMAT_VERSION,
    MISSING_ENV_SPEC,
    NOT_REPLAYABLE,
    RECORDER_TROUBLE,
    RUN_END_DAMAGED,
    SUMMARY_DAMAGED,
)
from .replayable import check_state_causes

__all__ = ["check_file_facts", "check_unfinished"]

_LIST_LIMIT = 5
_NOT_FINISHED = "the writer did not finish"


def check_file_facts(state: FileState) -> None:
    """The findings about the file as a whole, in this order."""
    _recorder_trouble(state)
    _recovered(state)
    _damaged_end(state)
    _replayable(state)
    _format_version(state)


def _recorder_trouble(state: FileState) -> None:
    """``recorder_trouble``: the recorder's failures, and what it dropped of the run for them."""
    said = RunEnd.of(state.ev.run_end)
    troubles, lost = said.troubles, said.lost
    if not (troubles or lost):
        return
    first = said.first_trouble or "not recorded"
    failed = (
        f"the recorder failed inside itself {troubles} time(s) while recording (first: "
        f"{first[:300]})"
        if troubles
        else "the recorder could not write part of the run"
    )
    if lost is None:
        state.finding(
            RECORDER_TROUBLE, f"{failed}; the evidence may miss what it was recording then"
        )
        return
    state.finding(
        RECORDER_TROUBLE,
        f"{failed}; it dropped {lost} it could not write (the run-end record counts them): "
        "the file's episodes, steps and outcomes are not the whole run; free disk space and "
        "record the run again",
    )


def _recovered(state: FileState) -> None:
    ev = state.ev
    said = RunEnd.of(ev.run_end)
    if not (ev.finished and said.recovered):
        return
    dropped = said.dropped or "not recorded"
    if ev.holds_nothing:  # (the original held no complete chunk)
        state.finding(
            FILE_RECOVERED,
            "rewritten by episode-audit recover from a torn or damaged file that held no "
            f"complete chunk: no episode, reset or step survives to check; dropped: {dropped}",
            severity="error",
        )
        return
    state.finding(
        FILE_RECOVERED,
        f"rewritten by episode-audit recover from a torn or damaged file; dropped: {dropped}",
    )
    damaged, stretches = ev.damaged_episodes, ev.damaged_stretches
    if damaged or stretches:
        shown = damaged.first(_LIST_LIMIT)
        lost = (
            f"{damaged.count} episode(s) lost part or all of their evidence "
            f"(episodes {listing(shown, damaged.count)}): their records, steps and "
            "outcomes are not the whole run"
            if damaged
            else "no episode lost evidence"
        )
        state.finding(
            EVIDENCE_DAMAGED,
            f"recover skipped {stretches} damaged stretch(es) of the original file; {lost}",
            shown[0] if shown else None,
        )


def _damaged_end(state: FileState) -> None:
    ev = state.ev
    if ev.summary_damage:
        state.finding(
            SUMMARY_DAMAGED,
            f"{ev.summary_damage}: the file was read by scanning its data section, which "
            "holds all the evidence (`episode-audit recover` writes a copy with a new summary)",
        )
    if ev.run_end_damage:
        state.finding(
            RUN_END_DAMAGED,
            f"{ev.run_end_damage}: the writer finished the file (its summary and footer are "
            "sound) and every chunk is there, but the record's status and counts are lost "
            "(`episode-audit recover` writes a copy with a new run-end record)",
        )


def _replayable(state: FileState) -> None:
    run = state.ev.run
    layout = run.layout or {}
    if run.env_spec is None and not layout.get("env_module"):  # PettingZoo: a module
        notes = [str(n) for n in (run.recorder or {}).get("notes") or []]
        why = f" ({'; '.join(notes)})" if notes else ""
        state.finding(
            MISSING_ENV_SPEC, f"no environment spec recorded{why}: replay needs an env factory"
        )
    unheld = spec_placeholders(run.env_spec)
    if unheld and _placeholders_needed(run.env_spec, run.recorder):
        state.finding(
            MISSING_ENV_SPEC,
            f"the environment spec holds placeholders for what JSON cannot hold "
            f"({', '.join(unheld)}): replay needs an env factory",
        )
    if layout.get("kind") == "vector" and layout.get("sub_envs") is False:
        why = layout.get("replay_note") or "the vector env had no sub-envs"
        state.finding(NOT_REPLAYABLE, f"no episode can be replayed on its own: {why}")
    check_state_causes(state)


def _placeholders_needed(spec: Any, recorder: Any) -> bool:
    """Whether replay needs what a spec's placeholders stand for to build the env.

    An env argument, yes; a wrapper's, when replay does not leave the wrapper out (a
    ``RecordVideo`` given a function is left out: it never changes a step).
    """
    kwargs = spec.get("kwargs")
    if isinstance(kwargs, Mapping) and any(unrecorded(v) is not None for v in kwargs.values()):
        return True
    wrappers = spec.get("additional_wrappers")
    plan = plan_wrappers(
        wrappers if isinstance(wrappers, list) else [], declared_transparent(recorder)
    )
    return plan.refused is not None


def _format_version(state: FileState) -> None:
    version = state.ev.run.format_version
    if _version_tuple(version) < _version_tuple(fmt.FORMAT_VERSION):
        state.finding(
            FORMAT_VERSION,
            f"written with format {version}, older than the current {fmt.FORMAT_VERSION}",
        )


def _version_tuple(version: str) -> tuple[int, ...]:
    try:
        return tuple(int(p) for p in version.split("."))
    except ValueError:
        return (0,)


def check_unfinished(state: FileState) -> None:
    """After the pass over the file: an unfinished file, and whether it held anything.

    A torn file (no live recorder) that holds nothing is an error: its evidence is gone.
    """
    ev = state.ev
    if ev.finished:
        return
    if ev.writer is not None:  # not torn: a live recorder still writes it
        read = "what it had flushed was checked"
        if not state.steps and not state.episodes and not ev.resets().num_rows:
            read = "it holds no complete chunk yet: no episode, reset or step to check"
        state.finding(
            FILE_UNFINISHED,
            f"the file is {still_written(ev.writer)}: {read}; wait for its recorder to close "
            "it, then check it again",
        )
        return
    # the reader's reason may end by saying it too ("ends at byte N without a summary: the
    # writer did not finish"): the message says it once
    why = (ev.torn or "no run-end record").removesuffix(f": {_NOT_FINISHED}")
    if state.steps or state.episodes or ev.resets().num_rows:
        state.finding(
            FILE_UNFINISHED, f"{_NOT_FINISHED} the file ({why}); complete chunks were read"
        )
        return
    # no writer holds it: nothing more will come, and what it recorded is lost
    state.finding(
        FILE_UNFINISHED,
        f"{_NOT_FINISHED} the file ({why}) and no recorder is writing it: it holds no complete "
        "chunk, so no episode, reset or step survives to check (a recorder killed before its "
        "first flush) and `episode-audit recover` cannot bring any back",
        severity="error",
    )
