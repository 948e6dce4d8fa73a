"""Run metadata and per-episode records: their fields, JSON Schemas and (de)serialization.

:class:`RunInfo` is what an evidence file says about its run (stored as the
``episode_audit.run`` MCAP metadata record, every value a string, JSON where structured).
:data:`EPISODE_SCHEMA` is the JSON Schema of the per-episode JSON messages.

>>> to_json({"a": 1.5, "b": float("nan")})
b'{"a":1.5,"b":"nan"}'
"""

from __future__ import annotations

import bisect
import json
import math
import operator
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from . import names as fmt

__all__ = [
    "EPISODE_SCHEMA",
    "MAX_JSON_TEXT",
    "EpisodeRanges",
    "RunInfo",
    "episode_index_problem",
    "from_json",
    "note_items",
    "to_json",
    "to_jsonable",
    "unstarted",
]

MAX_JSON_TEXT = 1 << 20
"""Largest JSON text from a file that :func:`from_json` parses: 1 MiB (as the reader's cap)."""


def episode_index_problem(index: int) -> str | None:
    """What is wrong with an episode index a person gave, or ``None`` (``0 .. 2**63 - 1``).

    >>> print(episode_index_problem(2**63))
    expected an episode index from 0 to 2**63 - 1, got 9223372036854775808
    """
    if 0 <= index < 2**63:
        return None
    return f"expected an episode index from 0 to 2**63 - 1, got {index}"


_EXACT_DTYPES = (np.dtype(np.float64), np.dtype(np.int64))
"""The numpy number types whose values JSON gives back as numbers numpy reads as the same type."""
_AS = {"f": "float64", "c": "complex", "i": "int64", "u": "int64"}


def to_jsonable(value: Any, *, exact: bool = False) -> Any:
    """Convert numpy scalars/arrays, tuples and non-finite floats into plain JSON values.

    Non-finite floats become the strings ``"nan"``, ``"inf"``, ``"-inf"``, and mapping keys
    their ``str()``; anything else that JSON cannot hold raises ``TypeError``. With ``exact``,
    a value JSON would change so (a non-finite float, a key that is not a string, a numpy
    number of another type than float64 or int64, which comes back as one of those) raises
    ``ValueError`` naming it instead: sequences become lists, numpy values Python ones, and
    nothing else changes.

    >>> to_jsonable({"x": np.float32(0.5), "y": (1, np.int64(2)), "z": np.arange(2)})
    {'x': 0.5, 'y': [1, 2], 'z': [0, 1]}
    >>> to_jsonable({5: float("inf")})
    {'5': 'inf'}
    >>> to_jsonable({"limit": [float("-inf")]}, exact=True)
    Traceback (most recent call last):
    ...
    ValueError: JSON has no -inf
    >>> to_jsonable({5: "x"}, exact=True)
    Traceback (most recent call last):
    ...
    ValueError: JSON keys are text, not int 5
    >>> to_jsonable({"low": np.array([0.5], np.float32)}, exact=True)
    Traceback (most recent call last):
    ...
    ValueError: JSON keeps no float32 numbers: they come back as float64
    """
    if value is None or isinstance(value, (bool, str, int)):
        return value
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        if exact:
            raise ValueError(f"JSON has no {value}")
        return str(value)
    if isinstance(value, (np.generic, np.ndarray)):
        if exact and value.dtype.kind in "fciu" and value.dtype not in _EXACT_DTYPES:
            raise ValueError(
                f"JSON keeps no {value.dtype} numbers: they come back as {_AS[value.dtype.kind]}"
            )
        return to_jsonable(
            value.tolist() if isinstance(value, np.ndarray) else value.item(), exact=exact
        )
    if isinstance(value, Mapping):
        if exact:
            for k in value:
                if not isinstance(k, str):
                    raise ValueError(f"JSON keys are text, not {type(k).__name__} {k!r:.40}")
        return {str(k): to_jsonable(v, exact=exact) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v, exact=exact) for v in value]
    raise TypeError(f"{type(value).__name__} is not JSON-serializable")


