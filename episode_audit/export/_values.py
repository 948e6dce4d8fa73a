"""What a viewer export takes from a step block: plottable numbers, camera frames, stream names.

:func:`split_column` cuts an action or observation column into :class:`Leaf` arrays of at most
:data:`SMALL` numbers per row (Box, MultiDiscrete, MultiBinary, Discrete; Dict and Tuple items
each on their own) and :class:`Frames`: ``uint8`` arrays shaped ``(H, W)`` or ``(H, W, C)``,
``C`` in 1, 3, 4, both sides at least :data:`IMAGE_MIN_SIDE`. :func:`json_rows` and
:func:`json_schema` give the leaves of a column as per-row JSON values and their JSON Schema;
:func:`streams` names each stream's topics and entity paths (:func:`agent_prefixes`: one per
PettingZoo agent, distinct) and :func:`frame_names` each camera field's (:func:`dotted_names`:
distinct for distinct fields); :func:`blocks` reads a file's reset and step blocks chunk by
chunk (:func:`chunk_blocks`: as one list a chunk); :func:`ending_text` says how an episode
ended.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt
import pyarrow as pa

from ..format.records import from_json

if TYPE_CHECKING:
    from ..read import Evidence

__all__ = [
    "IMAGE_MIN_SIDE",
    "NONFINITE_NULL",
    "RESET_STEP",
    "SMALL",
    "Frames",
    "Leaf",
    "Split",
    "Streams",
    "agent_prefixes",
    "blocks",
    "chunk_blocks",
    "dotted_names",
    "ending_text",
    "finite",
    "frame_names",
    "has_frames",
    "json_rows",
    "json_schema",
    "split_batch",
    "split_column",
    "streams",
]

SMALL: Final = 64
"""Arrays of at most this many numbers are plotted; larger ones are left out (not images)."""
IMAGE_MIN_SIDE: Final = 16
"""A ``uint8`` array is a camera frame when both its sides have at least this many pixels."""

RESET_STEP: Final = -1
"""The ``step`` of an episode's reset frame (its observation from ``reset()``): one before its
first step, whose ``step`` is 0 (docs/format.md)."""

_KIND: Final = b"episode_audit.kind"
_SHAPE: Final = b"episode_audit.shape"
_DTYPE: Final = b"episode_audit.dtype"


@dataclass
class Leaf:
    """One plottable field of a block: ``numbers[row]`` holds its values on that row."""

    path: tuple[str, ...]
    """The column, then Dict keys / Tuple indices: ``("observation", "position")``."""
    numbers: npt.NDArray[Any]
    """``(rows, size)``: ints or floats (non-finite floats as they are)."""
    present: npt.NDArray[np.bool_]
    """Rows that have a value (a null row has none)."""
    scalar: bool
    """One number per row (a Discrete, or a Box of shape ``()``) rather than a list."""
    integer: bool


@dataclass
class Frames:
    """One image field of a block: its path and its rows as ``(rows, H, W[, C])`` ``uint8``."""

    path: tuple[str, ...]
    pixels: npt.NDArray[np.uint8]
    present: npt.NDArray[np.bool_]


@dataclass
class Split:
    """What one column gives a viewer."""

    leaves: list[Leaf] = field(default_factory=list)
    images: list[Frames] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)
    """Fields neither plotted nor shown as images (too large, digests, text, JSON), by name."""


def finite(values: Sequence[float | None]) -> list[float | None]:
    """``values`` with NaN and infinities as ``None`` (JSON has no such numbers).

    >>> finite([1.0, float("nan"), None, float("inf")])
    [1.0, None, None, None]
    """
    return [v if v is not None and math.isfinite(v) else None for v in values]


def agent_prefixes(agents: Iterable[str]) -> dict[str, str]:
    """Each PettingZoo agent's topic / entity path prefix: distinct for distinct agents.

    The prefix is ``/`` and the agent's name, each character other than a letter, a digit,
    ``_``, ``-`` or ``.`` written ``_``. Where that makes one prefix of several names (``a/b``,
    ``a b`` and ``a_b`` are all ``a_b``), the agent already spelt so keeps it and the others, in
    sorted order, take the first free ``-2``, ``-3`` … after it; ``.`` and ``..`` are ``_`` and
    ``__``. The same agents always get the same prefixes.

    >>> agent_prefixes(["a_b", "a/b", "a b", "player 1", ".."])
    {'..': '/__', 'a b': '/a_b-2', 'a/b': '/a_b-3', 'a_b': '/a_b', 'player 1': '/player_1'}
    """
    names = sorted(set(agents))
    clean = {a: "".join(c if c.isalnum() or c in "_-." else "_" for c in a) for a in names}
    clean = {a: "_" * len(c) if c in (".", "..") else c for a, c in clean.items()}
    out = {a: a for a in names if clean[a] == a}
    taken = set(out.values())
    for agent in names:
        if agent in out:
            continue
        name, n = clean[agent], 1
        while name in taken:
            n += 1
            name = f"{clean[agent]}-{n}"
        out[agent] = name
        taken.add(name)
    return {a: "/" + out[a] for a in names}


@dataclass
class Streams:
    """A file's streams as a viewer names them (``/env_N``, ``/AGENT``; ``""`` single-env)."""

    prefix_of: dict[int, str]
    """Each episode's stream prefix, by episode index."""
    agent_at: dict[str, str]
    """Each PettingZoo agent's name, by its stream prefix (:func:`agent_prefixes`)."""

    def name(self, prefix: str) -> str:
        """Who a stream is, in words: the agent's name, ``env_N``, or ``""`` (single-env).

        >>> Streams({}, {"/a_b-2": "a b"}).name("/a_b-2"), Streams({}, {}).name("/env_1")
        ('a b', 'env_1')
        """
        return self.agent_at.get(prefix, prefix.lstrip("/"))


