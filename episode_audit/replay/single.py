"""Replay recorded episodes and compare them, step by step, with the evidence.

Each episode is reset from its recorded seed — or, for an unseeded reset, from the RNG state
captured just before it — and stepped with the recorded actions. The reset observation, every
observation, reward, reward terms, ``terminated``, ``truncated`` and the outcome are compared;
the first difference is reported with its step, field, expected and actual values.

How the environment is built, safely (a file may come from anyone):

1. ``env_factory`` (``"module:callable"`` or a callable), given by the user; else
2. the recorded env id, when it is registered in this process (Gymnasium's built-ins, ids
   registered by ``imports`` the user names, and episode-audit's own tasks), with the
   recorded kwargs and ``max_episode_steps``; else
3. only with ``trust_entry_points=True``: the entry point named in the file.

Nothing named inside a file is imported without that flag — including the ``module:`` prefix
Gymnasium's ``make`` would import, and wrappers recorded in the spec that are not Gymnasium's own.

Without ``env_factory``, a file needs its recorded env spec: the recorder writes the env id
whenever the env has a spec, but the spec only when it is JSON-serializable (not when a kwarg
of the env or of a wrapper is, say, a lambda). An id without a spec does not say which kwargs
and wrappers the env had, so such episodes are not replayable: the bare id may be another env,
and its differences would be false divergences.

An env built from its id or spec leaves out Gymnasium's two development-time checks, the
passive env checker and the reset-before-step order check: neither changes what a reset or
step returns (replay always resets first), and together they cost about as much per step as
replay's own work. An env from ``env_factory`` is used as the factory built it.

When the outermost wrapper is exactly Gymnasium's ``TimeLimit`` (either way), the stepping loop
resets and steps the env inside it and counts the limit itself, as the wrapper would: the same
flags and outcomes, without a wrapper call per step (see
:func:`~episode_audit.record.rules.plain_time_limit`).

The re-run env's infos are read as the recorder read the recorded env's: an info that is not a
mapping has no terms, terms that cannot be read are none, a term value that is not a number is
NaN, term names follow the recorder's one rule (:func:`~episode_audit.record.rules.named_terms`: a
name that is not a string is ``str()``-ed, names that then collide are one term, their sum; see
:meth:`_Terms.read`), and a final info the ending rules cannot read gives the ending by the flags
alone. No info makes replay raise.
"""

from __future__ import annotations

import json
import math
from array import array
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field, replace
from io import BytesIO
from itertools import chain
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from .._usercode import load_callable
from ..errors import ConfigurationError, ReplayError
from ..format import names as fmt
from ..format.columns import (
    PLAIN_NUMBERS,
    error_text,
    null_mask,
    number_or_nan,
    one_array,
    terms_column,
    terms_matrix_column,
)
from ..format.records import RunInfo, from_json
from ..format.spaces import SpaceCodec, equal_elements
from ..read import Evidence
from ..record.rules import (
    Ending,
    EndingRules,
    RewardTerms,
    find_time_limit,
    named_terms,
    plain_names,
    plain_time_limit,
    time_limit_hit,
)
from ..record.seeding import restore_rng_state

__all__ = [
    "Divergence",
    "EpisodeReplay",
    "ReplayResult",
    "build_env",
    "replay_single_evidence",
]

Status = Literal["identical", "diverged", "not_replayable"]
EnvFactory = Callable[[], gym.Env[Any, Any]]

_TRUSTED_WRAPPER_PREFIX = "gymnasium.wrappers"
_RECORD_COLUMNS = (
    fmt.COL_EPISODE,
    "seed",
    "rng_state",
    "options",
    "outcome",
    "failure_label",
    "truncation_reason",
    "error_during",
    "length",
)
"""The columns of the episode table a replay reads."""
_RECORD_KEYS = frozenset({fmt.COL_EPISODE, "outcome"})
"""Those it reads as ``record[key]``, listed even when every value is null."""
REPLAY_WINDOW_ROWS = 65_536
"""Replay compares this many steps (of whole episodes) at a time, so memory stays bounded."""
REPLAY_WINDOW_BYTES = 64 << 20
"""… or fewer: as many whole episodes as this many bytes of recorded steps hold (camera
frames), and at least one episode."""


@dataclass(frozen=True)
class Divergence:
    """Where a replay first differed from the evidence (``step`` is ``None`` for the reset)."""

    step: int | None
    field: str
    expected: str
    got: str
    max_abs_diff: float | None = None
    first_difference: str | None = None
    """For an array observation too long to show whole (``expected`` and ``got`` are cut to
    80 characters): the index of the first element that differs, both values and how many
    elements differ."""

    def describe(self) -> str:
        """One line: step, field, expected, got, max abs difference, first difference."""
        where = "reset" if self.step is None else f"step {self.step}"
        notes = []
        if self.max_abs_diff is not None:
            notes.append(f"max abs diff {self.max_abs_diff:.3g}")
        if self.first_difference is not None:
            notes.append(f"first at {self.first_difference}")
        more = f" ({'; '.join(notes)})" if notes else ""
        return f"{where}: {self.field} expected {self.expected}, got {self.got}{more}"

    @classmethod
    def of_observation(
        cls,
        step: int | None,
        expected: Any,
        got: Any,
        max_abs_diff: float | None,
        atol: float,
    ) -> Divergence:
        """An observation that differs (``step`` ``None``: the reset observation).

        When either value is too long to show whole, the first differing element is named.
        """
        shown = _short(expected), _short(got)
        cut = any("..." in text for text in shown)
        return cls(
            step,
            "observation" if step is not None else "reset_observation",
            *shown,
            max_abs_diff,
            _first_difference(expected, got, atol) if cut else None,
        )