def from_json(text: str | bytes, what: str, limit: int = MAX_JSON_TEXT) -> Any:
    """Parse JSON that came from a file, bounded in size and nesting.

    Raises ``ValueError`` naming ``what`` when the text is too large, too deeply nested or not
    JSON (never ``RecursionError``, and nothing over ``limit`` is parsed).

    >>> from_json('{"a": [1, 2]}', "info")
    {'a': [1, 2]}
    >>> from_json("[" * 100_000, "notes")
    Traceback (most recent call last):
    ...
    ValueError: notes is nested too deeply to be JSON episode-audit wrote
    >>> from_json("x" * 20, "notes", limit=10)
    Traceback (most recent call last):
    ...
    ValueError: notes is 20 bytes of JSON, more than the limit of 10
    """
    if len(text) > limit:
        raise ValueError(f"{what} is {len(text)} bytes of JSON, more than the limit of {limit}")
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError(f"{what} is nested too deeply to be JSON episode-audit wrote") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{what} is not valid JSON: {exc}") from None


def note_items(text: str) -> list[str] | None:
    """A row's ``notes`` value (JSON text) as its notes, ``"code: detail"``; ``None`` if garbled.

    >>> note_items('["action_cast: dtype float64 cast to float32"]')
    ['action_cast: dtype float64 cast to float32']
    >>> print(note_items("{not json"))
    None
    """
    try:
        notes = from_json(text, "notes")
    except (TypeError, ValueError):
        return None
    if isinstance(notes, str):
        return [notes]
    if not isinstance(notes, list):
        return None
    return [str(n) for n in notes]


def listing(indices: Sequence[int], count: int | None = None, limit: int = 5) -> str:
    """The first ``limit`` indices for people, and how many more of ``count`` there are.

    ``count`` defaults to ``len(indices)``; given, ``indices`` holds at least the first
    ``limit`` of them.

    >>> listing([3, 4, 5, 6, 7, 8, 9]), listing([3, 4, 5, 6, 7], count=40)
    ('3, 4, 5, 6, 7 and 2 more', '3, 4, 5, 6, 7 and 35 more')
    """
    shown = ", ".join(str(i) for i in indices[:limit])
    more = (len(indices) if count is None else count) - limit
    return shown + (f" and {more} more" if more > 0 else "")


def unstarted(episodes: pa.Table) -> np.ndarray[Any, np.dtype[np.bool_]]:
    """Which rows of an episodes table (``Evidence.episodes()``) are *unstarted* episodes.

    An unstarted episode was reset and never stepped: its end record says ``incomplete`` with
    length 0 (a vector env's autoreset after the last episode a loop ran, or a ``reset()``
    followed by ``close()``). It is not an episode that stopped before it ended: ``check``
    does not warn about it and ``report`` leaves it out of its counts. An episode a torn
    file cut off has no end record (``ended`` is false) and is never one of them.
    """
    mask = pc.and_(
        pc.and_(
            pc.equal(episodes.column("outcome"), fmt.OUTCOME_INCOMPLETE),
            pc.equal(episodes.column("length"), 0),
        ),
        episodes.column("ended"),
    )
    out: np.ndarray[Any, np.dtype[np.bool_]] = np.asarray(
        pc.fill_null(mask, False).to_numpy(zero_copy_only=False), dtype=np.bool_
    )
    return out