def streams(ev: Evidence) -> Streams:
    """The streams of ``ev``'s episodes (a vector env's sub-envs, PettingZoo agents)."""
    episodes = ev.episodes()
    kind = (ev.run.layout or {}).get("kind", "single")
    indices = episodes.column("episode").to_pylist()
    if kind == "single":
        return Streams(dict.fromkeys(indices, ""), {})
    env_indices = episodes.column("env_index").to_pylist()
    agents = episodes.column("agent").to_pylist()
    prefixes = agent_prefixes(a for a in agents if a)
    prefix_of = {
        e: prefixes[a] if a else f"/env_{i or 0}"
        for e, i, a in zip(indices, env_indices, agents, strict=True)
    }
    return Streams(prefix_of, {prefix: agent for agent, prefix in prefixes.items()})


def chunk_blocks(ev: Evidence) -> Iterator[list[tuple[bool, pa.RecordBatch]]]:
    """Each chunk's reset blocks (``True``), then its step blocks (``False``), chunk by chunk.

    One chunk is read at a time, so an export holds one chunk's observations however many
    episodes the file has. A reset is written in the chunk of its episode's first steps or
    an earlier one, so an episode's reset comes before its steps.
    """
    for chunk in ev.scan(steps=True, resets=True, episode_records=False):
        yield [(True, batch) for batch in chunk.resets] + [(False, b) for b in chunk.steps]


def blocks(ev: Evidence) -> Iterator[tuple[bool, pa.RecordBatch]]:
    """The blocks of :func:`chunk_blocks`, one after the other, in file order."""
    for chunk in chunk_blocks(ev):
        yield from chunk


def split_batch(batch: pa.RecordBatch, name: str) -> Split:
    """What the column ``name`` of ``batch`` gives a viewer (nothing if there is no such column)."""
    index = batch.schema.get_field_index(name)
    if index < 0:
        return Split()
    return split_column((name,), batch.column(index), batch.schema.field(index))


def has_frames(schema: pa.Schema) -> bool:
    """Whether step blocks of ``schema`` hold camera frames, before any block is read.

    They do when an action or observation field (a Dict or Tuple item too) is one that
    :func:`split_column` takes as images, as the field's metadata says.
    """
    none = pa.RecordBatch.from_pylist([], schema=schema)
    return any(split_batch(none, name).images for name in ("action", "observation"))


def frame_names(schema: pa.Schema) -> dict[tuple[str, ...], str]:
    """Each camera field of step blocks of ``schema``: its name in topics and entity paths.

    The names are :func:`dotted_names` of the fields' paths, distinct for distinct fields; a
    path not here (none in a file's schema) is named ``".".join(path)``.
    """
    none = pa.RecordBatch.from_pylist([], schema=schema)
    return dotted_names(
        frames.path
        for name in ("action", "observation")
        for frames in split_batch(none, name).images
    )