@dataclass(frozen=True)
class EpisodeReplay:
    """The replay of one episode."""

    file: str
    episode: int
    status: Status
    steps: int
    divergence: Divergence | None = None
    reason: str | None = None


@dataclass
class ReplayResult:
    """Replays of many episodes, with the library versions that differ from the recording."""

    episodes: list[EpisodeReplay] = field(default_factory=list)
    version_differences: dict[str, dict[str, tuple[str, str]]] = field(default_factory=dict)

    def count(self, status: Status) -> int:
        """How many episodes ended with ``status``."""
        return sum(1 for e in self.episodes if e.status == status)

    @property
    def ok(self) -> bool:
        """True when no episode diverged (not-replayable episodes do not fail a replay)."""
        return self.count("diverged") == 0

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able form: ``{"summary": {...}, "episodes": [...], "version_differences"}``."""
        return {
            "summary": {
                "identical": self.count("identical"),
                "diverged": self.count("diverged"),
                "not_replayable": self.count("not_replayable"),
            },
            "episodes": [asdict(e) for e in self.episodes],
            "version_differences": {
                file: {lib: {"recorded": a, "current": b} for lib, (a, b) in diffs.items()}
                for file, diffs in self.version_differences.items()
            },
        }


def _installed_version(distribution: str) -> str:
    """The installed version of a library this process has not imported, or "not installed"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except (PackageNotFoundError, ValueError):
        return "not installed"


def build_env(
    run: RunInfo,
    *,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
) -> gym.Env[Any, Any]:
    """Build the environment to replay a file's episodes in (see the module docstring)."""
    if env_factory is not None:
        factory = load_callable(env_factory) if isinstance(env_factory, str) else env_factory
        name = env_factory if isinstance(env_factory, str) else getattr(factory, "__name__", "")
        try:
            env = factory()
        except Exception as exc:  # the user's own code: say so, in one line
            raise ConfigurationError(
                f"--env-factory {name}: it raised {error_text(exc)}; it must take no "
                "arguments and return the env"
            ) from None
        if not isinstance(env, gym.Env):
            raise ConfigurationError(
                f"--env-factory {name}: it returned {type(env).__name__}, not a gymnasium.Env"
            )
        return env
    spec = run.env_spec or {}
    env_id = run.env_id
    if not env_id:
        raise ReplayError("the file names no env id; pass --env-factory MODULE:CALLABLE")
    if not spec:  # the spec was not serializable: the bare id may be another env
        raise ReplayError(_no_spec_reason(run))
    recorded = spec.get("additional_wrappers") or []
    wrappers = [w for w in recorded if isinstance(w, Mapping)] if isinstance(recorded, list) else []
    foreign = [str(w.get("entry_point")) for w in wrappers if not _gymnasium_wrapper(w)]
    if ":" not in env_id and env_id in gym.registry and (not foreign or trust_entry_points):
        try:
            kwargs = dict(spec.get("kwargs") or {})
            if "max_episode_steps" in spec:
                kwargs["max_episode_steps"] = spec["max_episode_steps"]
            env = gym.make(_without_checks(gym.spec(env_id)), **kwargs)
            for wrapper in wrappers:
                cls = load_callable(str(wrapper["entry_point"]))
                if not (isinstance(cls, type) and issubclass(cls, gym.Wrapper)):
                    raise ReplayError(
                        f"the recorded wrapper {wrapper['entry_point']!r} is not a Wrapper class"
                    )
                env = cls(env, **(wrapper.get("kwargs") or {}))
        except ConfigurationError:
            raise
        except Exception as exc:  # the env's own code, given what the file recorded
            raise ReplayError(f"cannot make {env_id!r} with the recorded kwargs: {exc}") from None
        return env
    entry = spec.get("entry_point")
    if trust_entry_points and spec:
        try:
            recorded_spec = gym.envs.registration.EnvSpec.from_json(json.dumps(spec))
            return gym.make(_without_checks(recorded_spec))
        except Exception as exc:
            raise ReplayError(f"cannot make the env from the recorded spec: {exc}") from None
    if foreign and env_id in gym.registry:
        raise ReplayError(
            f"the recorded env had wrappers from outside Gymnasium ({', '.join(foreign)}); "
            "pass --env-factory MODULE:CALLABLE, or --trust-entry-points to import them"
        )
    raise ReplayError(
        f"env id {env_id!r} is not registered in this process; pass --import MODULE that "
        "registers it, --env-factory MODULE:CALLABLE"
        + (f", or --trust-entry-points to import {entry!r} named in the file" if entry else "")
    )


def _no_spec_reason(run: RunInfo) -> str:
    """Why a file with an env id but no env spec cannot be replayed without an env factory."""
    notes = (run.recorder or {}).get("notes")
    said = (
        [str(n) for n in notes if str(n).startswith("env spec")] if isinstance(notes, list) else []
    )
    why = f" ({said[0][:200]})" if said else ""
    return (
        f"the env spec of {run.env_id!r} was not recorded{why}: its kwargs and wrappers are "
        "unknown, and the bare id may be another env; pass --env-factory MODULE:CALLABLE "
        "that builds the env as it was recorded"
    )


def _without_checks(spec: gym.envs.registration.EnvSpec) -> gym.envs.registration.EnvSpec:
    """``spec`` without the passive env checker and the order check (see the module doc)."""
    return replace(spec, disable_env_checker=True, order_enforce=False)


