"""A file at a glance: the library view ``episode-audit show`` renders.

:func:`summarize` returns a file's summary as plain data: run metadata, versions, env spec,
episodes by outcome, the spaces' shapes and dtypes (:func:`space_shape_dtype`), and the episodes
it lists (:func:`episode_list`: all up to :data:`EPISODE_LIST_FULL`, else the first
:data:`EPISODE_LIST_HEAD` and the last :data:`EPISODE_LIST_TAIL`). The keys: ``docs/cli.md``.
"""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING, Any

import pyarrow as pa
from gymnasium.spaces import Space

from ..format import names as fmt
from ..format.records import unstarted
from ..format.run_end import RunEnd
from ..format.spaces import space_from_description

if TYPE_CHECKING:
    from . import Evidence

__all__ = [
    "EPISODE_LIST_FULL",
    "EPISODE_LIST_HEAD",
    "EPISODE_LIST_TAIL",
    "episode_list",
    "rebuilt_space",
    "space_shape_dtype",
    "summarize",
]

EPISODE_LIST_HEAD = 5
"""Episodes listed from the start of a long file's summary."""
EPISODE_LIST_TAIL = 5
"""Episodes listed from the end of a long file's summary."""
EPISODE_LIST_FULL = 12
"""Files with up to this many episodes have every one listed (so no row hides one or two)."""

_LIST_COLUMNS = (
    "episode",
    "env_index",
    "agent",
    "outcome",
    "failure_label",
    "truncation_reason",
    "error_type",
    "length",
    "return",
)
_LABEL_OF = {
    fmt.OUTCOME_FAILURE: "failure_label",
    fmt.OUTCOME_TRUNCATED: "truncation_reason",
    fmt.OUTCOME_ERROR: "error_type",
}


def summarize(ev: Evidence, *, all_episodes: bool = False) -> dict[str, Any]:
    """The file summary: run metadata, versions, env spec, episodes by outcome, finished or not.

    ``episodes``, ``steps``, ``outcomes`` and the episode list count the episodes ``report``
    counts: an *unstarted* one (reset and never stepped,
    :func:`~episode_audit.format.records.unstarted`) is left out of them, and ``unstarted``
    says how many there were.

    ``dropped``: what the recorder could not write and dropped (a full disk), counted from the
    run-end record, ``None`` when nothing.

    ``episode_list`` holds the first and last episodes of a long file (``episode_list_omitted``
    says how many are between them), or every one with ``all_episodes``: see
    :func:`episode_list`.
    """
    episodes = ev.episodes()
    left_out = unstarted(episodes)
    if left_out.any():  # reset and never stepped: no episode to count (as report does)
        episodes = episodes.filter(pa.array(~left_out))
    outcomes = Counter(episodes.column("outcome").to_pylist())
    run = ev.run
    said = RunEnd.of(ev.run_end)
    listed, omitted = episode_list(episodes, all_episodes=all_episodes)
    obs_shape, obs_dtype = space_shape_dtype(run.observation_space)
    act_shape, act_dtype = space_shape_dtype(run.action_space)
    return {
        "file": str(ev.path),
        "finished": ev.finished,
        "torn": ev.torn,
        "recovered": (said.dropped or "not recorded") if said.recovered else None,
        "format_version": run.format_version,
        "writer": run.writer,
        "env_id": run.env_id,
        "start_time": run.start_time,
        "tags": run.tags,
        "episodes": episodes.num_rows,
        "steps": int(sum(episodes.column("length").to_pylist())),
        "outcomes": {k: outcomes.get(k, 0) for k in fmt.OUTCOMES},
        "observation_space": run.observation_space.get("type"),
        "action_space": run.action_space.get("type"),
        "reward_terms": run.reward_terms,
        "versions": run.versions,
        "platform": run.platform,
        "command_line": run.command_line,
        "env_spec": run.env_spec,
        "layout": run.layout,
        "observation_shape": obs_shape,
        "observation_dtype": obs_dtype,
        "action_shape": act_shape,
        "action_dtype": act_dtype,
        "episode_list": listed,
        "episode_list_omitted": omitted,
        "observation_digest_min_bytes": _digest_min_bytes(run.recorder),
        "dropped": (
            {
                "steps": said.lost_steps,
                "resets": said.lost_resets,
                "episode_records": said.lost_episode_records,
            }
            if said.lost
            else None
        ),
        "unstarted": int(left_out.sum()),
    }


def episode_list(
    episodes: pa.Table, *, all_episodes: bool = False
) -> tuple[list[dict[str, Any]], int]:
    """The episodes a summary lists, and how many it leaves out (between the first and last).

    ``episodes`` is :meth:`Evidence.episodes` (a summary's leaves its unstarted episodes out).
    Each entry: ``episode``, ``env_index`` and
    ``agent`` (``None`` outside vector and PettingZoo files), ``outcome``, ``label`` (the failure
    label, truncation reason or error type; ``None`` for a success or an incomplete episode),
    ``length`` and ``return``.
    """
    n = episodes.num_rows
    columns = [c for c in _LIST_COLUMNS if c in episodes.column_names]
    table = episodes.select(columns)
    if all_episodes or n <= EPISODE_LIST_FULL:
        parts, omitted = [table], 0
    else:
        tail = n - EPISODE_LIST_TAIL
        parts = [table.slice(0, EPISODE_LIST_HEAD), table.slice(tail)]
        omitted = tail - EPISODE_LIST_HEAD
    rows: list[dict[str, Any]] = []
    for part in parts:
        for record in part.to_pylist():
            label = _LABEL_OF.get(record["outcome"])
            rows.append(
                {
                    "episode": record["episode"],
                    "env_index": record.get("env_index"),
                    "agent": record.get("agent"),
                    "outcome": record["outcome"],
                    "label": record.get(label) if label else None,
                    "length": record["length"],
                    "return": record.get("return"),
                }
            )
    return rows, omitted


def rebuilt_space(description: Any) -> Space[Any] | None:
    """The space a file describes, rebuilt; ``None`` when the description does not parse."""
    try:
        return space_from_description(description)
    except Exception:  # a description from the file that is not one: nothing to show
        return None


def space_shape_dtype(description: Any) -> tuple[list[int] | None, str | None]:
    """The shape and dtype of a described space, or ``None`` where it has no single one.

    ``description`` is a space as the file describes it
    (:func:`~episode_audit.format.spaces.describe_space`); composite spaces (``Dict``, ``Tuple``, …)
    and ``Text`` have neither, and a description that does not parse gives ``None``.

    >>> space_shape_dtype({"type": "MultiBinary", "n": [2, 3]})
    ([2, 3], 'int8')
    >>> space_shape_dtype({"type": "Dict", "spaces": []})
    (None, None)
    """
    space = rebuilt_space(description)
    if space is None or space.shape is None or space.dtype is None:
        return None, None
    return list(space.shape), str(space.dtype)


def _digest_min_bytes(recorder: Any) -> int | None:
    """The recorder's ``digest_min_bytes`` setting (``None``: every array stored whole)."""
    value = recorder.get("digest_min_bytes") if isinstance(recorder, dict) else None
    return value if isinstance(value, int) and not isinstance(value, bool) else None
