"""What a file recorded, as a replay reads it: episode records, row ranges, actions and rules.

:func:`episode_records` (the records a replay reads), :func:`row_ranges` and :func:`to_end`
(each episode's rows), :func:`unrepeated` (what the recorded env did that a replay does not
repeat), :func:`cast_actions` (episodes whose actions the recorder cast), :func:`replay_actions`
(the actions to step with), :func:`rules_of` (the recorded ending rules and reward terms),
:func:`unrecorded_options` and :func:`reset_options` (the options an episode's reset had),
:func:`unread_rng_states` (why the recorder could not read an unseeded reset's RNG state),
:func:`layout_not_replayable` and :func:`state_not_restorable`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..format import names as fmt
from ..format.columns import one_array
from ..format.options import decode_typed
from ..format.records import RunInfo, from_json, note_items
from ..format.wrappers import state_causes
from ..read import Evidence
from ..record.rules import EndingRules, RewardTerms

__all__ = [
    "cast_actions",
    "episode_records",
    "first_noted",
    "layout_not_replayable",
    "ordinal",
    "replay_actions",
    "reset_options",
    "row_ranges",
    "rules_of",
    "state_not_restorable",
    "to_end",
    "unread_rng_states",
    "unrecorded_options",
    "unrepeated",
]

_RECORD_COLUMNS = (
    fmt.COL_EPISODE,
    fmt.COL_ENV_INDEX,
    "seed",
    "rng_state",
    "options",
    "outcome",
    "failure_label",
    "truncation_reason",
    "error_during",
    "error_type",
    "length",
)
"""The columns of the episode table a replay reads."""
_RECORD_KEYS = frozenset({fmt.COL_EPISODE, "outcome"})
"""Those it reads as ``record[key]``, listed even when every value is null."""
_ENDED = frozenset(
    {fmt.OUTCOME_SUCCESS, fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED, fmt.OUTCOME_ERROR}
)
"""The outcomes of an episode that ended while the loop could still step its env."""


def episode_records(ev: Evidence, wanted: set[int] | None) -> list[dict[str, Any]]:
    """The episode records of a single-env or vector file (``wanted``: only those), in order.

    Only the columns replay reads (a map column is slow to list), and of the optional ones only
    those with a value: a record's ``.get()`` gives ``None`` for the others.
    """
    table = ev.episodes()
    columns = [
        c
        for c in _RECORD_COLUMNS
        if c in table.column_names
        and (c in _RECORD_KEYS or table.column(c).null_count < table.num_rows)
    ]
    listed = table.select(columns).to_pylist()
    return listed if wanted is None else [r for r in listed if r["episode"] in wanted]


def row_ranges(episode: np.ndarray[Any, Any]) -> dict[int, tuple[int, int]]:
    """(first row, row count) of each episode; a single env's episodes are contiguous runs."""
    if episode.size == 0:
        return {}
    starts = np.flatnonzero(np.diff(episode)) + 1
    firsts = np.concatenate([[0], starts])
    counts = np.diff(np.append(firsts, episode.size))
    indices = episode[firsts]
    if np.unique(indices).size == indices.size:  # the usual case: one run per episode
        ranges = zip(firsts.tolist(), counts.tolist(), strict=True)
        return dict(zip(indices.tolist(), ranges, strict=True))
    out: dict[int, tuple[int, int]] = {}
    for first, count in zip(firsts.tolist(), counts.tolist(), strict=True):
        index = int(episode[first])
        if index in out:  # not contiguous (never written so): fall back to the first run
            continue
        out[index] = (first, count)
    return out


def to_end(
    rows: dict[int, tuple[int, int]], records: Mapping[int, Mapping[str, Any]]
) -> tuple[dict[int, tuple[int, int]], dict[int, int]]:
    """Each episode's rows up to its recorded end, and how many it has after that end.

    Rows stepped after an episode ended (the recorder noted them ``step_after_end``; ``check``
    reports them) are not the episode: replay compares the steps up to its ``length``. An
    episode ends by its flags, or as ``error``: the env raised, and the loop may have caught
    the error and stepped the same env on. The second dict has the episodes with such rows.
    """
    out = rows
    after: dict[int, int] = {}
    for index, (first, count) in rows.items():
        record = records.get(index)
        if record is None or record.get("outcome") not in _ENDED:
            continue
        length = record.get("length")
        if isinstance(length, int) and 0 <= length < count:
            if out is rows:
                out = dict(rows)
            out[index] = (first, length)
            after[index] = count - length
    return out, after


