"""Names and constants of the evidence file format (see ``docs/format.md``).

This module is the single place where topics, encodings, metadata names and column names are
spelled; every other module imports them from here.

>>> FORMAT_VERSION
'1.0'
>>> TOPIC_STEPS
'episode_audit/steps'
"""

from __future__ import annotations

from typing import Final

__all__ = [
    "ARROW_ENCODING",
    "COL_ACTION",
    "COL_AGENT",
    "COL_ENV_INDEX",
    "COL_ERROR_ACTION",
    "COL_EPISODE",
    "COL_GAME",
    "COL_INFO",
    "COL_LABEL",
    "COL_NOTES",
    "COL_OBSERVATION",
    "COL_OPTIONS",
    "COL_OPTIONS_TYPED",
    "COL_OUTCOME",
    "COL_REWARD",
    "COL_RNG_STATE",
    "COL_SEED",
    "COL_STATE",
    "COL_STEP",
    "COL_TERMINATED",
    "COL_TERMS",
    "COL_TIME",
    "COL_TRUNCATED",
    "FORMAT_MAJOR",
    "FORMAT_VERSION",
    "INFO_RNG_STATE",
    "INFO_STATE",
    "INFO_STATE_NOTE",
    "JSON_ENCODING",
    "JSONSCHEMA_ENCODING",
    "MCAP_PROFILE",
    "METADATA_EXPORT",
    "METADATA_RUN",
    "METADATA_RUN_END",
    "OUTCOMES",
    "OUTCOME_ERROR",
    "OUTCOME_FAILURE",
    "OUTCOME_INCOMPLETE",
    "OUTCOME_SUCCESS",
    "OUTCOME_TRUNCATED",
    "REASON_EXTERNAL",
    "REASON_TIME_LIMIT",
    "RUN_END_FIRST_TROUBLE",
    "RUN_END_LOST_EPISODES",
    "RUN_END_LOST_RESETS",
    "RUN_END_LOST_STEPS",
    "RUN_END_SUCCESS_REPORTED",
    "RUN_END_TROUBLE",
    "RUN_STATUS_FINISHED",
    "RUN_STATUS_RECOVERED",
    "SCHEMA_EPISODE_BLOCK",
    "SCHEMA_EPISODE_END",
    "SCHEMA_RESET_BLOCK",
    "SCHEMA_STEP_BLOCK",
    "TOPIC_EPISODE_END",
    "TOPIC_EPISODES",
    "TOPIC_RESETS",
    "TOPIC_STEPS",
    "UNLABELED",
    "format_major",
]

FORMAT_VERSION: Final = "1.0"
"""Version of the format this package writes. Readers refuse a newer *major* version."""
FORMAT_MAJOR: Final = 1

MCAP_PROFILE: Final = "episode_audit"
"""MCAP header profile of every evidence file."""

ARROW_ENCODING: Final = "application/vnd.apache.arrow.stream"
"""Message (and schema) encoding of columnar blocks: one Arrow IPC stream per message."""
JSON_ENCODING: Final = "json"
JSONSCHEMA_ENCODING: Final = "jsonschema"

TOPIC_STEPS: Final = "episode_audit/steps"
TOPIC_RESETS: Final = "episode_audit/resets"
TOPIC_EPISODE_END: Final = "episode_audit/episode_end"
TOPIC_EPISODES: Final = "episode_audit/episodes"
"""Arrow blocks of the same episode records as ``TOPIC_EPISODE_END``, for fast machine reads."""

SCHEMA_STEP_BLOCK: Final = "episode_audit.StepBlock"
SCHEMA_RESET_BLOCK: Final = "episode_audit.ResetBlock"
SCHEMA_EPISODE_END: Final = "episode_audit.EpisodeEnd"
SCHEMA_EPISODE_BLOCK: Final = "episode_audit.EpisodeBlock"

