"""Key sets that change within an episode: ``terms_keys_changed`` and ``info_keys_changed``.

A step's key set is summarised by a 64-bit signature (the wrapping sum of one hash per name),
so a block is compared with numpy; names are looked up only for the first change in the file.
:class:`KeyChecks` tracks the reward-term names and the kept info keys, block by block.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..format.columns import null_mask
from ..format.records import from_json, listing
from ._state import BoolArray, FileState, IntArray
from .registry import INFO_KEYS_CHANGED, TERMS_KEYS_CHANGED

__all__ = ["KeyChecks"]

_HASH_MASK = (1 << 64) - 1
_Signatures = npt.NDArray[np.uint64]


class _KeySets:
    """Per episode, the key set of its previous step; counts the steps where it changed."""

    def __init__(self, code: str, noun: str) -> None:
        self.code = code
        self.noun = noun
        self.carry: dict[int, tuple[int, int]] = {}  # episode -> (signature, row) of last step
        self.carry_names: Callable[[int], list[str]] | None = None
        self.changed: set[int] = set()
        self.first: tuple[int, int, list[str], list[str]] | None = None

    def add(
        self,
        episode: IntArray,
        step: IntArray,
        signature: _Signatures,
        mask: BoolArray,
        names: Callable[[int], list[str]],
    ) -> None:
        """Compare the rows in ``mask`` (``names(row)`` gives a row's keys, for messages)."""
        rows = np.flatnonzero(mask)
        if rows.size == 0:
            return
        eps = episode[rows]
        if not (eps[1:] >= eps[:-1]).all():
            order = np.argsort(eps, kind="stable")
            rows, eps = rows[order], eps[order]
        sig = signature[rows]
        boundary = eps[1:] != eps[:-1]
        first_of = np.concatenate(([True], boundary))
        previous = np.concatenate((sig[:1], sig[:-1]))
        changed = ~first_of & (sig != previous)
        from_carry: dict[int, int] = {}
        if self.carry:
            for i in np.flatnonzero(first_of).tolist():
                before = self.carry.get(int(eps[i]))
                if before is not None and before[0] != int(sig[i]):
                    changed[i] = True
                    from_carry[i] = before[1]
        if changed.any():
            hit = np.flatnonzero(changed)
            self.changed.update(eps[hit].tolist())
            if self.first is None:
                i = int(hit[0])
                old = (
                    self.carry_names(from_carry[i])
                    if i in from_carry and self.carry_names is not None
                    else names(int(rows[i - 1]))
                )
                self.first = (int(eps[i]), int(step[rows[i]]), old, names(int(rows[i])))
        last = np.concatenate((boundary, [True]))
        self.carry = dict(
            zip(
                eps[last].tolist(),
                zip(sig[last].tolist(), rows[last].tolist(), strict=True),
                strict=True,
            )
        )
        self.carry_names = names

    def finding(self, state: FileState) -> None:
        """After the steps: the file's one finding, if a key set changed."""
        if self.first is None:
            return
        episode, step, old, new = self.first
        eps = sorted(self.changed)
        added = sorted(set(new) - set(old))
        removed = sorted(set(old) - set(new))
        state.finding(
            self.code,
            f"{self.noun} keys changed between steps in {len(eps)} episode(s) (episodes "
            f"{listing(eps)}); first at step {step} of episode {episode}: added {added}, "
            f"removed {removed}",
            episode,
            step,
        )


class KeyChecks:
    """The reward-term names and kept info keys of one file, from step to step."""

    def __init__(self, state: FileState) -> None:
        self.state = state
        self.term_keys = _KeySets(TERMS_KEYS_CHANGED, "reward-term")
        self.info_keys = _KeySets(INFO_KEYS_CHANGED, "info")

    def terms(self, terms: pa.Array, episode: IntArray, step: IntArray) -> None:
        """Track the set of reward-term names from step to step (``terms_keys_changed``)."""
        if terms.null_count == len(terms):
            return
        offsets: IntArray = terms.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
        lo, hi = int(offsets[0]), int(offsets[-1])
        if hi == lo:
            return
        keys = terms.keys.slice(lo, hi - lo)
        lengths = np.diff(offsets)

        def names(row: int) -> list[str]:
            return sorted(
                str(k) for k in keys[offsets[row] - lo : offsets[row + 1] - lo].to_pylist()
            )

        n = len(terms)
        width = int(lengths[0])
        uniform = terms.null_count == 0 and width and bool((lengths == width).all())
        if uniform and (n == 1 or _same_names_every_row(keys, n, width)):
            sig, _ = _signatures([names(0)])
            every = np.ones(n, dtype=np.bool_)
            self.term_keys.add(episode, step, np.full(n, sig[0], np.uint64), every, names)
            return
        encoded = pc.dictionary_encode(keys)
        weights, _ = _signatures([[k] for k in encoded.dictionary.to_pylist()])
        per_value = weights[encoded.indices.to_numpy(zero_copy_only=False)]
        signature = np.add.reduceat(np.append(per_value, np.uint64(0)), offsets[:-1] - lo)
        mask = (lengths > 0) & ~null_mask(terms)
        self.term_keys.add(episode, step, signature.astype(np.uint64), mask, names)

    def info(self, info: pa.Array, episode: IntArray, step: IntArray) -> None:
        """Track the set of kept info keys from step to step (``info_keys_changed``)."""
        if info.null_count == len(info):
            return
        encoded = pc.dictionary_encode(info)
        distinct: list[list[str] | None] = []
        for text in encoded.dictionary.to_pylist():
            try:
                value = from_json(text, "info")
            except ValueError:
                value = None
            distinct.append(sorted(str(k) for k in value) if isinstance(value, dict) else None)
        sig, has = _signatures(distinct)
        size = len(distinct)
        indices = encoded.indices.fill_null(size).to_numpy(zero_copy_only=False)
        signature = np.append(sig, np.uint64(0))[indices]
        mask = np.append(has, False)[indices]

        def names(row: int) -> list[str]:
            return distinct[int(indices[row])] or []

        self.info_keys.add(episode, step, signature, mask, names)

    def findings(self) -> None:
        """After the steps: one finding per key set that changed."""
        self.term_keys.finding(self.state)
        self.info_keys.finding(self.state)


def _signatures(names: list[list[str] | None]) -> tuple[_Signatures, BoolArray]:
    """A key-set signature per entry, and whether the entry has keys at all."""
    sig = np.zeros(len(names), dtype=np.uint64)
    has = np.zeros(len(names), dtype=np.bool_)
    for i, keys in enumerate(names):
        if keys:
            sig[i] = sum(hash(k) & _HASH_MASK for k in keys) & _HASH_MASK
            has[i] = True
    return sig, has


def _same_names_every_row(keys: pa.Array, rows: int, width: int) -> bool:
    """Whether ``rows`` rows of ``width`` keys each repeat the first row's keys, in order.

    The usual case, checked on the string buffers (one ``memcmp``), not string by string.
    """
    if keys.type != pa.string() or keys.null_count:
        return False
    start = keys.offset
    bounds = np.frombuffer(keys.buffers()[1], dtype=np.int32)[start : start + len(keys) + 1]
    lo, hi = int(bounds[0]), int(bounds[-1])
    row = int(bounds[width]) - lo
    if hi - lo != row * rows:
        return False
    sizes = np.diff(bounds).reshape(rows, width)
    if not bool((sizes == sizes[0]).all()):
        return False
    data = np.frombuffer(keys.buffers()[2], dtype=np.uint8, count=hi - lo, offset=lo)
    return bool((data.reshape(rows, row) == data[:row]).all())