_ACTION_CAST = "action_cast"
_OPTIONS_UNRECORDED = "options_unserializable"
_RNG_UNREAD = "rng_state_unavailable"


def cast_actions(steps: pa.Table) -> dict[int, tuple[int, str]]:
    """The episodes of ``steps`` whose actions the recorder cast: first step, and the note.

    The recorder notes ``action_cast`` on a step whose action it stored in the space's dtype
    from another (a float64 action of a float32 ``Box``): the env stepped a value the file
    holds only rounded. Only the distinct notes values are parsed.

    >>> import pyarrow as pa
    >>> notes = [None, '["action_cast: dtype float64 cast to float32"]', None]
    >>> cast_actions(pa.table({"episode": [0, 1, 1], "step": [0, 0, 1], "notes": notes}))
    {1: (0, 'dtype float64 cast to float32')}
    """
    found = first_noted(steps, _ACTION_CAST)
    if not found:
        return {}
    step = steps.column(fmt.COL_STEP)
    return {e: (step[row].as_py(), message) for e, (row, message) in found.items()}


def unrecorded_options(resets: pa.Table) -> dict[int, str]:
    """The episodes of ``resets`` whose reset options the file does not hold, and the note.

    The recorder notes ``options_unserializable`` on a reset whose options plain JSON cannot
    hold exactly (a tuple, a numpy value, a non-finite float, a key that is not a string, an
    object), and holds them exactly in the reset's ``options_typed`` column when it can: those
    it holds are not listed (the note is for readers without the column). The others (a
    function, an object) the env was reset with, and replay does not have.

    >>> import pyarrow as pa
    >>> notes = [None, '["options_unserializable: {1: f} (JSON has no function values)"]']
    >>> unrecorded_options(pa.table({"episode": [0, 1], "notes": notes}))
    {1: '{1: f} (JSON has no function values)'}
    """
    noted = first_noted(resets, _OPTIONS_UNRECORDED)
    if not noted or fmt.COL_OPTIONS_TYPED not in resets.column_names:
        return {e: message for e, (_, message) in noted.items()}
    typed = resets.column(fmt.COL_OPTIONS_TYPED)
    return {e: message for e, (row, message) in noted.items() if not typed[row].is_valid}


def unread_rng_states(resets: pa.Table) -> dict[int, str]:
    """The episodes of ``resets`` whose RNG state the recorder noted it could not read, and why.

    >>> import pyarrow as pa
    >>> notes = [None, '["rng_state_unavailable: its np_random raised"]']
    >>> unread_rng_states(pa.table({"episode": [0, 1], "notes": notes}))
    {1: 'its np_random raised'}
    """
    return {e: message for e, (_, message) in first_noted(resets, _RNG_UNREAD).items()}


def reset_options(options: str | None, typed: str | None) -> Any:
    """The options an episode was reset with: the typed form when the file holds one, else JSON.

    ``options``: the episode record's; ``typed``: its reset row's ``options_typed``.

    Raises ``ValueError`` when the text is not what episode-audit writes.

    >>> reset_options('{"init":[1,2]}', '{"init":{"$tuple":[1,2]}}')
    {'init': (1, 2)}
    >>> reset_options('{"init":[1,2]}', None), reset_options(None, None)
    ({'init': [1, 2]}, None)
    """
    if typed is not None:
        return decode_typed(typed)
    return from_json(options, "options") if options else None


def first_noted(table: pa.Table, code: str) -> dict[int, tuple[int, str]]:
    """By episode: the position of its first row of ``table`` noted ``code``, and the note.

    Only the distinct notes values are parsed.
    """
    if fmt.COL_NOTES not in table.column_names:
        return {}
    notes = table.column(fmt.COL_NOTES)
    if notes.null_count == len(notes):
        return {}
    encoded = pc.dictionary_encode(notes).combine_chunks()
    noted: dict[int, str] = {}
    for slot, text in enumerate(encoded.dictionary.to_pylist()):
        for item in (note_items(text) if text else None) or ():  # (garbled: says nothing)
            found, _, message = item.partition(": ")
            if found == code:
                noted[slot] = message
                break
    if not noted:
        return {}
    indices = encoded.indices.to_numpy(zero_copy_only=False)
    valid = np.asarray(encoded.indices.is_valid())
    rows = np.flatnonzero(valid & np.isin(np.where(valid, indices, -1), list(noted)))
    episode = table.column(fmt.COL_EPISODE).to_numpy()[rows]
    out: dict[int, tuple[int, str]] = {}
    for row, e in zip(rows.tolist(), episode.tolist(), strict=True):
        if e not in out:
            out[e] = (row, noted[int(indices[row])])
    return out


