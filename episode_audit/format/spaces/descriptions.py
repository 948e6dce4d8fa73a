"""Spaces as JSON and back: :func:`describe_space` and :func:`space_from_description`.

The run metadata describes the observation and action spaces this way, so a reader rebuilds
their codecs (and replay their bounds) from the file alone.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.spaces import Space

from ...errors import ConfigurationError

__all__ = ["UnknownSpace", "describe_space", "space_from_description", "unknown_spaces"]


class UnknownSpace(Space[Any]):
    """Stands in for a space of a class episode-audit does not know (a ``"Custom"`` description).

    The file holds its values as JSON (``json.dumps(space.to_jsonable([value])[0])``): they
    decode to that JSON value, are not checked against the space (``contains`` is always true)
    and cannot be sampled.

    >>> space = UnknownSpace("minigrid.core.mission.MissionSpace", "MissionSpace(...)")
    >>> space.name, space.contains("go to the red door")
    ('MissionSpace', True)
    """

    def __init__(self, class_path: str, text: str) -> None:
        super().__init__()
        self.class_path = class_path
        """The module and qualified name of the recorded space's class."""
        self.text = text
        """The recorded space's ``repr``."""

    @property
    def name(self) -> str:
        """The class name of the recorded space, without its module."""
        return self.class_path.rsplit(".", 1)[-1] or "a custom space"

    def sample(self, mask: Any = None, probability: Any = None) -> Any:
        """Raise :class:`ConfigurationError`: the recorded space is not here to sample from."""
        raise ConfigurationError(
            f"Cannot sample {self.name}: the file describes it by class and repr only; "
            "build the space in code"
        )

    def contains(self, x: Any) -> bool:
        """Return ``True``: values of an unknown space are not checked."""
        return True

    def to_jsonable(self, sample_n: Any) -> list[Any]:
        """Return the values with numpy arrays and scalars as lists and numbers."""
        return [_plain(value) for value in sample_n]

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, UnknownSpace)
            and other.class_path == self.class_path
            and other.text == self.text
        )

    def __hash__(self) -> int:
        return hash((self.class_path, self.text))

    def __repr__(self) -> str:
        return f"Custom({self.class_path})"


def _plain(value: Any) -> Any:
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    if isinstance(value, Mapping):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def _json_float(value: float) -> float | str:
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def _describe_bound(values: npt.NDArray[Any], bounded: npt.NDArray[np.bool_], marker: str) -> Any:
    """Return one bound of a Box: a scalar when all elements agree, else a flat C-order list."""
    kind = values.dtype.kind
    flat, flat_bounded = values.reshape(-1), bounded.reshape(-1)
    if flat.size > 1 and (flat_bounded == flat_bounded[0]).all() and (flat == flat[0]).all():
        # the usual case (an image: 0 and 255 everywhere), without a loop over the elements
        return _describe_bound(flat[:1], flat_bounded[:1], marker)
    items: list[Any] = []
    for value, is_bounded in zip(
        values.reshape(-1).tolist(), bounded.reshape(-1).tolist(), strict=True
    ):
        if kind == "f":
            items.append(_json_float(value))
        elif kind == "b":
            items.append(bool(value))
        else:
            items.append(int(value) if is_bounded else marker)
    if items and all(type(x) is type(items[0]) and x == items[0] for x in items):
        return items[0]
    return items


