"""What the replayed env returned: kept as it comes while stepping, then as columns to compare.

The stepping loop fills :class:`Rows` (observations), :class:`Steps` (rewards, flags, infos)
and :class:`Ran` (each episode's rows and how its stepping ended, one :class:`Stepped` each);
:class:`Got` makes them the columns compared with the evidence, with :class:`Terms` (the reward
terms, read from the infos as the recorder reads them: :func:`recorded_terms`).
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from io import BytesIO
from itertools import chain
from typing import Any

import numpy as np
import pyarrow as pa

from ..format.columns import (
    PLAIN_NUMBERS,
    number,
    number_or_nan,
    terms_column,
    terms_matrix_column,
)
from ..format.spaces import SpaceCodec
from ..record.rules import RewardTerms, named_terms, plain_names
from .results import Divergence, env_error

__all__ = ["Got", "Ran", "Rows", "Stepped", "Steps", "Terms", "encoded", "recorded_terms"]


@dataclass(slots=True)
class Stepped:
    """One episode as it was stepped: where its rows are and how its stepping ended."""

    record: dict[str, Any]
    count: int  # rows recorded
    first: int  # its first row in the compared columns
    ran: int  # steps taken
    crash: Divergence | None
    last_info: Any
    hit_time_limit: bool


@dataclass
class Ran:
    """The stepped episodes, in order, as parallel lists.

    The stepping loop appends one tuple per episode to :attr:`stepped` (cheaper than an
    object, or an append per list); :meth:`finish` makes the lists. :meth:`episode` gives one
    episode as a :class:`Stepped`.
    """

    # (record, start, count, ran, last info, hit, reset row) per episode, until finish() (the
    # reset row is never None: an episode without one is not stepped)
    stepped: list[tuple[dict[str, Any], int, int, int, Any, bool, int | None]] = field(
        default_factory=list
    )
    records: list[dict[str, Any]] = field(default_factory=list)
    starts: list[int] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    ran: list[int] = field(default_factory=list)
    last_infos: list[Any] = field(default_factory=list)
    hits: list[bool] = field(default_factory=list)  # whether its TimeLimit was reached
    reset_at: list[int] = field(default_factory=list)  # its row in the resets table
    crashes: dict[int, Divergence] = field(default_factory=dict)  # by position

    def finish(self) -> Ran:
        """Turn the stepped tuples into the parallel lists."""
        if self.stepped:
            columns = [list(c) for c in zip(*self.stepped, strict=True)]
            (
                self.records,
                self.starts,
                self.counts,
                self.ran,
                self.last_infos,
                self.hits,
                self.reset_at,
            ) = columns
            self.stepped = []
        return self

    def episode(self, k: int, first: int) -> Stepped:
        """The ``k``-th episode, whose first compared row is ``first``."""
        return Stepped(
            self.records[k],
            self.counts[k],
            first,
            self.ran[k],
            self.crashes.get(k),
            self.last_infos[k],
            self.hits[k],
        )


class Rows:
    """Values of one column as a replay gets them, copied as they come.

    (An env may change an array it returned.) A C-contiguous array of exactly the column's
    dtype and shape is kept as its raw bytes: the stepping loop writes it to :attr:`raw`
    itself (no object per row). Any other value goes through :meth:`add` and the column's
    buffer.
    """

    def __init__(self, codec: SpaceCodec) -> None:
        self.codec = codec
        self.dtype: np.dtype[Any] | None = None
        self.shape: tuple[int, ...] | None = None
        self._row_bytes = 0
        if codec.raw_rows is not None:
            dtype, shape = codec.raw_rows
            self._row_bytes = dtype.itemsize * math.prod(shape)
            if self._row_bytes:  # (rows of no bytes could not be counted)
                self.dtype, self.shape = dtype, shape
        self.raw = BytesIO()  # the raw rows, back to back
        self._buffer = codec.new_buffer()
        self._added: list[int] = []  # the rows that went through add()

    def __len__(self) -> int:
        raw = self.raw.tell() // self._row_bytes if self._row_bytes else 0
        return raw + len(self._added)

    def add(self, value: Any) -> None:
        """Add one row through the column's buffer (a null row if it cannot be encoded)."""
        self._added.append(len(self))
        try:
            self._buffer.append(value)
        except Exception:  # not encodable (whatever the value raised): a null row
            self._buffer.append_null()

    def keep(self, value: Any) -> None:
        """Add one row, whatever it is (the stepping loop inlines the raw case)."""
        if type(value) is np.ndarray and value.dtype is self.dtype and value.shape == self.shape:
            try:
                self.raw.write(value)  # type: ignore[arg-type]  # (an ndarray is a buffer)
                return
            except ValueError:  # not C-contiguous
                pass
        self.add(value)

    def finish(self) -> pa.Array:
        """The column of the rows added so far."""
        n, added = len(self), self._added
        if n and not added:
            return self.codec.from_raw(self.raw.getvalue())
        via_buffer = self._buffer.finish()
        if len(added) == n:
            return via_buffer
        raw = self.codec.from_raw(self.raw.getvalue())
        order = np.empty(n, dtype=np.int64)
        is_added = np.zeros(n, dtype=np.bool_)
        is_added[added] = True
        order[~is_added] = np.arange(n - len(added))
        order[is_added] = np.arange(n - len(added), n)
        return pa.concat_arrays([raw, via_buffer]).take(pa.array(order))