def _gymnasium_wrapper(wrapper: Mapping[str, Any]) -> bool:
    """Whether a recorded wrapper's entry point is a plain name in ``gymnasium.wrappers``."""
    module, sep, attr = str(wrapper.get("entry_point", "")).partition(":")
    inside = module == _TRUSTED_WRAPPER_PREFIX or module.startswith(_TRUSTED_WRAPPER_PREFIX + ".")
    return bool(sep) and inside and attr.isidentifier() and not attr.startswith("_")


def _short(value: Any) -> str:
    if isinstance(value, np.ndarray) and value.size > 16:
        # (a camera frame's list would be millions of characters)
        text = np.array2string(value, threshold=16, edgeitems=2, separator=", ")
        text = " ".join(text.split())
    else:
        text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else text[:77] + "..."


def _first_difference(expected: Any, got: Any, atol: float, path: str = "") -> str | None:
    """Where two observations first differ, element by element, or ``None``.

    Only for numeric arrays (in a Dict or Tuple too) of the same shape: the index of the first
    element that differs (as replay compares: bitwise, NaN equal to NaN, or within ``atol``),
    both values, and how many elements differ.

    >>> _first_difference(np.zeros((2, 3)), np.array([[0, 0, 0], [0, 0.5, 0.25]]), 0.0)
    '[1, 1]: expected 0.0, got 0.5; 2 of 6 elements differ'
    >>> _first_difference({"pos": np.zeros(2)}, {"pos": np.ones(2)}, 0.0)
    "['pos'][0]: expected 0.0, got 1.0; 2 of 2 elements differ"
    """
    if isinstance(expected, Mapping) and isinstance(got, Mapping):
        for key in expected:
            if key in got:
                found = _first_difference(expected[key], got[key], atol, f"{path}[{key!r}]")
                if found is not None:
                    return found
        return None
    if isinstance(expected, tuple) and isinstance(got, tuple) and len(expected) == len(got):
        for i, (e, g) in enumerate(zip(expected, got, strict=True)):
            found = _first_difference(e, g, atol, f"{path}[{i}]")
            if found is not None:
                return found
        return None
    if not isinstance(expected, np.ndarray) or not isinstance(got, np.ndarray):
        return None
    if expected.shape != got.shape or expected.ndim == 0 or expected.dtype.kind not in "biuf":
        return None
    if got.dtype.kind not in "biuf":
        return None
    a, b = expected.reshape(-1), got.reshape(-1)
    differ = np.flatnonzero(~equal_elements(a, b, atol))
    if differ.size == 0:
        return None
    first = int(differ[0])
    index = ", ".join(str(int(i)) for i in np.unravel_index(first, expected.shape))
    return (
        f"{path}[{index}]: expected {a[first].item()!r}, got {b[first].item()!r}; "
        f"{differ.size} of {a.size} elements differ"
    )


def _rules_of(run: RunInfo) -> tuple[EndingRules | None, RewardTerms | None]:
    ending = run.ending_rules or {}
    rules: EndingRules | None = None
    if not ending.get("success_fn") and not ending.get("failure_fn"):
        rules = EndingRules(
            success_keys=tuple(ending.get("success_keys") or ("success", "is_success")),
            failure_key=str(ending.get("failure_key") or "failure"),
            truncation_reason_key=str(ending.get("truncation_reason_key") or "truncation_reason"),
        )
    source = (run.reward_terms or {}).get("source", "auto")
    terms: RewardTerms | None
    if source == "auto" or source is None:
        terms = RewardTerms(source)
    elif isinstance(source, list):
        terms = RewardTerms(tuple(str(k) for k in source))
    else:  # a callable the file can only name: terms are not compared
        terms = None
    return rules, terms


@dataclass(slots=True)
class _Stepped:
    """One episode as it was stepped: where its rows are and how its stepping ended."""

    record: dict[str, Any]
    count: int  # rows recorded
    first: int  # its first row in the compared columns
    ran: int  # steps taken
    crash: Divergence | None
    last_info: Any
    hit_time_limit: bool


