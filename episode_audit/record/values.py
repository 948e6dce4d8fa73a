"""Reading what an env gave one value at a time, as the recorder's slow path and resets do.

Each reader returns what is recorded and appends a note (:func:`~.notes.note`) for anything
odd, never raising over an env's value: :func:`step_result`, :func:`truth_flags`,
:func:`reward_and_terms`, :func:`kept_info`, :func:`recordable_seed`; reset options as the file
records them, before the reset (:func:`recordable_options`), and whether a reset changed them
(:func:`changed_in_reset`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from ..format.columns import error_text, number
from ..format.options import encode_typed, json_loss
from ..format.records import MAX_JSON_TEXT, to_json, to_jsonable
from .notes import has_note, note, short
from .rules import RewardTerms, named_terms

__all__ = [
    "RecordedOptions",
    "changed_in_reset",
    "kept_info",
    "recordable_options",
    "recordable_seed",
    "reward_and_terms",
    "step_result",
    "truth_flags",
]

_INT64_MAX = 2**63 - 1


def step_result(result: Any, notes: list[str]) -> tuple[Any, Any, Any, Any, Any]:
    """``step()``'s 5-tuple, or an empty step (noted ``step_result_invalid``) if it is none."""
    try:
        obs, reward, terminated, truncated, info = result
    except Exception:
        notes.append(note("step_result_invalid", f"step() returned {short(result)}"))
        return None, math.nan, False, False, {}
    return obs, reward, terminated, truncated, info


def truth_flags(terminated: Any, truncated: Any, notes: list[str]) -> tuple[bool, bool] | None:
    """Both flags' truth values; ``None`` (noted ``flags_not_bool``) when one has none."""
    try:
        return bool(terminated), bool(truncated)
    except Exception:
        notes.append(
            note("flags_not_bool", f"terminated={short(terminated)}, truncated={short(truncated)}")
        )
        return None


def reward_and_terms(
    terms_rule: RewardTerms, reward: Any, info: Any, notes: list[str]
) -> tuple[float, dict[str, float] | None]:
    """A step's reward and named terms, value by value (what is not a number is NaN, noted)."""
    try:
        r = number(reward)
    except Exception:
        r = math.nan
        notes.append(note("reward_not_numeric", f"reward {short(reward)}"))
    if not isinstance(info, Mapping):
        notes.append(note("info_not_dict", f"info is a {type(info).__name__}"))
        return r, None
    try:
        raw = terms_rule.extract(info)
    except Exception as exc:
        notes.append(note("terms_unreadable", error_text(exc)))
        return r, None
    if raw is None:
        return r, None
    values: list[float] = []
    for key, value in raw.items():
        try:
            values.append(number(value))
        except Exception:
            values.append(math.nan)
            notes.append(note("term_not_numeric", f"term {short(key)} is {short(value)}"))
    terms, shared = named_terms(list(raw), values)
    if shared is not None:
        notes.append(note("terms_name_collision", shared))
    return r, terms


def kept_info(
    info: Any, keep_all: bool, keys: Sequence[str] | None, notes: list[str]
) -> dict[str, Any] | None:
    """The part of ``info`` kept per row: all of it, or ``keys`` (``None`` for nothing)."""
    if not isinstance(info, Mapping):
        if not has_note(notes, "info_not_dict"):  # (the step's terms may have said so)
            notes.append(note("info_not_dict", f"info is a {type(info).__name__}"))
        return None
    if keep_all:
        return dict(info)
    if not keys:
        return None
    return {k: info[k] for k in keys if k in info} or None


def recordable_seed(seed: Any, notes: list[str]) -> int | None:
    """The seed as an int64 for the file, or ``None`` (with a note) when it does not fit."""
    if seed is None:
        return None
    if type(seed) is int and 0 <= seed <= _INT64_MAX:
        return seed
    try:
        value = int(seed)
    except (TypeError, ValueError):
        value = -1
    if 0 <= value <= _INT64_MAX:
        return value
    notes.append(note("seed_out_of_range", f"seed {short(seed)} is not an int64; not replayable"))
    return None


