"""What a vector ``reset()`` does to each sub-env: which ones it resets, and with which seed.

``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (a list seeds each in turn);
``options["reset_mask"]`` selects the sub-envs reset (and is left out of the recorded options).
The options are recorded before the reset (:func:`recorded_per_env`); when sub-envs were given one
options object and the reset changed it, what each was given is unknown (:func:`shared_changed`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..values import RecordedOptions, changed_in_reset, recordable_options

__all__ = ["recorded_per_env", "refused", "reset_targets", "seeds_of", "shared_changed"]


def reset_targets(options: Any, n: int) -> tuple[list[int], Any]:
    """The sub-envs a ``reset(options=options)`` resets, and the options their episodes record.

    Only a mapping's ``reset_mask`` (a mask of ``n`` values) selects sub-envs; options that are
    not a mapping are passed to every sub-env and recorded as they are (``{}`` too: a sub-env
    is given ``{}`` for ``{"reset_mask": mask}``).
    """
    if not isinstance(options, Mapping):
        return list(range(n)), options
    indices: Sequence[int] | np.ndarray[Any, Any] = range(n)
    if "reset_mask" in options:
        try:
            mask = np.asarray(options["reset_mask"]).astype(bool).reshape(-1)
        except Exception:  # not a mask (the env refuses it)
            mask = None
        if mask is not None and mask.size == n:
            indices = np.flatnonzero(mask)
    recorded = {k: v for k, v in options.items() if k != "reset_mask"}
    return [int(i) for i in indices], recorded


def recorded_per_env(passed: Sequence[Any]) -> list[RecordedOptions | None]:
    """Each sub-env's options as recorded, taken before the reset; one options object once."""
    encoded: dict[int, RecordedOptions | None] = {}
    out = []
    for options in passed:
        if id(options) not in encoded:
            encoded[id(options)] = recordable_options(options)
        out.append(encoded[id(options)])
    return out


def shared_changed(
    recorded: list[RecordedOptions | None], after: Sequence[Any], indices: Sequence[int]
) -> list[RecordedOptions | None]:
    """``recorded`` (:func:`recorded_per_env`), where the reset changed shared options, noted.

    Sub-envs of ``indices`` with the same recorded entry were given one options object, reset
    in turn: when ``after`` (that object after the reset) differs from what was recorded, an
    earlier sub-env's reset changed what a later one was given, and each one's entry is
    :func:`~..values.changed_in_reset`'s. Options given to one sub-env are as recorded.
    """
    sharing: dict[int, list[int]] = {}
    for i in indices:
        if recorded[i] is not None:
            sharing.setdefault(id(recorded[i]), []).append(i)
    out = list(recorded)
    for group in sharing.values():
        changed = changed_in_reset(recorded[group[0]], after[group[0]]) if len(group) > 1 else None
        for i in group if changed is not None else ():
            out[i] = changed
    return out


def seeds_of(seed: Any, n: int, sub_envs: bool) -> list[Any]:
    """The seed each sub-env's reset gets from ``reset(seed=seed)`` (as Gymnasium's do).

    ``None`` for each sub-env of a vector env without sub-envs (one RNG drives them all).
    """
    if seed is None or not sub_envs:
        return [None] * n
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + i for i in range(n)]
    try:
        seeds = list(seed)
    except TypeError:  # not a seed (the env refuses it)
        return [None] * n
    return (seeds + [None] * n)[:n]


def refused(seed: Any, options: Any, n: int) -> bool:
    """Whether Gymnasium's vector envs refuse these reset arguments before resetting any sub-env.

    (A seed that is neither ``None``, an int nor ``n`` seeds; a ``reset_mask`` that is not a bool
    array of shape ``(n,)`` with a true value.) Such a refused reset changes no episode.
    """
    if seed is not None and not isinstance(seed, int):
        try:
            if len(seed) != n:
                return True
        except TypeError:
            return True
    if isinstance(options, Mapping) and "reset_mask" in options:
        mask = options["reset_mask"]
        return not (
            isinstance(mask, np.ndarray)
            and mask.shape == (n,)
            and mask.dtype == np.bool_
            and bool(mask.any())
        )
    return False
