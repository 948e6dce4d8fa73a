"""Reward terms on the batched vector path: a step's info read once, its terms kept in columns.

A MuJoCo vector env's step info holds each sub-env's reward terms (``reward_dist``,
``reward_ctrl``, ...) in Gymnasium's vector dict form: an array per key, one entry per sub-env,
and a ``_key`` mask. :func:`step_terms` reads such an info for the batched path (or declines:
the step is then recorded sub-env by sub-env), and :class:`TermBatch` keeps the batched steps'
terms and hands each sub-env's to its block with its rows, as :meth:`Stream.step
<episode_audit.record.stream.Stream.step>` would have added them one step at a time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..block import Block
from .infos import EMPTY

__all__ = ["StepTerms", "TermBatch", "step_terms"]

_BOOL = np.dtype(np.bool_)
_Names = tuple[str, ...]


class StepTerms(NamedTuple):
    """A vector step's info as the batched path takes it.

    Attributes:
        info: The vector info.
        keys: Its keys (the masks left out).
        names: The reward terms the streams read from infos with these keys (maybe none).
        values: Each term's array (one entry per sub-env), in the order of ``names``.
        present: Which sub-envs the info has entries for (all of its keys, or none).
    """

    info: dict[str, Any]
    keys: tuple[str, ...]
    names: _Names
    values: tuple[np.ndarray[Any, Any], ...]
    present: list[bool]

    def env_info(self, i: int) -> dict[str, Any]:
        """Sub-env ``i``'s info, as :func:`~.infos.split_info` gives it."""
        if not self.present[i]:
            return EMPTY
        info = self.info
        return {key: info[key][i] for key in self.keys}


def step_terms(
    info: dict[Any, Any],
    n: int,
    resetting: Sequence[int],
    names_for: Callable[[tuple[Any, ...]], _Names | None],
) -> StepTerms | None:
    """``info`` as the batched path takes it; ``None``: the step is recorded sub-env by sub-env.

    It takes the vector dict form when each key has a ``_key`` mask (a bool array of ``n``)
    and an array of ``n`` entries, each sub-env has entries for all keys or for none (none for
    the sub-envs the step only resets, ``resetting``), the streams read the terms by name
    (``names_for``: :meth:`Stream.term_names <episode_audit.record.stream.Stream.term_names>`),
    and each term's array holds floats.

    >>> info = {"reward_a": np.array([0.5, 1.0]), "_reward_a": np.array([True, True])}
    >>> terms = step_terms(info, 2, [], lambda keys: keys)
    >>> terms.names, terms.env_info(1)
    (('reward_a',), {'reward_a': np.float64(1.0)})
    >>> step_terms(info, 2, [1], lambda keys: keys) is None  # a reset-only step has no terms
    True
    """
    keys: list[str] = []
    present: list[bool] | None = None
    for key, value in info.items():
        if type(key) is not str:
            return None
        if key[:1] == "_" and key[1:] in info:  # the mask of another key
            if "_" + key in info:
                return None  # (a mask with a mask: the general reading)
            continue
        mask = info.get("_" + key)
        if (
            type(value) is not np.ndarray
            or value.shape != (n,)
            or type(mask) is not np.ndarray
            or mask.dtype is not _BOOL
            or mask.shape != (n,)
        ):
            return None
        here = mask.tolist()
        if present is None:
            present = here
        elif here != present:
            return None
        keys.append(key)
    if present is None or any(present[i] for i in resetting):
        return None
    names = names_for(tuple(keys))
    if names is None:
        return None
    values = tuple(info[name] for name in names)
    if any(v.dtype.kind != "f" for v in values):
        return None
    return StepTerms(info, tuple(keys), names, values, present)


class TermBatch:
    """The reward terms of a batch of vector steps (``rows`` steps of ``n`` sub-envs).

    Every step of the batch that has terms has the same ``names``; a row without terms (a
    step with no info, or a sub-env the info has no entries for) is not ``present``.
    """

    __slots__ = ("names", "present", "values")

    def __init__(self, rows: int, n: int, names: _Names) -> None:
        self.names = names
        self.values = np.empty((rows, n, len(names)), dtype=np.float64)
        self.present = np.zeros((rows, n), dtype=np.bool_)

    def keep(self, t: int, terms: StepTerms) -> None:
        """Keep ``terms`` (of ``names``) as batched step ``t``'s."""
        row = self.values[t]
        for j, value in enumerate(terms.values):
            row[:, j] = value
        self.present[t] = terms.present

    def hand_over(
        self, block: Block, first_row: int, steps: slice | np.ndarray[Any, Any], i: int
    ) -> None:
        """Add sub-env ``i``'s terms of batched ``steps`` to its ``block``.

        The steps are the block's rows from ``first_row`` on; each row's terms go in as
        :meth:`Stream.step` adds a step's.
        """
        hit = np.flatnonzero(self.present[steps, i])
        if not len(hit):
            return
        values = self.values[steps, i][hit]
        block.term_rows.frombytes((hit + first_row).astype(np.int64).tobytes())
        block.term_counts.frombytes(np.full(len(hit), len(self.names), np.int64).tobytes())
        block.term_keys.extend(self.names * len(hit))
        block.term_vals.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