@dataclass
class Steps:
    """What the steps returned (but the observations), in order.

    No tuple is kept per step: many live tuples make the garbage collector walk them again
    and again (a third of the replay's own time on CartPole).
    """

    rewards: list[Any] = field(default_factory=list)
    ends: list[tuple[int, Any, Any]] = field(default_factory=list)  # each episode's last step
    info_rows: list[int] = field(default_factory=list)  # the steps whose info is not empty
    infos: list[Any] = field(default_factory=list)  # and their infos


@dataclass
class Got:
    """The replayed values, one row per compared row (rows never stepped: null, NaN, 0)."""

    obs: pa.Array
    rewards: np.ndarray[Any, Any]  # float64
    terminated: np.ndarray[Any, Any]  # int8: 0, 1, or 2 for a value bool() refused
    truncated: np.ndarray[Any, Any]
    terms: Terms
    reward_errors: dict[int, str] = field(default_factory=dict)
    """By compared row: what ``float()`` of a reward that is not a number raised."""

    @classmethod
    def collect(
        cls,
        steps: Steps,
        ran: np.ndarray[Any, Any],
        firsts: np.ndarray[Any, Any],
        obs: pa.Array,
        n: int,
        terms_rule: RewardTerms | None,
    ) -> Got:
        """Columns of ``n`` rows from what the episodes' ``steps`` returned.

        Each episode took ``ran`` steps and its recorded rows start at ``firsts`` in the
        compared columns.
        """
        rewards, refused = _rewards(steps.rewards)
        total = len(steps.rewards)
        terminated = np.zeros(total, dtype=np.int8)
        truncated = np.zeros(total, dtype=np.int8)
        if steps.ends:
            last, term, trunc = zip(*steps.ends, strict=True)
            terminated[list(last)] = _flags(list(term))
            truncated[list(last)] = _flags(list(trunc))
        if total == n:  # every recorded row was stepped
            positions: np.ndarray[Any, Any] = np.arange(n)
        else:
            positions = np.repeat(firsts, ran) + (
                np.arange(total) - np.repeat(np.cumsum(ran) - ran, ran)
            )
            index = np.full(n, -1, dtype=np.int64)
            index[positions] = np.arange(total)
            obs = obs.take(pa.array(index, mask=index < 0))
            rewards = _scatter(rewards, positions, n, np.nan)
            terminated = _scatter(terminated, positions, n, 0)
            truncated = _scatter(truncated, positions, n, 0)
        terms = Terms(n)
        if terms_rule is not None and steps.infos:
            terms.read(terms_rule, positions[steps.info_rows], steps.infos)
        errors = {int(positions[i]): why for i, why in refused.items()}
        return cls(obs, rewards, terminated, truncated, terms, errors)


def encoded(codec: SpaceCodec, values: Iterable[Any]) -> pa.Array:
    """The column of ``values``: a null row for one it cannot hold (whatever that raised)."""
    buffer = codec.new_buffer()
    for value in values:
        try:
            buffer.append(value)
        except Exception:  # the env's own object, not encodable
            buffer.append_null()
    return buffer.finish()


def recorded_terms(
    extract: Callable[[Mapping[str, Any]], dict[str, Any] | None], info: Any
) -> dict[str, float] | None:
    """One step's terms as the recorder's ``Stream._slow_values`` records them (no notes).

    None when the info is not a mapping or its terms cannot be read; each value is
    :func:`~episode_audit.format.columns.number_or_nan` of it; names are the recorder's
    (:func:`~episode_audit.record.rules.named_terms`).
    """
    if not isinstance(info, Mapping):
        return None
    try:
        raw = extract(info)
        if raw is None:
            return None
        return named_terms(list(raw), [number_or_nan(value) for value in raw.values()])[0]
    except Exception:  # terms that cannot be read: none, as the recorder noted
        return None


_JUST_DICTS = frozenset({dict})