@dataclass(frozen=True)
class EpisodeRanges:
    """A set of episode indices as sorted, disjoint, inclusive ``(first, last)`` spans.

    Compact whatever the count: a recovery that skipped damaged chunks lists the episodes
    that lost evidence this way (a run of thousands of lost episodes is one span).

    >>> lost = EpisodeRanges.of([7, 3, 4, 5], spans=[(10, 12)])
    >>> lost.spans, lost.count, 4 in lost, 6 in lost
    (((3, 5), (7, 7), (10, 12)), 7, True, False)
    >>> lost.first(5), lost.to_json()
    ([3, 4, 5, 7, 10], '[[3, 5], [7, 7], [10, 12]]')
    >>> EpisodeRanges.from_json(lost.to_json()) == lost
    True
    """

    spans: tuple[tuple[int, int], ...] = ()

    @classmethod
    def of(
        cls, indices: Iterable[int] = (), spans: Iterable[tuple[int, int]] = ()
    ) -> EpisodeRanges:
        """The union of ``indices`` and ``spans`` (merged where they touch or overlap)."""
        merged: list[tuple[int, int]] = []
        for first, last in sorted([*((i, i) for i in indices), *spans]):
            if merged and first <= merged[-1][1] + 1:
                merged[-1] = (merged[-1][0], max(merged[-1][1], last))
            else:
                merged.append((first, last))
        return cls(tuple(merged))

    @classmethod
    def from_json(cls, raw: str | None) -> EpisodeRanges:
        """Parse :meth:`to_json`'s text; anything else (absent, garbled) is the empty set.

        >>> EpisodeRanges.from_json("[" * 100_000)
        EpisodeRanges(spans=())
        """
        try:
            values = from_json(raw, "episode ranges") if raw else []
        except ValueError:  # (too large, too deeply nested, not JSON)
            return cls()
        spans = [
            (v[0], v[1])
            for v in (values if isinstance(values, list) else [])
            if isinstance(v, list)
            and len(v) == 2
            and all(type(x) is int for x in v)
            and 0 <= v[0] <= v[1]
        ]
        return cls.of(spans=spans)

    def to_json(self) -> str:
        """``[[first, last], ...]``."""
        return json.dumps([list(span) for span in self.spans])

    @property
    def count(self) -> int:
        """How many indices."""
        return sum(last - first + 1 for first, last in self.spans)

    def first(self, n: int) -> list[int]:
        """The ``n`` smallest indices (fewer if there are fewer)."""
        out: list[int] = []
        for first, last in self.spans:
            out.extend(range(first, min(last, first + n - len(out) - 1) + 1))
            if len(out) >= n:
                break
        return out

    def __contains__(self, index: object) -> bool:
        try:
            index = operator.index(index)  # type: ignore[arg-type]
        except TypeError:
            return False
        at = bisect.bisect_right(self.spans, (index, float("inf"))) - 1
        return at >= 0 and self.spans[at][0] <= index <= self.spans[at][1]

    def __bool__(self) -> bool:
        return bool(self.spans)


def _numpy_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serializable")


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_numpy_default)
# json's C encoder made once (JSONEncoder.encode makes one per call: a third of its cost for a
# small record). Its circular-reference markers are shared: a stale or concurrent entry can only
# make it refuse (ValueError), and a refused value takes the general path.
_MAKE_ENCODER = getattr(json.encoder, "c_make_encoder", None)  # (None without json's C speedups)
_C_ENCODE = (
    None
    if _MAKE_ENCODER is None
    else _MAKE_ENCODER(
        {},
        _numpy_default,
        json.encoder.encode_basestring_ascii,
        None,
        ":",
        ",",
        False,
        False,
        False,
    )
)


def to_json(value: Any) -> bytes:
    """Compact UTF-8 JSON of ``value`` after :func:`to_jsonable`.

    The common case (plain values, numpy scalars, no NaN) takes json's C encoder directly.

    >>> to_json({"a": [1, 2.5], "b": None, "c": np.float32(0.5), "d": float("nan")})
    b'{"a":[1,2.5],"b":null,"c":0.5,"d":"nan"}'
    """
    try:
        if _C_ENCODE is not None and type(value) is dict:
            return "".join(_C_ENCODE(value, 0)).encode()
        text = _ENCODER.encode(value)
    except (ValueError, TypeError):
        text = json.dumps(to_jsonable(value), separators=(",", ":"), allow_nan=False)
    return text.encode()


_NUM = {"type": "number"}
_NUM_OR_STR = {"type": ["number", "string"]}
_OPT_STR = {"type": ["string", "null"]}