INFO_RNG_STATE: Final = "episode_audit.rng_state"
"""Reset-info key where ``ResetRngInfo`` puts the RNG state before an unseeded reset (JSON)."""
INFO_STATE: Final = "episode_audit.state"
"""Reset-info key where ``ResetRngInfo`` puts the state snapshot taken before a reset (JSON)."""
INFO_STATE_NOTE: Final = "episode_audit.state_note"
"""Reset-info key where ``ResetRngInfo`` says why it took no snapshot before a reset (a note)."""

METADATA_RUN: Final = "episode_audit.run"
METADATA_RUN_END: Final = "episode_audit.run_end"
METADATA_EXPORT: Final = "episode_audit.export"
"""The metadata record a Foxglove export writes (its source, env id, tags): it marks the file as
our viewer export, which the reader names when it is given one as evidence."""
# The run-end record's ``status``: written by the recorder's close(), or by recovery.
RUN_STATUS_FINISHED: Final = "finished"
RUN_STATUS_RECOVERED: Final = "recovered"
# Run-end keys present when the recorder failed inside itself while recording (never raised
# into the loop): how many times, and the first failure as "Type: message".
RUN_END_TROUBLE: Final = "recorder_trouble"
RUN_END_FIRST_TROUBLE: Final = "recorder_trouble_first"
# Run-end keys present when the OS refused flushes for longer than the recorder could hold them
# (a full disk): the step rows, reset rows and episode records dropped.
RUN_END_LOST_STEPS: Final = "recorder_lost_steps"
RUN_END_LOST_RESETS: Final = "recorder_lost_resets"
RUN_END_LOST_EPISODES: Final = "recorder_lost_episode_records"
# Run-end key: how many episodes the task ended (or cut off) with an info that said anything
# about success (``EndingRules.reports_success``); 0 for a task without a success signal.
RUN_END_SUCCESS_REPORTED: Final = "success_reported"

# Column names of the blocks (their schemas: ``schemas.py``).
COL_EPISODE: Final = "episode"
COL_STEP: Final = "step"
COL_TIME: Final = "time_ns"
COL_ACTION: Final = "action"
COL_OBSERVATION: Final = "observation"
COL_REWARD: Final = "reward"
COL_TERMS: Final = "terms"
COL_TERMINATED: Final = "terminated"
COL_TRUNCATED: Final = "truncated"
COL_OUTCOME: Final = "outcome"
COL_LABEL: Final = "label"
COL_INFO: Final = "info"
COL_NOTES: Final = "notes"
COL_ENV_INDEX: Final = "env_index"
COL_SEED: Final = "seed"
COL_RNG_STATE: Final = "rng_state"
COL_STATE: Final = "state"
"""Reset column (optional): the state snapshot taken before the reset (``format/state.py``)."""
COL_OPTIONS: Final = "options"
COL_OPTIONS_TYPED: Final = "options_typed"
"""Reset and episode column (optional): options plain JSON does not hold exactly, tagged
(``format/options.py``)."""
COL_AGENT: Final = "agent"
COL_GAME: Final = "game"
COL_ERROR_ACTION: Final = "error_action"
"""Episode blocks of single-env files: the action of an error episode's step that raised."""

OUTCOME_SUCCESS: Final = "success"
OUTCOME_FAILURE: Final = "failure"
OUTCOME_TRUNCATED: Final = "truncated"
OUTCOME_INCOMPLETE: Final = "incomplete"
OUTCOME_ERROR: Final = "error"
OUTCOMES: Final = (
    OUTCOME_SUCCESS,
    OUTCOME_FAILURE,
    OUTCOME_TRUNCATED,
    OUTCOME_INCOMPLETE,
    OUTCOME_ERROR,
)
UNLABELED: Final = "unlabeled"
REASON_TIME_LIMIT: Final = "time_limit"
REASON_EXTERNAL: Final = "external"


def format_major(version: str) -> int:
    """Return the major number of a ``"MAJOR.MINOR"`` format version string.

    >>> format_major("1.3")
    1

    Raises ``ValueError`` when the string is not of that form.
    """
    major, _, minor = version.partition(".")
    if not major.isdigit() or (minor and not minor.isdigit()):
        raise ValueError(f"expected a version like '1.0', found {version!r}")
    return int(major)