def dotted_names(paths: Iterable[tuple[str, ...]]) -> dict[tuple[str, ...], str]:
    """Each field path's name, its parts joined with ``.``: distinct for distinct paths.

    Where that makes one name of several paths (a Dict key ``"cam.left"`` and the key
    ``"left"`` of the Dict ``"cam"``), the path none of whose parts holds a ``.`` keeps it and
    the others, in sorted order, take the first free ``-2``, ``-3`` … after it, as PettingZoo
    agents' prefixes do (:func:`agent_prefixes`). The same paths always get the same names.

    >>> dotted_names([("o", "cam.left"), ("o", "cam", "left"), ("o", "eye")])
    {('o', 'cam', 'left'): 'o.cam.left', ('o', 'eye'): 'o.eye', ('o', 'cam.left'): 'o.cam.left-2'}
    """
    unique = sorted(set(paths))
    # (paths whose parts hold no "." join to distinct names: those keep theirs)
    names = {path: ".".join(path) for path in unique if not any("." in part for part in path)}
    taken = set(names.values())
    for path in unique:
        if path in names:
            continue
        name = base = ".".join(path)
        k = 1
        while name in taken:
            k += 1
            name = f"{base}-{k}"
        names[path] = name
        taken.add(name)
    return names


def split_column(path: tuple[str, ...], array: pa.Array, field_: pa.Field) -> Split:
    """What the column (or Dict / Tuple item) at ``path`` gives a viewer."""
    meta = field_.metadata or {}
    kind = meta.get(_KIND, b"").decode(errors="replace")  # (not UTF-8: no kind we know)
    present = ~np.asarray(array.is_null().to_numpy(zero_copy_only=False), dtype=bool)
    if kind == "array":
        return _split_array(path, array, meta, present)
    if kind == "discrete" and pa.types.is_integer(array.type):
        numbers = array.fill_null(0).to_numpy(zero_copy_only=False).reshape(-1, 1)
        return Split([Leaf(path, numbers, present, scalar=True, integer=True)])
    if kind in ("dict", "tuple") and isinstance(array, pa.StructArray):
        out = Split()
        for i in range(array.type.num_fields):
            child = array.type.field(i)
            part = split_column((*path, child.name), array.field(i), child)
            for leaf in part.leaves:
                leaf.present &= present
            out.leaves += part.leaves
            out.images += part.images
            out.left_out += part.left_out
        return out
    return Split(left_out=[".".join(path)])


def _split_array(
    path: tuple[str, ...], array: pa.Array, meta: dict[bytes, bytes], present: npt.NDArray[Any]
) -> Split:
    layout = _array_layout(array, meta)
    if layout is None:  # (metadata that does not describe the column: not from our recorder)
        return Split(left_out=[".".join(path)])
    shape, dtype = layout
    size = math.prod(shape)
    if size > SMALL and not _is_image(shape, dtype):
        return Split(left_out=[".".join(path)])
    values = array.values.slice(array.offset * size, len(array) * size)
    if values.null_count:
        values = values.fill_null(pa.scalar(0, values.type))
    flat = values.to_numpy(zero_copy_only=False).reshape(len(array), size)
    if _is_image(shape, dtype):
        pixels = flat.astype(np.uint8, copy=False).reshape(len(array), *shape)
        return Split(images=[Frames(path, pixels, present)])
    integer = dtype.kind in "iub"
    if dtype.kind == "b":
        flat = flat.astype(np.int8)
    return Split([Leaf(path, flat, present, scalar=not shape, integer=integer)])


def _array_layout(
    array: pa.Array, meta: dict[bytes, bytes]
) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
    """A Box column's row shape and dtype as its field's metadata says, if they describe it.

    They do when the column is a fixed-size list of as many numbers per row as the shape
    holds, of that dtype; for anything else (a file not from our recorder) ``None``.

    >>> column = pa.array([[1, 2, 3, 4]], pa.list_(pa.uint8(), 4))
    >>> _array_layout(column, {_SHAPE: b"[2, 2]", _DTYPE: b"uint8"})
    ((2, 2), dtype('uint8'))
    >>> _array_layout(column, {_SHAPE: b"[" * 100_000, _DTYPE: b"uint8"}) is None
    True
    """
    try:
        shape = from_json(meta.get(_SHAPE, b"[]"), "the column's shape", limit=1024)
        dtype = np.dtype(meta.get(_DTYPE, b"float64").decode())
        value_type = pa.from_numpy_dtype(dtype)
    except (ValueError, TypeError, pa.ArrowException):  # (UnicodeDecodeError: a ValueError)
        return None
    if (
        not isinstance(shape, list)
        or not all(type(n) is int and n >= 0 for n in shape)
        or not pa.types.is_fixed_size_list(array.type)
        or array.type.value_type != value_type
        or array.type.list_size != math.prod(shape)
    ):
        return None
    return tuple(shape), dtype