@dataclass
class _Ran:
    """The stepped episodes, in order, as parallel lists.

    The stepping loop appends one tuple per episode to :attr:`stepped` (cheaper than an
    object, or an append per list); :meth:`finish` makes the lists. :meth:`episode` gives one
    episode as a :class:`_Stepped`.
    """

    # (record, start, count, ran, last info, hit, reset row) per episode, until finish()
    stepped: list[tuple[dict[str, Any], int, int, int, Any, bool, int]] = field(
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

    def finish(self) -> _Ran:
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

    def episode(self, k: int, first: int) -> _Stepped:
        """The ``k``-th episode, whose first compared row is ``first``."""
        return _Stepped(
            self.records[k],
            self.counts[k],
            first,
            self.ran[k],
            self.crashes.get(k),
            self.last_infos[k],
            self.hits[k],
        )


class _Rows:
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


_FLAG_NAMES = ("False", "True", "not a bool")


@dataclass
class _Got:
    """The replayed values, one row per compared row (rows never stepped: null, NaN, 0)."""

    obs: pa.Array
    rewards: np.ndarray[Any, Any]  # float64
    terminated: np.ndarray[Any, Any]  # int8: 0, 1, or 2 for a value bool() refused
    truncated: np.ndarray[Any, Any]
    terms: _Terms

    @classmethod
    def collect(
        cls,
        steps: _Steps,
        ran: np.ndarray[Any, Any],
        firsts: np.ndarray[Any, Any],
        obs: pa.Array,
        n: int,
        terms_rule: RewardTerms | None,
    ) -> _Got:
        """Columns of ``n`` rows from what the episodes' ``steps`` returned.

        Each episode took ``ran`` steps and its recorded rows start at ``firsts`` in the
        compared columns.
        """
        rewards = _rewards(steps.rewards)
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
        terms = _Terms(n)
        if terms_rule is not None and steps.infos:
            terms.read(terms_rule, positions[steps.info_rows], steps.infos)
        return cls(obs, rewards, terminated, truncated, terms)


def _recorded_terms(
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
class _Terms:
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
        info by info, as the recorder's slow path reads it (:func:`_recorded_terms`). No info
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
            terms = _recorded_terms(extract, info)
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


@dataclass
class _Steps:
    """What the steps returned (but the observations), in order.

    No tuple is kept per step: many live tuples make the garbage collector walk them again
    and again (a third of the replay's own time on CartPole).
    """

    rewards: list[Any] = field(default_factory=list)
    ends: list[tuple[int, Any, Any]] = field(default_factory=list)  # each episode's last step
    info_rows: list[int] = field(default_factory=list)  # the steps whose info is not empty
    infos: list[Any] = field(default_factory=list)  # and their infos


def _scatter(
    values: np.ndarray[Any, Any], positions: np.ndarray[Any, Any], n: int, fill: Any
) -> np.ndarray[Any, Any]:
    out = np.full(n, fill, dtype=values.dtype)
    out[positions] = values
    return out


def _rewards(values: list[Any]) -> np.ndarray[Any, Any]:
    """Rewards as float64; one that is not a number is NaN (a text reward is not parsed)."""
    try:
        return np.frombuffer(array("d", values), dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        pass
    out = array("d")
    for value in values:
        try:
            out.append(value)
        except (TypeError, ValueError, OverflowError):  # (an int too large for a float)
            out.append(math.nan)
    return np.frombuffer(out, dtype=np.float64)


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


def _replay_actions(column: pa.ChunkedArray, codec: Any) -> tuple[Any, np.ndarray[Any, Any] | None]:
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


class _EpisodeRunner:
    """Replays the episodes of one file in one environment."""

    def __init__(
        self,
        ev: Evidence,
        env: gym.Env[Any, Any],
        *,
        atol: float,
        progress: Callable[[int], None] | None,
    ) -> None:
        self.ev = ev
        self.file = str(ev.path)
        self.env = env
        self.atol = atol
        self.progress = progress
        self.obs_codec = ev.observation_codec
        self.act_codec = ev.action_codec
        self.rules, self.terms_rule = _rules_of(ev.run)
        self.time_limit = find_time_limit(env)
        # An outermost Gymnasium TimeLimit is counted by the stepping loop, not called: the
        # same flags, without a wrapper call per step (see plain_time_limit).
        self.counted = plain_time_limit(env)
        self._plain_endings: dict[tuple[bool, bool, bool], Ending] = {}

    def not_replayable(self, index: int, steps: int, reason: str) -> EpisodeReplay:
        return EpisodeReplay(self.file, index, "not_replayable", steps, reason=reason)

    def _diverged(self, index: int, steps: int, divergence: Divergence) -> EpisodeReplay:
        return EpisodeReplay(self.file, index, "diverged", steps, divergence)

    def run_all(
        self,
        records: list[dict[str, Any]],
        steps: pa.Table,
        rows: dict[int, tuple[int, int]],
        reset_rows: dict[int, int],
        resets: pa.Table,
    ) -> list[EpisodeReplay]:
        """Replay ``records`` (in file order): step every episode, then compare in one pass.

        Stepping only keeps what the env returns; the values become columns afterwards, and
        the comparison runs over whole columns at once. Only an episode with a difference is
        looked at on its own, from the mismatch positions.
        """
        obs_codec, act_codec = self.obs_codec, self.act_codec
        done: dict[int, EpisodeReplay] = {}
        if not records:
            return []
        if obs_codec is None or act_codec is None:
            for r in records:
                index = int(r["episode"])
                done[index] = self.not_replayable(index, 0, "the file's spaces cannot be rebuilt")
            return [done[int(r["episode"])] for r in records]
        actions, null_rows = _replay_actions(steps.column(fmt.COL_ACTION), act_codec)
        ran, returned, got_obs, got_reset = self._step_all(
            records, actions, null_rows, rows, reset_rows, done
        )
        if ran.records:
            self._compare(ran, returned, got_obs, got_reset, steps, resets, done)
        return [done[int(r["episode"])] for r in records]

    def _compare(
        self,
        ran: _Ran,
        returned: _Steps,
        got_obs: pa.Array,
        got_reset: pa.Array,
        steps: pa.Table,
        resets: pa.Table,
        done: dict[int, EpisodeReplay],
    ) -> None:
        """Compare the stepped episodes with the evidence; put each one's result in ``done``."""
        obs_codec = self.obs_codec
        assert obs_codec is not None
        starts = np.array(ran.starts, dtype=np.int64)
        counts = np.array(ran.counts, dtype=np.int64)
        steps_ran = np.array(ran.ran, dtype=np.int64)
        firsts = np.cumsum(counts) - counts
        take = np.repeat(starts - firsts, counts) + np.arange(int(counts.sum()))
        same_rows = take.size == steps.num_rows and bool((take == np.arange(take.size)).all())
        expected = steps if same_rows else steps.take(pa.array(take))
        got = _Got.collect(returned, steps_ran, firsts, got_obs, expected.num_rows, self.terms_rule)
        bad, field_masks = self._mismatches(expected, got)
        reset_obs = one_array(resets.column(fmt.COL_OBSERVATION))
        reset_equal, reset_diff = obs_codec.compare(
            reset_obs.take(pa.array(ran.reset_at, pa.int64())), got_reset, atol=self.atol
        )
        first_bad = np.append(bad, np.iinfo(np.int64).max)[np.searchsorted(bad, firsts)]
        # clean: the reset and every compared row match, all rows ran, nothing raised
        clean = reset_equal & (first_bad >= firsts + steps_ran) & (steps_ran == counts)
        if ran.crashes:
            clean[list(ran.crashes)] = False
        lasts = (firsts + steps_ran - 1)[steps_ran > 0]
        last_term = np.zeros(len(counts), dtype=np.int8)
        last_trunc = np.zeros(len(counts), dtype=np.int8)
        last_term[steps_ran > 0] = got.terminated[lasts]
        last_trunc[steps_ran > 0] = got.truncated[lasts]
        file, outcome_difference = self.file, self._outcome_difference
        checks_outcome, plain = self.rules is not None, self._plain_endings
        for k, (record, is_clean, n, term, trunc) in enumerate(
            zip(
                ran.records,
                clean.tolist(),
                ran.ran,
                last_term.tolist(),
                last_trunc.tolist(),
                strict=True,
            )
        ):
            index = record["episode"]
            if is_clean:
                outcome = None
                info = ran.last_infos[k]
                if n and not (
                    # the usual case, without a call: an outcome already classified the same
                    checks_outcome
                    and type(info) is dict
                    and not info
                    and plain.get((term == 1, trunc == 1, ran.hits[k])) == _recorded_outcome(record)
                ):
                    outcome = outcome_difference(
                        record, term == 1, trunc == 1, n - 1, info, ran.hits[k]
                    )
                done[index] = (
                    EpisodeReplay(file, index, "identical", n)
                    if outcome is None
                    else self._diverged(index, n, outcome)
                )
            elif not reset_equal[k]:
                exp = obs_codec.decode(reset_obs.slice(ran.reset_at[k], 1))[0]
                now = obs_codec.decode(got_reset.slice(k, 1))[0]
                done[index] = self._diverged(
                    index,
                    0,
                    Divergence.of_observation(None, exp, now, float(reset_diff[k]), self.atol),
                )
            else:
                episode = ran.episode(k, int(firsts[k]))
                done[index] = self._verdict(episode, int(first_bad[k]), field_masks, expected, got)

    def _step_all(
        self,
        records: list[dict[str, Any]],
        actions: Any,
        null_rows: np.ndarray[Any, Any] | None,
        rows: dict[int, tuple[int, int]],
        reset_rows: dict[int, int],
        done: dict[int, EpisodeReplay],
    ) -> tuple[_Ran, _Steps, pa.Array, pa.Array]:
        """Reset and step every replayable episode.

        Returns the stepped episodes, what their steps returned (in order), and the columns
        of their observations and reset observations (copied as they come: an env may
        change an array it returned).
        """
        assert self.obs_codec is not None
        env = self.env if self.counted is None else self.counted[0]
        limit = None if self.counted is None else self.counted[1]
        env_step = env.step
        got_obs, got_reset = _Rows(self.obs_codec), _Rows(self.obs_codec)
        keep_raw: Callable[[Any], int] = got_obs.raw.write  # (takes any C-contiguous array)
        keep_other = got_obs.add
        keep_reset = got_reset.keep
        raw_dtype, raw_shape, ndarray = got_obs.dtype, got_obs.shape, np.ndarray
        steps = _Steps()
        rewards = steps.rewards
        keep_reward, keep_info = rewards.append, steps.infos.append
        keep_info_row = steps.info_rows.append
        ends = steps.ends
        ran = _Ran()
        stepped = ran.stepped
        keep_stepped = stepped.append
        time_limit = self.time_limit
        progress = self.progress
        has_nulls = null_rows is not None and null_rows.size > 0
        damaged = self.ev.damaged_episodes or None  # (an empty set is not asked)
        no_rows = (0, 0)
        for record in records:
            index = record["episode"]
            start, count = rows.get(index, no_rows)
            seed = record.get("seed")
            rng_state = record.get("rng_state")
            reset_at = reset_rows.get(index)
            if seed is None and rng_state is None:
                done[index] = self.not_replayable(
                    index, 0, "no seed or RNG state recorded for its reset"
                )
                continue
            if damaged is not None and index in damaged:
                done[index] = self.not_replayable(
                    index, count, "part of its evidence was in a damaged chunk (skipped by recover)"
                )
                continue
            if reset_at is None:
                why = (
                    RESET_RAISED
                    if record.get("error_during") == "reset"
                    else "its reset row is missing (torn file)"
                )
                done[index] = self.not_replayable(index, count, why)
                continue
            try:
                options = from_json(record["options"], "options") if record.get("options") else None
                state: Any = None if seed is not None else from_json(str(rng_state), "rng_state")
            except ValueError as exc:
                done[index] = self.not_replayable(index, count, f"its reset record: {exc}")
                continue
            try:
                if seed is not None:
                    obs, _ = env.reset(seed=seed, options=options)
                else:
                    restore_rng_state(env, state)
                    obs, _ = env.reset(options=options)
            except Exception as exc:
                done[index] = self._diverged(
                    index, 0, Divergence(None, "reset", "a reset", f"{type(exc).__name__}: {exc}")
                )
                continue
            keep_reset(obs)
            stop = start + count
            crash: Divergence | None = None
            if has_nulls:
                assert null_rows is not None
                k = int(np.searchsorted(null_rows, start))
                if k < null_rows.size and null_rows[k] < stop:
                    stop = int(null_rows[k])
                    crash = Divergence(
                        stop - start, "action", "a recorded action", "null (not recordable)"
                    )
            # the TimeLimit truncates its limit-th step, so stepping ends there at the latest
            end = stop if limit is None or stop - start <= limit else start + limit
            before = len(rewards)
            try:
                for action in actions[start:end]:
                    obs, reward, term, trunc, info = env_step(action)
                    # got_obs.keep(obs), inlined
                    if type(obs) is ndarray and obs.dtype is raw_dtype and obs.shape == raw_shape:
                        try:
                            keep_raw(obs)
                        except ValueError:  # not C-contiguous
                            keep_other(obs)
                    else:
                        keep_other(obs)
                    keep_reward(reward)
                    try:
                        if info:
                            keep_info_row(len(rewards) - 1)
                            keep_info(info)
                    except Exception:  # an info with no truth value (an array): kept
                        keep_info_row(len(rewards) - 1)
                        keep_info(info)
                    try:
                        if term or trunc:
                            break
                    except Exception:  # flags with no truth value: False, as the recorder took them
                        term = trunc = False
            except Exception as exc:
                ran_now = len(rewards) - before
                crash = Divergence(ran_now, "step", "a step", f"{type(exc).__name__}: {exc}")
            ran_now = len(rewards) - before
            if ran_now == limit:
                trunc = True  # what the TimeLimit sets on its limit-th step
            if ran_now < stop - start and (crash is None or crash.field == "action"):
                crash = None  # it ended early: the length check says so
            # Every step before the last had both flags falsy (stepping stops at the first
            # that has one set): only the last step's are kept.
            if ran_now:
                ends.append((len(rewards) - 1, term, trunc))
            if crash is not None:
                ran.crashes[len(stepped)] = crash
            # the TimeLimit state belongs to this episode: read it now, not after the others
            hit = ran_now == limit if limit is not None else time_limit_hit(time_limit)
            keep_stepped((record, start, count, ran_now, info if ran_now else {}, hit, reset_at))
            if progress is not None:
                progress(count)
        return ran.finish(), steps, got_obs.finish(), got_reset.finish()

    def _mismatches(
        self, expected: pa.Table, got: _Got
    ) -> tuple[
        np.ndarray[Any, Any], list[tuple[str, np.ndarray[Any, Any], np.ndarray[Any, Any] | None]]
    ]:
        """Rows that differ in any field, and per field (name, equal mask, abs diff)."""
        assert self.obs_codec is not None
        n = expected.num_rows
        obs_equal, obs_diff = self.obs_codec.compare(
            expected.column(fmt.COL_OBSERVATION), got.obs, atol=self.atol
        )
        exp_r = expected.column(fmt.COL_REWARD).to_numpy()
        got_r = got.rewards
        with np.errstate(invalid="ignore"):
            diff_r = np.abs(exp_r - got_r)
            same_r = (exp_r == got_r) | (np.isnan(exp_r) & np.isnan(got_r)) | (diff_r <= self.atol)
        fields: list[tuple[str, np.ndarray[Any, Any], np.ndarray[Any, Any] | None]] = [
            ("observation", obs_equal, obs_diff),
            ("reward", same_r, diff_r),
        ]
        if self.terms_rule is not None:
            fields.append(("terms", self._terms_equal(expected, got.terms.column(), n), None))
        for name, flags in (
            (fmt.COL_TERMINATED, got.terminated),
            (fmt.COL_TRUNCATED, got.truncated),
        ):
            exp = expected.column(name).to_numpy(zero_copy_only=False).astype(np.int8)
            fields.append((name, exp == flags, None))
        ok = np.ones(n, dtype=np.bool_)
        for _, equal, _ in fields:
            ok &= equal
        return np.flatnonzero(~ok), fields

    def _terms_equal(self, expected: pa.Table, got: pa.Array, n: int) -> np.ndarray[Any, Any]:
        exp = one_array(expected.column(fmt.COL_TERMS))
        if exp.null_count == n and got.null_count == n:
            return np.ones(n, dtype=np.bool_)
        return _terms_rows_equal(exp, got, self.atol)

    def _verdict(
        self,
        episode: _Stepped,
        first_bad: int,
        fields: list[tuple[str, np.ndarray[Any, Any], np.ndarray[Any, Any] | None]],
        expected: pa.Table,
        got: _Got,
    ) -> EpisodeReplay:
        assert self.obs_codec is not None
        record, first, count, ran = episode.record, episode.first, episode.count, episode.ran
        index = int(record["episode"])
        if first_bad < first + ran:
            row = first_bad
            step = row - first
            for name, equal, diff in fields:
                if equal[row]:
                    continue
                d = None if diff is None else float(diff[row])
                if name == "observation":
                    col = expected.column(fmt.COL_OBSERVATION)
                    exp_obs = self.obs_codec.decode(one_array(col.slice(row, 1)))[0]
                    got_obs = self.obs_codec.decode(got.obs.slice(row, 1))[0]
                    divergence = Divergence.of_observation(step, exp_obs, got_obs, d, self.atol)
                    return self._diverged(index, step, divergence)
                if name == "reward":
                    exp_v = repr(expected.column(fmt.COL_REWARD)[row].as_py())
                    got_v = repr(float(got.rewards[row]))
                elif name == "terms":
                    exp_v = _short(dict(expected.column(fmt.COL_TERMS)[row].as_py() or []))
                    got_v = _short(got.terms.at(row))
                else:
                    flags = got.terminated if name == fmt.COL_TERMINATED else got.truncated
                    exp_v = str(expected.column(name)[row].as_py())
                    got_v = _FLAG_NAMES[int(flags[row])]
                return self._diverged(index, step, Divergence(step, name, exp_v, got_v, d))
        if episode.crash is not None:
            return self._diverged(index, ran, episode.crash)
        if ran < count:
            return self._diverged(
                index,
                ran,
                Divergence(ran, "length", f"{count} steps", f"the episode ended after {ran}"),
            )
        if ran:
            last = first + ran - 1
            outcome = self._outcome_difference(
                record,
                bool(got.terminated[last] == 1),
                bool(got.truncated[last] == 1),
                ran - 1,
                episode.last_info,
                episode.hit_time_limit,
            )
            if outcome is not None:
                return self._diverged(index, ran, outcome)
        return EpisodeReplay(self.file, index, "identical", ran)

    def _outcome_difference(
        self,
        record: dict[str, Any],
        term: bool,
        trunc: bool,
        last_step: int,
        info: Any,
        hit_time_limit: bool,
    ) -> Divergence | None:
        """How the outcome of an episode whose last step was ``last_step`` differs, if it does."""
        if self.rules is None or record["outcome"] in (fmt.OUTCOME_INCOMPLETE, fmt.OUTCOME_ERROR):
            return None
        if not (term or trunc):
            return None
        if type(info) is dict and not info:  # the usual case: one classification per flags
            key = (term, trunc, hit_time_limit)
            ending = self._plain_endings.get(key)
            if ending is None:
                ending = self._plain_endings[key] = self.rules.classify(
                    term, trunc, {}, time_limit_hit=hit_time_limit
                )
        else:
            ending = _final_ending(self.rules, term, trunc, info, time_limit_hit=hit_time_limit)
        return _outcome_divergence(record, ending, last_step)


RESET_RAISED = "its reset raised (an error episode): there is no reset to compare"
"""Why an episode (or a PettingZoo game) whose recorded ``reset()`` raised is not replayable."""


def _final_ending(
    rules: EndingRules, terminated: bool, truncated: bool, info: Any, *, time_limit_hit: bool
) -> Ending:
    """A final step's ending as the recorder's ``Stream._end_by_flags`` classifies it.

    An info that is not a mapping is read as an empty one; one the rules cannot read (a success
    value with no single truth value, an array) gives the ending by the flags alone
    (:meth:`~episode_audit.record.rules.EndingRules.classify_or_note`). Never raises.
    """
    ending, _ = rules.classify_or_note(
        terminated,
        truncated,
        info if isinstance(info, Mapping) else {},
        time_limit_hit=time_limit_hit,
    )
    return ending


def _outcome_divergence(
    record: Mapping[str, Any], ending: Ending, last_step: int
) -> Divergence | None:
    """How ``ending`` differs from an episode record's ending, at ``last_step``, if it does."""
    want = _recorded_outcome(record)
    got = (ending.outcome, ending.failure_label, ending.truncation_reason)
    if want != got:
        return Divergence(last_step, "outcome", _fmt_outcome(*want), _fmt_outcome(*got))
    return None


def _recorded_outcome(record: Mapping[str, Any]) -> tuple[Any, Any, Any]:
    """An episode record's (outcome, failure label, truncation reason), as an ``Ending`` is."""
    return record["outcome"], record.get("failure_label"), record.get("truncation_reason")


def _fmt_outcome(outcome: str, label: str | None, reason: str | None) -> str:
    parts = [outcome] + [p for p in (label, reason) if p]
    return "/".join(parts)


def _terms_rows_equal(exp: pa.Array, got: pa.Array, atol: float) -> np.ndarray[Any, Any]:
    """Per row of two ``terms`` map columns, what :func:`_terms_equal` says, over whole columns.

    Rows are equal when both are null, or both hold the same names in the same order with
    values equal (NaN equals NaN; within ``atol`` when it is positive; a null value equals
    only a null value).
    """
    exp_null, got_null = null_mask(exp), null_mask(got)
    exp_off = exp.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
    got_off = got.offsets.to_numpy(zero_copy_only=False).astype(np.int64)
    exp_len, got_len = np.diff(exp_off), np.diff(got_off)
    both = ~exp_null & ~got_null
    equal: np.ndarray[Any, Any] = (exp_null == got_null) & (~both | (exp_len == got_len))
    rows = np.flatnonzero(both & (exp_len == got_len) & (exp_len > 0))
    if rows.size == 0:
        return equal
    # the flat positions of every compared (name, value) pair, row after row
    lens = exp_len[rows]
    within = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens)
    exp_at = pa.array(np.repeat(exp_off[rows], lens) + within)
    got_at = pa.array(np.repeat(got_off[rows], lens) + within)
    keys = pc.equal(exp.keys.take(exp_at), got.keys.take(got_at)).fill_null(False)
    same = keys.to_numpy(zero_copy_only=False)
    exp_v, got_v = exp.items.take(exp_at), got.items.take(got_at)
    a = exp_v.to_numpy(zero_copy_only=False).astype(np.float64)
    b = got_v.to_numpy(zero_copy_only=False).astype(np.float64)
    a_null, b_null = null_mask(exp_v), null_mask(got_v)
    with np.errstate(invalid="ignore"):
        close = (a == b) | (np.isnan(a) & np.isnan(b))
        if atol > 0:
            close |= np.abs(a - b) <= atol
    same &= np.where(a_null | b_null, a_null & b_null, close)
    equal[rows[np.repeat(np.arange(rows.size), lens)[~same]]] = False
    return equal


def _terms_equal(a: Any, b: Any, atol: float) -> bool:
    """One row of :func:`_terms_rows_equal`: ``(name, value)`` lists, or ``None``."""
    if a is None or b is None:
        return a is None and b is None
    if [k for k, _ in a] != [k for k, _ in b]:
        return False
    for (_, x), (_, y) in zip(a, b, strict=True):
        if x is None or y is None:
            if x is None and y is None:
                continue
            return False
        if x == y or (x != x and y != y):
            continue
        if atol > 0 and abs(x - y) <= atol:
            continue
        return False
    return True


def _row_ranges(episode: np.ndarray[Any, Any]) -> dict[int, tuple[int, int]]:
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


_ENDINGS = frozenset({fmt.OUTCOME_SUCCESS, fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED})


def _to_end(
    rows: dict[int, tuple[int, int]], records: Mapping[int, Mapping[str, Any]]
) -> dict[int, tuple[int, int]]:
    """Each episode's rows up to its recorded end.

    Rows stepped after an episode ended (the recorder noted them ``step_after_end``; ``check``
    reports them) are not the episode: replay compares the steps up to its ``length``.
    """
    out = rows
    for index, (first, count) in rows.items():
        record = records.get(index)
        if record is None or record.get("outcome") not in _ENDINGS:
            continue
        length = record.get("length")
        if isinstance(length, int) and 0 <= length < count:
            if out is rows:
                out = dict(rows)
            out[index] = (first, length)
    return out


def _layout_not_replayable(layout: Mapping[str, Any]) -> str | None:
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


def replay_single_evidence(
    ev: Evidence,
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[EpisodeReplay]:
    """Replay the episodes of one open single-env or vector evidence file."""
    wanted = None if episodes is None else set(episodes)

    def records() -> list[dict[str, Any]]:
        table = ev.episodes()
        # Only the columns replay reads (a map column is slow to list), and of the optional
        # ones only those with a value: a record's .get() gives None for the others.
        columns = [
            c
            for c in _RECORD_COLUMNS
            if c in table.column_names
            and (c in _RECORD_KEYS or table.column(c).null_count < table.num_rows)
        ]
        listed = table.select(columns).to_pylist()
        return listed if wanted is None else [r for r in listed if r["episode"] in wanted]

    def none_replayable(reason: str) -> list[EpisodeReplay]:
        path = str(ev.path)
        return [
            EpisodeReplay(path, int(r["episode"]), "not_replayable", 0, reason=reason)
            for r in records()
        ]

    why_not = _layout_not_replayable(ev.run.layout)
    if why_not is not None:
        return none_replayable(why_not)
    try:
        env = build_env(ev.run, env_factory=env_factory, trust_entry_points=trust_entry_points)
    except ReplayError as exc:
        return none_replayable(str(exc))
    try:
        runner = _EpisodeRunner(ev, env, atol=atol, progress=progress)
        selected = None if wanted is None else pa.array(sorted(wanted), pa.int64())
        results: dict[int, EpisodeReplay] = {}
        known: list[Any] = []  # records, by index, resets, reset rows: read when first needed

        def run(table: pa.Table) -> None:
            if not known:
                # After a complete pass over the steps this reads nothing again: the pass kept
                # the episode records and reset blocks. (A file longer than a window is read
                # once more here.)
                listed = records()
                resets = ev.resets()
                indices = resets.column(fmt.COL_EPISODE).to_pylist()
                reset_rows = dict(zip(indices, range(len(indices)), strict=True))
                known.extend([listed, {r["episode"]: r for r in listed}, resets, reset_rows])
            _, by_index, resets, reset_rows = known
            rows = _to_end(_row_ranges(table.column(fmt.COL_EPISODE).to_numpy()), by_index)
            batch = [by_index[e] for e in rows if e in by_index and e not in results]
            for result in runner.run_all(batch, table, rows, reset_rows, resets):
                results[result.episode] = result

        # One pass over the file, in windows of whole episodes (memory stays bounded): the
        # rows of a single env's episodes are contiguous, so all but the last run are complete.
        window: list[pa.RecordBatch] = []
        held = held_bytes = 0
        cut = 0  # where the window's last episode starts (0: it holds one episode only)
        last: Any = None  # the episode of the window's last row
        for batch in ev.iter_step_batches():
            if selected is not None:
                batch = batch.filter(pc.is_in(batch.column(fmt.COL_EPISODE), selected))
            episode = batch.column(fmt.COL_EPISODE).to_numpy()
            if episode.size:
                if last is not None and episode[0] != last:
                    cut = held
                starts = np.flatnonzero(episode[1:] != episode[:-1])
                if starts.size:
                    cut = held + int(starts[-1]) + 1
                last = episode[-1]
            window.append(batch)
            held += batch.num_rows
            held_bytes += batch.nbytes
            if cut and (held >= REPLAY_WINDOW_ROWS or held_bytes >= REPLAY_WINDOW_BYTES):
                table = pa.Table.from_batches(window)  # (its columns are joined as needed)
                run(table.slice(0, cut))
                window = table.slice(cut).to_batches()
                held -= cut
                held_bytes = sum(b.nbytes for b in window)
                cut = 0
        # the last window, and (with no rows) the episodes that have no steps at all
        run(pa.Table.from_batches(window) if window else ev.steps_schema.empty_table())
        listed, _, resets, reset_rows = known
        rest = [r for r in listed if r["episode"] not in results]  # no rows at all
        if rest:
            empty = ev.steps_schema.empty_table()
            for result in runner.run_all(rest, empty, {}, reset_rows, resets):
                results[result.episode] = result
        return [results[r["episode"]] for r in listed]
    finally:
        env.close()