EPISODE_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": fmt.SCHEMA_EPISODE_END,
    "description": (
        "One record per episode, written when the episode ends (or at close/error). "
        "Optional fields that are null may be left out."
    ),
    "type": "object",
    "required": ["episode", "outcome", "length", "return", "start_time_ns", "end_time_ns"],
    "properties": {
        "episode": {"type": "integer", "description": "episode index in the file"},
        "env_index": {"type": "integer", "description": "sub-env index (vector envs), else 0"},
        "agent": {**_OPT_STR, "description": "agent name (multi-agent streams), else null"},
        "seed": {"type": ["integer", "null"], "description": "seed passed to reset()"},
        "rng_state": {
            "type": ["object", "null"],
            "description": "np_random bit-generator state captured before an unseeded reset",
        },
        "options": {"type": ["object", "null"], "description": "options passed to reset()"},
        "outcome": {"enum": list(fmt.OUTCOMES)},
        "failure_label": _OPT_STR,
        "truncation_reason": _OPT_STR,
        "terminated": {"type": "boolean"},
        "truncated": {"type": "boolean"},
        "length": {"type": "integer", "description": "steps recorded in the episode"},
        "return": {**_NUM_OR_STR, "description": "sum of rewards ('nan'/'inf' if non-finite)"},
        "term_totals": {"type": "object", "additionalProperties": _NUM_OR_STR},
        "start_time_ns": {"type": "integer"},
        "end_time_ns": {"type": "integer"},
        "error": {
            "type": ["object", "null"],
            "properties": {
                "type": {"type": "string"},
                "message": {"type": "string"},
                "during": {"enum": ["reset", "step"]},
            },
        },
        "notes": {
            "type": "integer",
            "description": "rows of this episode (reset and steps) with recorder notes",
        },
        "game": {
            "type": ["integer", "null"],
            "description": "multi-agent files: the joint reset (game) of this agent-episode",
        },
    },
}


@dataclass
class RunInfo:
    """What an evidence file says about its run (the ``episode_audit.run`` metadata record)."""

    format_version: str
    writer: str
    env_id: str | None
    env_spec: dict[str, Any] | None
    observation_space: dict[str, Any]
    action_space: dict[str, Any]
    reward_terms: dict[str, Any]
    ending_rules: dict[str, Any]
    versions: dict[str, str]
    platform: str
    command_line: list[str]
    start_time: str
    tags: dict[str, str] = field(default_factory=dict)
    recorder: dict[str, Any] = field(default_factory=dict)
    layout: dict[str, Any] = field(default_factory=lambda: {"kind": "single", "num_envs": 1})

    _JSON_FIELDS = (
        "env_spec",
        "observation_space",
        "action_space",
        "reward_terms",
        "ending_rules",
        "versions",
        "command_line",
        "tags",
        "recorder",
        "layout",
    )

    def to_metadata(self) -> dict[str, str]:
        """Encode as an MCAP metadata map (string values; structured values as JSON)."""
        out: dict[str, str] = {}
        for key, value in asdict(self).items():
            if value is None:
                continue  # env_id, env_spec: absent (a reader takes absent as None)
            out[key] = to_json(value).decode() if key in self._JSON_FIELDS else str(value)
        return out

    @classmethod
    def from_metadata(cls, data: Mapping[str, str]) -> RunInfo:
        """Decode an MCAP metadata map. Raises ``ValueError`` naming the bad or missing key."""
        kwargs: dict[str, Any] = {}
        for name in cls.__dataclass_fields__:
            if name.startswith("_"):
                continue
            raw = data.get(name)
            if raw is None:
                if name in ("env_id", "env_spec"):
                    kwargs[name] = None
                    continue
                if name in ("tags", "recorder", "layout"):
                    continue
                raise ValueError(f"run metadata lacks the key {name!r}")
            if name in cls._JSON_FIELDS:
                kwargs[name] = from_json(raw, f"run metadata key {name!r}")
            else:
                kwargs[name] = raw
        info = cls(**kwargs)
        for name, kind in (
            ("observation_space", dict),
            ("action_space", dict),
            ("reward_terms", dict),
            ("ending_rules", dict),
            ("versions", dict),
            ("command_line", list),
            ("tags", dict),
            ("recorder", dict),
            ("layout", dict),
        ):
            if not isinstance(getattr(info, name), kind):
                raise ValueError(f"run metadata key {name!r}: expected a JSON {kind.__name__}")
        if info.env_spec is not None and not isinstance(info.env_spec, dict):
            raise ValueError("run metadata key 'env_spec': expected a JSON dict")
        for name in ("versions", "tags"):
            if not all(isinstance(v, str) for v in getattr(info, name).values()):
                raise ValueError(f"run metadata key {name!r}: expected string values")
        if not all(isinstance(v, str) for v in info.command_line):
            raise ValueError("run metadata key 'command_line': expected a list of strings")
        constants = info.reward_terms.get("constants")
        if constants is not None and not (
            isinstance(constants, dict)
            and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in constants.values()
            )
        ):
            raise ValueError(
                "run metadata key 'reward_terms': expected 'constants' to map term names to numbers"
            )
        return info