class RecordedOptions(NamedTuple):
    """``reset()``'s options as the file records them, taken before the reset.

    ``plain``: JSON-able data; ``typed``: their typed form when plain JSON does not hold them
    exactly; ``noted``: the ``options_unserializable`` note when the file does not hold them
    exactly in either form (or holds them in the typed form only), else ``None``; ``text``:
    ``plain`` as JSON text (the ``options`` column's), made once.
    """

    plain: Any
    typed: str | None
    noted: str | None
    text: str


def recordable_options(options: Any) -> RecordedOptions | None:
    """``reset()``'s options for the file (``None`` for none); never raises.

    Taken before the reset: an env may change its options in place (``options.pop(key)``).
    Options plain JSON gives back as they were are that JSON, with no typed form. Any others
    (a tuple, a numpy value, a non-finite float, a key that is not a string, a list found twice,
    an object) are noted ``options_unserializable``, which readers without the ``options_typed``
    column take as "not held" (so they never reset with other options than the env had), and
    held exactly in their typed form (:func:`~episode_audit.format.options.encode_typed`) when
    it holds them. Their JSON-able data is what ``to_jsonable(exact=True)`` makes of them
    (tuples and float64 / int64 arrays as lists), else their ``repr``; options whose JSON is
    larger than a reader parses (:data:`~episode_audit.format.records.MAX_JSON_TEXT`) are noted,
    their ``repr`` recorded.
    """
    if options is None:
        return None
    unfit: str | None = None  # why plain JSON cannot be written at all
    try:
        plain = to_jsonable(options, exact=True)  # (a copy: the caller may change its options)
        data = to_json(plain)
        text = data.decode()
        if len(data) > MAX_JSON_TEXT:
            unfit = f"{len(data)} bytes of JSON, more than the {MAX_JSON_TEXT} a reader parses"
    except Exception as exc:  # a value JSON would change; not JSON; cyclic, too deep or too long
        plain, unfit = _shown(options), error_text(exc)
        text = to_json(plain).decode()
    loss: str | None = None
    try:
        loss = json_loss(options)
        if loss is None and unfit is None:
            return RecordedOptions(plain, None, None, text)
        if loss is None and unfit is not None:
            shown = _shown(options)
            return RecordedOptions(
                shown, None, _options_note(options, unfit), to_json(shown).decode()
            )
        typed: str | None = encode_typed(options)
        held = "exact in the options_typed column"
    except RecursionError:
        typed, held = None, "nested too deeply"
    except (TypeError, ValueError) as exc:  # what the typed form does not hold; too large
        typed, held = None, str(exc)
    except Exception as exc:  # (a key's repr() raises)
        typed, held = None, error_text(exc)
    why = held if loss is None else f"{loss}; {held}"
    return RecordedOptions(plain, typed, _options_note(options, why), text)


def changed_in_reset(before: RecordedOptions | None, options: Any) -> RecordedOptions | None:
    """The options of sub-envs that were all reset with ``options`` if the reset changed them.

    ``before``: :func:`recordable_options` of ``options`` before the reset. ``None`` when the
    reset left them as they were (or the file does not hold them anyway): each sub-env was
    reset with them as recorded. Otherwise an earlier sub-env's reset may have changed what a
    later one was given, and what each was given is unknown: noted, no typed form.
    """
    if before is None or (before.noted is not None and before.typed is None):
        return None
    after = recordable_options(options)
    if after is not None and (after.plain, after.typed) == (before.plain, before.typed):
        return None
    why = "the env changed its options during reset(): what each sub-env received is unknown"
    return RecordedOptions(before.plain, None, note("options_unserializable", why), before.text)


def _shown(options: Any) -> dict[str, str]:
    """What the file holds of options plain JSON cannot be written of: their ``repr``."""
    return {"repr": short(options)}


def _options_note(options: Any, why: str) -> str:
    return note("options_unserializable", f"{short(options)} ({why})")