@dataclass
class Terms:
    """The replayed reward terms of ``n`` rows.

    Either a dict per row in ``found``, or (the usual case) one tuple of ``names`` and a
    float64 row of ``values`` for each row in ``rows``.
    """

    n: int
    found: dict[int, dict[str, Any]] = field(default_factory=dict)
    rows: np.ndarray[Any, Any] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    names: tuple[str, ...] = ()
    values: np.ndarray[Any, Any] | None = None

    def read(self, rule: RewardTerms, rows: np.ndarray[Any, Any], infos: list[Any]) -> None:
        """Read the terms of the steps at ``rows`` from their ``infos``, as the recorder does.

        Dict infos whose terms are all plain numbers with plain names are read as they are, as
        the recorder's fast path reads them; anything else (an info that is not a dict, terms
        that cannot be read, a value that is not a plain number, a name that is not plain text)
        info by info, as the recorder's slow path reads it (:func:`recorded_terms`). No info
        makes this raise.
        """
        self.rows = rows
        try:
            many = rule.extract_many(infos)
        except Exception:  # an info that is not a dict (a list, a number): step by step
            many = None
        if many is not None:
            self.names, self.values = many  # plain names (names_for): as they are
            return
        extract = rule.extractor
        found: dict[int, dict[str, Any]] = {}
        if set(map(type, infos)) == _JUST_DICTS:
            try:
                for row, info in zip(rows.tolist(), infos, strict=True):
                    terms = extract(info)
                    if terms is not None:
                        found[row] = terms
            except Exception:  # terms that cannot be read: info by info
                pass
            else:
                if self._keep_if_plain(found):
                    return
            found = {}
        for row, info in zip(rows.tolist(), infos, strict=True):
            terms = recorded_terms(extract, info)
            if terms is not None:
                found[row] = terms
        self.found = found

    def _keep_if_plain(self, found: dict[int, dict[str, Any]]) -> bool:
        """Keep ``found`` if its values are plain numbers and its names plain; say if it was kept.

        (The ``terms`` column reads other values its own way, e.g. parses text, where the
        recorder writes NaN; other names are the recorder's :func:`named_terms`.) When every
        step has the same names: as a matrix.
        """
        dicts = list(found.values())
        if not plain_names(set(chain.from_iterable(dicts))):
            return False
        if dicts:
            names = tuple(dicts[0])
            many = RewardTerms(names).extract_many(dicts)
            if many is not None:
                self.rows = np.fromiter(found, dtype=np.int64, count=len(found))
                self.names, self.values = names, many[1]
                return True
        if not set(map(type, chain.from_iterable(map(dict.values, dicts)))) <= PLAIN_NUMBERS:
            return False
        self.found = found  # plain names: as the recorder's fast path writes them
        return True

    def column(self) -> pa.Array:
        """The ``terms`` map column of the ``n`` rows (null where a step had none)."""
        if self.values is None:
            return terms_column(self.n, self.found)
        return terms_matrix_column(self.n, self.rows, self.names, self.values)

    def at(self, row: int) -> dict[str, Any]:
        """The terms of one row (empty if it had none)."""
        if self.values is None:
            return self.found.get(row, {})
        hit = np.flatnonzero(self.rows == row)
        if not hit.size:
            return {}
        return dict(zip(self.names, self.values[int(hit[0])].tolist(), strict=True))


def _scatter(
    values: np.ndarray[Any, Any], positions: np.ndarray[Any, Any], n: int, fill: Any
) -> np.ndarray[Any, Any]:
    out = np.full(n, fill, dtype=values.dtype)
    out[positions] = values
    return out


def _rewards(values: list[Any]) -> tuple[np.ndarray[Any, Any], dict[int, str]]:
    """Rewards as float64, and why each one that is not a number is NaN, by position.

    As the recorder reads them (:func:`~episode_audit.format.columns.number_or_nan`): a text
    reward is not parsed; an int too large for a float, or a value whose ``float()`` raises
    whatever it raises, is NaN too.
    """
    if set(map(type, values)) <= PLAIN_NUMBERS:  # (else arrays, text...: value by value)
        try:
            return np.frombuffer(array("d", values), dtype=np.float64), {}
        except Exception:
            pass
    out = array("d")
    refused: dict[int, str] = {}
    for i, value in enumerate(values):
        try:
            if isinstance(value, np.ndarray):
                number(value)  # (an array of one or more dimensions raises)
            out.append(value)
        except Exception as exc:  # the env's own object: whatever its __float__ raised
            out.append(math.nan)
            refused[i] = env_error(exc)
    return np.frombuffer(out, dtype=np.float64), refused


def _flags(values: list[Any]) -> np.ndarray[Any, Any]:
    """Flags as int8: 0 or 1 by ``bool()``, 2 where ``bool()`` refuses (an array of many)."""
    try:
        return np.array(list(map(bool, values)), dtype=np.int8)
    except Exception:
        out = np.empty(len(values), dtype=np.int8)
        for i, value in enumerate(values):
            try:
                out[i] = bool(value)
            except Exception:
                out[i] = 2
        return out
