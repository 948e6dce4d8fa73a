"""What the run metadata says replay cannot restore: one ``not_replayable`` finding per cause.

:func:`check_state_causes` reports each cause :func:`~episode_audit.format.wrappers.state_causes`
finds (a recorded wrapper that keeps state across episodes without a snapshot, a vector wrapper
under the vector recorder), naming it, and the one of
:func:`~episode_audit.format.wrappers.unplaced_limits` (sub-envs in worker processes under a
frame skip: where their time limits sat is unknown); replay gives every episode of such a file
the same reasons (docs/replay.md, "Honest verdicts").
"""

from __future__ import annotations

from ..format.wrappers import state_causes, unplaced_limits
from ._state import FileState
from .registry import NOT_REPLAYABLE

__all__ = ["check_state_causes"]


def check_state_causes(state: FileState) -> None:
    """One ``not_replayable`` finding per cause that makes the episodes' state unrestorable."""
    run = state.ev.run
    for cause in state_causes(run.env_spec, run.layout):
        state.finding(NOT_REPLAYABLE, f"no episode can be replayed as recorded: {cause}")
    unplaced = unplaced_limits(run.env_spec, run.layout)
    if unplaced is not None:
        state.finding(NOT_REPLAYABLE, f"no episode can be replayed from the spec: {unplaced}")
