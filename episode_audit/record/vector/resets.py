"""What a vector ``reset()`` does to each sub-env: which ones it resets, and with which seed.

``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (a list seeds each in turn);
``options["reset_mask"]`` selects the sub-envs reset (and is left out of the recorded options).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["refused", "reset_targets", "seeds_of"]


def reset_targets(options: Any, n: int) -> tuple[list[int], Any]:
    """The sub-envs a ``reset(options=options)`` resets, and the options their episodes record.

    Only a mapping's ``reset_mask`` (a mask of ``n`` values) selects sub-envs; options that are
    not a mapping are passed to every sub-env and recorded as they are.
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
    recorded = {k: v for k, v in options.items() if k != "reset_mask"} or None
    return [int(i) for i in indices], recorded


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