def unrepeated(
    record: Mapping[str, Any], after_end: int, *, raised_again: bool = False, unset: bool = False
) -> str | None:
    """What the recorded env did in ``record``'s episode that replay does not repeat, or None.

    The step or reset that raised, in an ``error`` episode (a call that raised is no row),
    unless replay stepped its recorded action and it raised the same (``raised_again``), and
    the ``after_end`` rows stepped after its end; all of it when its reset options are not in
    the file (``unset``: replay does not reset it).

    >>> rec = {"episode": 1, "outcome": "error", "error_during": "step", "length": 2}
    >>> print(unrepeated({**rec, "error_type": "KeyError"}, 3))
    episode 1's 3rd step, which raised KeyError, and 3 steps after its end
    >>> print(unrepeated({**rec, "error_type": "KeyError"}, 3, raised_again=True))
    episode 1's 3 steps after its end
    >>> print(unrepeated({"episode": 4, "outcome": "success", "length": 9}, 1))
    episode 4's 1 step after its end
    >>> print(unrepeated({"episode": 2, "outcome": "success", "length": 9}, 1, unset=True))
    episode 2's reset and steps (its reset options are not in the file)
    """
    if unset:
        return (
            f"episode {record['episode']}'s reset and steps (its reset options are not in the file)"
        )
    parts = []
    if record.get("outcome") == fmt.OUTCOME_ERROR and not raised_again:
        error = record.get("error_type") or "an error"
        if record.get("error_during") == "reset":
            parts.append(f"reset, which raised {error}")
        else:
            nth = ordinal(int(record.get("length") or 0) + 1)
            parts.append(f"{nth} step, which raised {error}")
    if after_end:
        parts.append(f"{after_end} step{'s' if after_end != 1 else ''} after its end")
    return f"episode {record['episode']}'s " + ", and ".join(parts) if parts else None


def ordinal(n: int) -> str:
    """``n`` as an ordinal: ``1st``, ``2nd``, ``3rd``, ``4th``, ``11th``, ``22nd``."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def replay_actions(column: pa.ChunkedArray, codec: Any) -> tuple[Any, np.ndarray[Any, Any] | None]:
    """The actions a replay steps with, and the rows with none (``None`` when all have one).

    Integer actions are numpy integers, as ``Discrete.sample()`` and ``from_jsonable`` give;
    others are what the space codec decodes.
    """
    actions = one_array(column)
    if len(actions) == 0:  # (a torn file may not even name the column's type)
        return [], None
    if pa.types.is_integer(actions.type) and actions.null_count == 0:
        return actions.to_numpy(), None
    values = codec.decode(actions)
    if actions.null_count == 0:
        return values, None
    missing = [i for i, value in enumerate(values) if value is None]
    return values, (np.array(missing, dtype=np.int64) if missing else None)


def rules_of(run: RunInfo) -> tuple[EndingRules | None, RewardTerms | None]:
    """The recorded ending rules and reward terms a replay can apply (``None``: not compared).

    Read back from the file's description of them (:meth:`EndingRules.from_description`,
    :meth:`RewardTerms.from_description`): ending rules with a ``success_fn`` or ``failure_fn``
    and terms from a callable are only named in a file, so outcomes (terms) are then not
    compared. Replay compares term names and values, never the declared constants.
    """
    source = (run.reward_terms or {}).get("source", "auto")
    return (
        EndingRules.from_description(run.ending_rules),
        RewardTerms.from_description({"source": source}),
    )


def layout_not_replayable(layout: Mapping[str, Any]) -> str | None:
    """Why a file's layout cannot be replayed episode by episode, or ``None`` if it can.

    A vector file's episodes replay one by one in a single sub-env rebuilt from the recorded
    sub-env spec, unless the vector env had no sub-envs (a ``vector_entry_point`` env).
    """
    kind = layout.get("kind", "single")
    if kind == "single":
        return None
    if kind == "vector":
        if layout.get("sub_envs", True):
            return None
        return str(layout.get("replay_note") or "the vector env had no sub-envs")
    return f"layout {kind!r} is not replayable yet"


def state_not_restorable(run: RunInfo) -> str | None:
    """Why no episode of a file can begin in the state it was recorded in, or ``None``.

    Every cause :func:`~episode_audit.format.wrappers.state_causes` finds in the run metadata,
    in one line. Whatever env replay would build (a user's ``env_factory`` too), comparing would
    only show that state, as a false divergence.
    """
    causes = state_causes(run.env_spec, run.layout)
    return "; ".join(causes) if causes else None
