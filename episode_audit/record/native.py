"""The recorder's compiled part, ``episode_audit.record._stepfast``: loaded once, or ``None``.

The extension is built with the package when a C compiler is there (``setup.py``). It holds the
compiled step and reset (:mod:`.fast`), the common episode records' JSON (:func:`episode_json`),
the framing of many MCAP messages at once (:func:`frame_messages`), and a block's counting and
text columns (:func:`counting`). Each writes the same bytes as the Python it stands in for.
``EPISODE_AUDIT_PURE_PYTHON=1`` in the environment (read when a recorder is made) keeps a
recorder on the pure-Python path. See ``docs/recording.md``.
"""

from __future__ import annotations

import array
import importlib
import json
import os
from collections.abc import Callable
from typing import Any

from ..format.records import to_json
from ..format.spaces.buffers import _ArrayBuffer, _FlatArrayBuffer, _IntBuffer
from .block import Block, Episode
from .counting import Compiled

__all__ = [
    "NATIVE",
    "PURE_PYTHON_ENV",
    "compiled",
    "counting",
    "episode_columns",
    "episode_json",
    "frame_messages",
    "rng_json",
    "rng_json_function",
    "untrack",
]

PURE_PYTHON_ENV = "EPISODE_AUDIT_PURE_PYTHON"
"""The environment variable that, set to ``1``, keeps recorders on the pure-Python path."""


def _load() -> Any:
    try:
        module: Any = importlib.import_module("episode_audit.record._stepfast")
        module.configure(Block, Episode, _FlatArrayBuffer, _ArrayBuffer, _IntBuffer, array.array)
    except Exception:  # not built, or built for another layout: the Python path
        return None
    return module


NATIVE = _load()
"""The configured extension module, or ``None`` when it is not built (or does not fit)."""


def _tracked(obj: object) -> None:
    """Without the extension the collector keeps tracking them: nothing to do."""


untrack: Callable[[object], None] = _tracked if NATIVE is None else NATIVE.untrack
"""Leave one of a recorder's per-episode objects out of the cyclic garbage collector.

Only for objects no reference cycle can pass through: an :class:`~.block.Episode` (ints,
texts, its own JSON data), an ``(episode, ending)`` pair, a block's row tuples of ints and
texts. Made once per episode and kept until a flush, they would otherwise be scanned at each
young collection and promoted to the oldest generation, whose growth sets off full collections
of the whole process (on the vector recorder over 8 CartPoles: 0.41 µs a sub-env step, 0.15
with them left out). Does nothing without the extension.
"""

_QUOTE = json.encoder.encode_basestring_ascii  # (json.dumps' strings: ASCII, escaped)


def compiled() -> bool:
    """Whether the extension is built and recorders made now use it."""
    return NATIVE is not None and os.environ.get(PURE_PYTHON_ENV) != "1"


def episode_json(
    ended: list[tuple[Episode, dict[str, Any]]], offset: int, games: bool
) -> tuple[list[bytes], list[int]] | None:
    """The JSON records of the ended episodes and their end times (wall clock), compiled.

    The same bytes as ``file._episode_json``. ``None`` when one of them is not the common
    record (an error, options, a return that is no finite float...): the Python path then
    writes them all. Requires the extension (:data:`NATIVE`).
    """
    result: tuple[list[bytes], list[int]] | None = NATIVE.episode_json(
        ended, offset, games, _QUOTE, to_json
    )
    return result


def episode_columns(
    ended: list[tuple[Episode, dict[str, Any]]], offset: int, games: bool
) -> dict[str, Any] | None:
    """The episode block's columns of the ended episodes, when all are common records.

    Arrays of the numbers and flags, lists of the texts and term totals (``csrc/records.c`` says
    which); ``None`` when one is not a common record (:func:`episode_json`'s). Requires the
    extension (:data:`NATIVE`).
    """
    result: dict[str, Any] | None = NATIVE.episode_columns(ended, offset, games)
    return result


def counting() -> Compiled | None:
    """The compiled counting of a block's rows (``csrc/blocks.c``) when used now, else ``None``.

    For :func:`~.block.count_block`: the same counts, returns, term totals and terms column as
    its Python.
    """
    module: Compiled | None = NATIVE if compiled() else None
    return module


def rng_json(state: dict[str, Any]) -> bytes:
    """``to_json(state)`` for an RNG state (a bit generator's ``state`` dict), compiled.

    A dict of text, integers and such dicts (PCG64's) is written in C; any other (MT19937's
    holds an array) by :func:`~episode_audit.format.records.to_json`. Requires the extension.

    >>> import numpy as np
    >>> state = np.random.PCG64(7).state
    >>> NATIVE is None or rng_json(state) == to_json(state)
    True
    """
    data: bytes | None = NATIVE.rng_json(state, _QUOTE)
    return to_json(state) if data is None else data


def rng_json_function() -> Callable[[dict[str, Any]], bytes]:
    """:func:`rng_json` when the extension is used now (:func:`compiled`), else ``to_json``.

    >>> rng_json_function()({"bit_generator": "PCG64"})
    b'{"bit_generator":"PCG64"}'
    """
    return rng_json if compiled() else to_json


def frame_messages(
    datas: list[bytes], times: list[int], channel: int, sequence: int, offset: int
) -> tuple[bytes, list[tuple[int, int]]]:
    """MCAP Message records of ``datas`` on ``channel``, and their message index entries.

    Each message's log and publish time is its entry of ``times``; sequence numbers count from
    ``sequence`` (modulo 2**32); the first record starts at byte ``offset`` of its chunk. The
    bytes ``mcap``'s ``Writer.add_message`` writes one by one. Requires the extension.
    """
    result: tuple[bytes, list[tuple[int, int]]] = NATIVE.frame_messages(
        datas, times, channel, sequence, offset
    )
    return result