def _is_image(shape: tuple[int, ...], dtype: np.dtype[Any]) -> bool:
    if dtype != np.uint8 or len(shape) not in (2, 3):
        return False
    if len(shape) == 3 and shape[2] not in (1, 3, 4):
        return False
    return min(shape[0], shape[1]) >= IMAGE_MIN_SIDE


def json_rows(leaves: Sequence[Leaf], rows: int) -> list[Any]:
    """Per row, the leaves of one column as JSON values (``None``: the row has none).

    A column that is one leaf gives its number or list per row; Dict / Tuple items nest as
    objects keyed like the space. Non-finite floats become ``None`` (JSON has none).
    """
    if not leaves:
        return [None] * rows
    depth = len(leaves[0].path)
    if len(leaves) == 1 and depth == 1:
        return _leaf_rows(leaves[0])
    out: list[Any] = [{} for _ in range(rows)]
    for leaf in leaves:
        for row, value in enumerate(_leaf_rows(leaf)):
            if value is None:
                continue
            node = out[row]
            for key in leaf.path[1:-1]:
                node = node.setdefault(key, {})
            node[leaf.path[-1]] = value
    return [row or None for row in out]


def _leaf_rows(leaf: Leaf) -> list[Any]:
    numbers = leaf.numbers
    if numbers.dtype.kind == "f" and not np.isfinite(numbers).all():
        rows: list[Any] = [finite(r) for r in numbers.tolist()]
    else:
        rows = numbers.tolist()
    if leaf.scalar:
        rows = [r[0] for r in rows]
    if not leaf.present.all():
        rows = [r if ok else None for r, ok in zip(rows, leaf.present.tolist(), strict=True)]
    return rows


def json_schema(leaves: Sequence[Leaf]) -> dict[str, Any] | None:
    """The JSON Schema of :func:`json_rows` of ``leaves`` (``None`` when there are none)."""
    if not leaves:
        return None
    if len(leaves) == 1 and len(leaves[0].path) == 1:
        return _leaf_schema(leaves[0])
    root: dict[str, Any] = {"type": "object", "properties": {}}
    for leaf in leaves:
        node = root
        for key in leaf.path[1:-1]:
            node = node["properties"].setdefault(key, {"type": "object", "properties": {}})
        node["properties"][leaf.path[-1]] = _leaf_schema(leaf)
    return root


NONFINITE_NULL = "null where the value is NaN or infinite (JSON has no such number)"
"""The description of a float field in a JSON Schema: its type stays ``number`` (the one type
Foxglove reads a field as), though NaN and infinite values are written ``null``."""


def _leaf_schema(leaf: Leaf) -> dict[str, Any]:
    number = (
        {"type": "integer"} if leaf.integer else {"type": "number", "description": NONFINITE_NULL}
    )
    return number if leaf.scalar else {"type": "array", "items": number}


def ending_text(record: dict[str, Any]) -> str:
    """How an episode ended, in one line (the text of its ``foxglove.Log`` and Rerun log).

    >>> ending_text({"episode": 3, "outcome": "failure", "failure_label": "collision",
    ...              "length": 12, "return": -4.5, "env_index": 0, "agent": None})
    'episode 3: failure (collision) after 12 steps, return -4.5'
    >>> ending_text({"episode": 0, "outcome": "error", "error_type": "ValueError",
    ...              "error_message": "boom", "error_during": "step", "length": 2,
    ...              "return": 0.0, "env_index": 1, "agent": None}, )
    'episode 0: error in step (ValueError: boom) after 2 steps, return 0'
    """
    outcome = record["outcome"]
    detail = ""
    if outcome == "failure":
        detail = f" ({record.get('failure_label') or 'unlabeled'})"
    elif outcome == "truncated":
        detail = f" ({record.get('truncation_reason') or 'external'})"
    elif outcome == "error":
        detail = (
            f" in {record.get('error_during') or 'step'} "
            f"({record.get('error_type')}: {record.get('error_message')})"
        )
    ret = record.get("return")
    returned = f", return {ret:.6g}" if isinstance(ret, float) else ""
    return (
        f"episode {record['episode']}: {outcome}{detail} after {record['length']} steps{returned}"
    )