def describe_space(space: Space[Any]) -> dict[str, Any]:
    """Return a JSON-serializable description of ``space`` (:func:`space_from_description` inverts).

    Non-finite floats are written as the strings ``"inf"``, ``"-inf"`` and ``"nan"``; a Box bound
    that is the same for every element is written once. Spaces this module does not know are
    described by class and ``repr`` only, and rebuilt as an :class:`UnknownSpace`.

    >>> import numpy as np
    >>> from gymnasium import spaces
    >>> describe_space(spaces.Box(-np.inf, 1.0, shape=(2,), dtype=np.float32))
    {'type': 'Box', 'shape': [2], 'dtype': 'float32', 'low': '-inf', 'high': 1.0}
    >>> describe_space(spaces.Discrete(3, start=-1))
    {'type': 'Discrete', 'n': 3, 'start': -1, 'dtype': 'int64'}
    """
    if isinstance(space, spaces.Box):
        return {
            "type": "Box",
            "shape": list(space.shape),
            "dtype": space.dtype.name,
            "low": _describe_bound(space.low, space.bounded_below, "-inf"),
            "high": _describe_bound(space.high, space.bounded_above, "inf"),
        }
    if isinstance(space, spaces.Discrete):
        return {
            "type": "Discrete",
            "n": int(space.n),
            "start": int(space.start),
            "dtype": space.dtype.name,
        }
    if isinstance(space, spaces.MultiDiscrete):
        return {
            "type": "MultiDiscrete",
            "nvec": space.nvec.tolist(),
            "start": space.start.tolist(),
            "dtype": space.dtype.name,
        }
    if isinstance(space, spaces.MultiBinary):
        return {"type": "MultiBinary", "n": space.n if isinstance(space.n, int) else list(space.n)}
    if isinstance(space, spaces.Text):
        return {
            "type": "Text",
            "min_length": space.min_length,
            "max_length": space.max_length,
            "charset": "".join(space.character_list),
        }
    if isinstance(space, spaces.Dict):
        return {
            "type": "Dict",
            "spaces": [[key, describe_space(s)] for key, s in space.spaces.items()],
        }
    if isinstance(space, spaces.Tuple):
        return {"type": "Tuple", "spaces": [describe_space(s) for s in space.spaces]}
    if isinstance(space, spaces.Sequence):
        return {
            "type": "Sequence",
            "space": describe_space(space.feature_space),
            "stack": bool(space.stack),
        }
    if isinstance(space, spaces.Graph):
        return {
            "type": "Graph",
            "node_space": describe_space(space.node_space),
            "edge_space": None if space.edge_space is None else describe_space(space.edge_space),
        }
    if isinstance(space, spaces.OneOf):
        return {"type": "OneOf", "spaces": [describe_space(s) for s in space.spaces]}
    cls = type(space)
    return {"type": "Custom", "class": f"{cls.__module__}.{cls.__qualname__}", "repr": repr(space)}


def _parse_float(value: Any) -> float:
    if isinstance(value, str) and value in ("inf", "-inf", "nan"):
        return float(value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    raise ConfigurationError(f"Expect a number or 'inf', '-inf', 'nan', actually: {value!r}")


def _parse_bound(
    raw: Any, shape: tuple[int, ...], dtype: np.dtype[Any], marker: str
) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    size = math.prod(shape)
    if not isinstance(raw, list) and size != 1:
        # one value for every element (written so when all agree): parsed once
        one, one_bounded = _parse_bound(raw, (1,), dtype, marker)
        return np.full(shape, one[0], dtype=dtype), np.full(shape, bool(one_bounded[0]))
    items = raw if isinstance(raw, list) else [raw] * size
    if len(items) != size:
        raise ConfigurationError(
            f"Expect a Box bound with {size} values for shape {shape}, actually: {len(items)}"
        )
    bounded = np.array([x != marker for x in items], dtype=np.bool_).reshape(shape)
    if dtype.kind == "f":
        values = np.array([_parse_float(x) for x in items], dtype=dtype)
    elif dtype.kind == "b":
        if not all(isinstance(x, bool) for x in items):
            raise ConfigurationError(f"Expect bool Box bounds, actually: {raw!r}")
        values = np.array(items, dtype=dtype)
    else:
        info = np.iinfo(dtype)
        limit = int(info.min) if marker == "-inf" else int(info.max)
        if not all(x == marker or (isinstance(x, int) and not isinstance(x, bool)) for x in items):
            raise ConfigurationError(f"Expect integer Box bounds, actually: {raw!r}")
        values = np.array([limit if x == marker else x for x in items], dtype=dtype)
    return values.reshape(shape), bounded


def _box_from_description(desc: Mapping[str, Any]) -> spaces.Box[Any]:
    shape = tuple(desc["shape"])
    if not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape):
        raise ConfigurationError(f"Expect a Box shape of ints >= 0, actually: {desc['shape']!r}")
    dtype = np.dtype(desc["dtype"])
    low, bounded_below = _parse_bound(desc["low"], shape, dtype, "-inf")
    high, bounded_above = _parse_bound(desc["high"], shape, dtype, "inf")
    box = spaces.Box(low=low, high=high, shape=shape, dtype=dtype)
    if dtype.kind in "iu":  # integer boxes store unbounded ends as the dtype limits
        box.bounded_below = bounded_below
        box.bounded_above = bounded_above
    return box


def _discrete(n: int, start: int, dtype: str) -> spaces.Discrete:
    """``Discrete(n, start=start, dtype=dtype)``; int64 without the argument Gymnasium 1.1 lacks."""
    if np.dtype(dtype) == np.int64:
        return spaces.Discrete(n, start=start)
    if "dtype" not in inspect.signature(spaces.Discrete).parameters:
        raise ConfigurationError(
            f"a Discrete space of dtype {dtype} needs Gymnasium >= 1.2 (this is "
            f"{gymnasium.__version__}): upgrade it to rebuild this space"
        )
    return spaces.Discrete(n, start=start, dtype=dtype)


