"""Reward terms on the batched vector path: a step's info read once, its terms kept in columns.

A MuJoCo vector env's step info holds each sub-env's reward terms (``reward_dist``,
``reward_ctrl``, ...) in Gymnasium's vector dict form: an array per key, one entry per sub-env,
and a ``_key`` mask. :func:`step_terms` reads such an info for the batched path (or declines:
the step is then recorded sub-env by sub-env), and :class:`TermBatch` keeps the batched steps'
terms and hands each sub-env's to its block with its rows, as :meth:`Stream.step
<episode_audit.record.stream.Stream.step>` would have added them one step at a time.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..block import Block
from .infos import EMPTY

__all__ = ["StepTerms", "TermBatch", "TermColumns", "TermNames", "list_terms", "step_terms"]

_BOOL = np.dtype(np.bool_)
_NUMBERS = frozenset({float, np.float64, np.float32})  # (array("d") takes them exactly)
_Names = tuple[str, ...]
TermNames = Callable[[tuple[Any, ...]], "tuple[str, ...] | None"]
"""How the streams read reward terms from an info's keys (:meth:`Stream.term_names
<episode_audit.record.stream.Stream.term_names>`)."""


class StepTerms(NamedTuple):
    """A vector step's info as the batched path takes it.

    Attributes:
        names: The reward terms the step's rows have (maybe none).
        values: Their values, a row of ``len(names)`` per sub-env (``None`` without names).
        present: Which sub-envs' rows have them.
        infos: The sub-envs' infos: each one's dict (a list of per-sub-env infos), or the
            vector dict (Gymnasium's form; then ``keys`` are its keys, the masks left out).
        keys: See ``infos``.
    """

    names: _Names
    values: np.ndarray[Any, np.dtype[np.float64]] | None
    present: list[bool]
    infos: Any
    keys: tuple[str, ...] | None = None

    def env_info(self, i: int) -> Any:
        """Sub-env ``i``'s info, as :func:`~.infos.env_infos` gives it."""
        keys, infos = self.keys, self.infos
        if keys is None:
            return infos[i]
        if not self.present[i]:
            return EMPTY
        return {key: infos[key][i] for key in keys}


def step_terms(
    info: dict[Any, Any],
    n: int,
    resetting: Sequence[int],
    names_for: TermNames,
) -> StepTerms | None:
    """Gymnasium's vector dict form of an info, as the batched path takes it (or ``None``).

    ``None``: the step is recorded sub-env by sub-env. It takes the info when each key has a
    ``_key`` mask (a bool array of ``n``) and an array of ``n`` entries, each sub-env has
    entries for all keys or for none (none for the sub-envs the step only resets,
    ``resetting``), the streams read the terms by name (``names_for``: :meth:`Stream.term_names
    <episode_audit.record.stream.Stream.term_names>`), and each term's array holds floats.

    >>> info = {"reward_a": np.array([0.5, 1.0]), "_reward_a": np.array([True, True])}
    >>> terms = step_terms(info, 2, [], lambda keys: keys)
    >>> terms.names, terms.values.tolist(), terms.env_info(1) == {"reward_a": 1.0}
    (('reward_a',), [[0.5], [1.0]], True)
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
    values = None
    if names:
        columns = [info[name] for name in names]
        if any(c.dtype.kind != "f" for c in columns):
            return None
        values = np.empty((n, len(names)), dtype=np.float64)
        for j, column in enumerate(columns):
            values[:, j] = column
    return StepTerms(names, values, present, info, tuple(keys))


def list_terms(
    infos: Sequence[Any],
    resetting: Sequence[int],
    names_for: TermNames,
    finals: Mapping[int, dict[str, Any]] | None = None,
) -> StepTerms | None:
    """A list of per-sub-env infos as the batched path takes it (or ``None``).

    ``None``: the step is recorded sub-env by sub-env. ``finals``: the ``SAME_STEP`` endings'
    step infos (``final_info``), whose terms the ending rows have. It takes the infos when every
    one is a dict (an empty one for the sub-envs the step only resets), the streams read the
    terms by name, the same names in every info that has terms, and each value is a float (a
    Python or a numpy one: the step path takes them as they are).

    >>> terms = list_terms([{"reward_a": 0.5, "x": "?"}, {}], [], lambda keys: keys[:1])
    >>> terms.names, terms.values.tolist(), terms.present
    (('reward_a',), [[0.5], [0.0]], [True, False])
    >>> list_terms([{"reward_a": "0.5"}], [], lambda keys: keys) is None  # text: not a number
    True
    """
    names: _Names | None = None
    flat: list[Any] = []  # the values of the infos with terms, in order
    present: list[bool] = []
    last_keys: tuple[Any, ...] | None = None  # (the infos of a step mostly share their keys)
    here: _Names | None = ()
    get: Callable[[dict[str, Any]], Any] = tuple
    for i, info in enumerate(infos):
        if finals is not None and i in finals:
            info = finals[i]
        if type(info) is not dict:
            return None
        if not info:
            present.append(False)
            continue
        if i in resetting:
            return None  # (a reset info: the autoreset reads it on the slow path)
        keys = tuple(info)
        if keys != last_keys:
            last_keys, here = keys, names_for(keys)
            if here is None:
                return None
            get = operator.itemgetter(*here) if here else tuple
        if not here:
            present.append(False)
            continue
        if names is None:
            names = here
        elif here != names:
            return None
        if len(here) == 1:
            flat.append(get(info))
        else:
            flat.extend(get(info))
        present.append(True)
    if names is None:
        return StepTerms((), None, present, infos)
    if not {type(v) for v in flat} <= _NUMBERS:
        return None
    rows = np.array(flat, dtype=np.float64).reshape(-1, len(names))
    if len(rows) == len(present):
        return StepTerms(names, rows, present, infos)
    values = np.zeros((len(present), len(names)), dtype=np.float64)
    values[[i for i, here in enumerate(present) if here]] = rows
    return StepTerms(names, values, present, infos)


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
        self.values[t] = terms.values
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


class TermColumns:
    """A vector recorder's reward terms on the batched path.

    How a step's info is read (``names_for``: the streams' rule, :data:`TermNames`), and the
    current batch's terms.
    """

    __slots__ = ("_n", "batch", "names_for")

    def __init__(self, n: int, names_for: TermNames) -> None:
        self._n = n
        self.names_for = names_for
        self.batch: TermBatch | None = None  # (None until a batched step has terms)

    def read(self, infos: Any, resetting: Sequence[int]) -> StepTerms | None:
        """A step's info as the batched path takes it, or ``None`` (sub-env by sub-env)."""
        if type(infos) is dict:
            return step_terms(infos, self._n, resetting, self.names_for)
        if type(infos) is list and len(infos) == self._n:
            return list_terms(infos, resetting, self.names_for)
        return None

    def fits(self, terms: StepTerms) -> bool:
        """Whether ``terms`` go into the current batch (its steps' terms have their names)."""
        batch = self.batch
        return not terms.names or batch is None or batch.names == terms.names

    def keep(self, t: int, rows: int, terms: StepTerms) -> None:
        """Keep ``terms`` as batched step ``t``'s, in a batch of ``rows`` steps.

        The batch :meth:`fits` them (the caller checked).
        """
        if not terms.names:
            return
        batch = self.batch
        if batch is None:
            batch = self.batch = TermBatch(rows, self._n, terms.names)
        batch.keep(t, terms)

    def take(self) -> TermBatch | None:
        """The batch's terms, for their hand-over; the next batch starts without any."""
        batch, self.batch = self.batch, None
        return batch