def _from_description(desc: Any) -> Space[Any]:
    if not isinstance(desc, Mapping) or not isinstance(desc.get("type"), str):
        raise ConfigurationError(
            f"Expect a space description (a dict with a 'type'), actually: {desc!r:.200}"
        )
    kind = desc["type"]
    if kind == "Box":
        return _box_from_description(desc)
    if kind == "Discrete":
        return _discrete(int(desc["n"]), int(desc["start"]), desc["dtype"])
    if kind == "MultiDiscrete":
        dtype: np.dtype[Any] = np.dtype(desc["dtype"])
        nvec: npt.NDArray[np.integer[Any]] = np.array(desc["nvec"], dtype=dtype)
        start: npt.NDArray[np.integer[Any]] = np.array(desc["start"], dtype=dtype)
        return spaces.MultiDiscrete(nvec, dtype=dtype, start=start)
    if kind == "MultiBinary":
        n = desc["n"]
        return spaces.MultiBinary(n if isinstance(n, int) else tuple(n))
    if kind == "Text":
        return spaces.Text(
            int(desc["max_length"]),
            min_length=int(desc["min_length"]),
            charset=str(desc["charset"]),
        )
    if kind == "Dict":
        return spaces.Dict([(key, _from_description(s)) for key, s in desc["spaces"]])
    if kind == "Tuple":
        return spaces.Tuple([_from_description(s) for s in desc["spaces"]])
    if kind == "Sequence":
        return spaces.Sequence(_from_description(desc["space"]), stack=bool(desc["stack"]))
    if kind == "Graph":
        edge = desc["edge_space"]
        return spaces.Graph(
            node_space=_from_description(desc["node_space"]),
            edge_space=None if edge is None else _from_description(edge),
        )
    if kind == "OneOf":
        return spaces.OneOf([_from_description(s) for s in desc["spaces"]])
    if kind == "Custom":
        return UnknownSpace(str(desc.get("class", "")), str(desc.get("repr", "")))
    raise ConfigurationError(
        "Expect a space type Box, Discrete, MultiDiscrete, MultiBinary, Text, Dict, Tuple, "
        f"Sequence, Graph or OneOf, actually: {kind!r}"
    )


def space_from_description(desc: dict[str, Any]) -> Space[Any]:
    """Rebuild the space :func:`describe_space` described (its RNG state is not kept).

    A space of a class this module does not know comes back as an :class:`UnknownSpace`
    (at any depth: the other items of a Dict or Tuple are rebuilt as usual).

    >>> from gymnasium import spaces
    >>> space = spaces.Dict({"pos": spaces.Box(-1.0, 1.0, shape=(2,)), "id": spaces.Discrete(4)})
    >>> space_from_description(describe_space(space)) == space
    True

    Raises :class:`ConfigurationError` when the description is unknown or invalid.
    """
    try:
        return _from_description(desc)
    except ConfigurationError:
        raise
    except (KeyError, TypeError, ValueError, OverflowError, AssertionError) as exc:
        raise ConfigurationError(
            f"Expect a valid space description, actually: {desc!r:.200} "
            f"({type(exc).__name__}: {exc})"
        ) from exc


def unknown_spaces(description: Any, name: str) -> list[str]:
    """Where a described space holds spaces of a class episode-audit does not know, one line each.

    ``name`` is what the space is (``"observation"``); a Dict item is named by its key, a Tuple
    item by its index, the item space of a Sequence by ``[*]``.

    >>> desc = {"type": "Dict", "spaces": [["mission", {"type": "Custom", "class": "m.Mission"}]]}
    >>> unknown_spaces(desc, "observation")
    ["observation['mission']: Mission is not a Gymnasium space episode-audit knows: stored as JSON"]
    """
    if not isinstance(description, Mapping):
        return []
    kind = description.get("type")
    if kind == "Custom":
        known = UnknownSpace(str(description.get("class", "")), "").name
        return [f"{name}: {known} is not a Gymnasium space episode-audit knows: stored as JSON"]
    found: list[str] = []
    items: list[tuple[str, Any]] = []
    if kind == "Dict" and isinstance(description.get("spaces"), list):
        items = [
            (f"{name}[{item[0]!r}]", item[1])
            for item in description["spaces"]
            if isinstance(item, list) and len(item) == 2
        ]
    elif kind in ("Tuple", "OneOf") and isinstance(description.get("spaces"), list):
        items = [(f"{name}[{i}]", d) for i, d in enumerate(description["spaces"])]
    elif kind == "Sequence":
        items = [(f"{name}[*]", description.get("space"))]
    elif kind == "Graph":
        items = [(f"{name}.nodes", description.get("node_space"))]
        items.append((f"{name}.edges", description.get("edge_space")))
    for item_name, item in items:
        found.extend(unknown_spaces(item, item_name))
    return found
