"""An episode's JSON record: the common one, written straight from the episode, is the same bytes
as the general encoding of its record; every other one takes the general encoding."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from episode_audit.format.records import to_json
from episode_audit.format.schemas import EPISODE_BLOCK_BASE, EPISODE_BLOCK_SCHEMA
from episode_audit.record import native
from episode_audit.record.block import Episode
from episode_audit.record.episode_records import (
    _columns_batch,
    _episode_batch,
    _episode_json,
    _episode_record,
    _plain_episode_json,
)
from episode_audit.record.writer import ipc_stream

_TEXT = st.text(max_size=12)
_FLOATS = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, -0.0, 1e300])


@st.composite
def ended(draw: Any, common: bool = False) -> tuple[Episode, dict[str, Any], int, int, bool]:
    """An ended episode; ``common``: one without options or error, of a finite return."""
    options = (
        None if common else draw(st.none() | st.dictionaries(_TEXT, st.integers(), max_size=2))
    )
    episode = Episode(
        draw(st.integers(0, 2**40)),
        draw(st.none() | st.integers(0, 2**63 - 1)),
        draw(st.none() | st.just(to_json({"bit_generator": "PCG64", "state": {"state": 1}}))),
        options,
        draw(st.integers(0, 2**62)),
        draw(st.integers(0, 64)),
        draw(st.none() | _TEXT),
        draw(st.none() | st.integers(0, 1000)),
    )
    episode.steps = draw(st.integers(0, 2**31))
    episode.ret = draw(st.floats(allow_nan=False, allow_infinity=False) if common else _FLOATS)
    episode.totals = draw(st.dictionaries(_TEXT, _FLOATS, max_size=3))
    episode.notes = draw(st.integers(0, 5))
    error = None
    if not common:
        error = draw(
            st.none() | st.just({"type": "ValueError", "message": "x\u00e9", "during": "step"})
        )
    ending = {
        "outcome": draw(st.sampled_from(["success", "failure", "truncated", "incomplete"])),
        "failure_label": draw(st.none() | _TEXT),
        "truncation_reason": draw(st.none() | _TEXT),
        "terminated": draw(st.booleans()),
        "truncated": draw(st.booleans()),
        "error": error,
    }
    return (
        episode,
        ending,
        draw(st.integers(0, 2**62)),
        draw(st.integers(0, 2**60)),
        draw(st.booleans()),
    )


def general(episode: Episode, ending: dict[str, Any], end: int, offset: int, games: bool) -> bytes:
    record = _episode_record(episode, ending, end, offset, games)
    data = to_json({k: v for k, v in record.items() if v is not None})
    if episode.rng_json is not None:
        data = data[:-1] + b',"rng_state":' + episode.rng_json + b"}"
    return data


@settings(max_examples=300, deadline=None)
@given(ended())
def test_an_episode_record_is_the_general_encodings_bytes(
    case: tuple[Episode, dict[str, Any], int, int, bool],
) -> None:
    assert _episode_json(*case) == general(*case)


def test_the_common_record_is_written_straight_and_others_are_not() -> None:
    episode = Episode(3, 7, None, None, 10, 0, None)
    episode.steps, episode.ret, episode.totals = 21, 21.0, {"ctrl": -0.5, "dist": 1e-3}
    ending = {
        "outcome": "failure",
        "failure_label": "unlabeled",
        "truncation_reason": None,
        "terminated": True,
        "truncated": False,
        "error": None,
    }
    plain = _plain_episode_json(episode, ending, 99, 1000, False)
    assert plain == general(episode, ending, 99, 1000, False)
    assert plain is not None and b'"term_totals":{"ctrl":-0.5,"dist":0.001}' in plain
    episode.ret = math.nan
    assert _plain_episode_json(episode, ending, 99, 1000, False) is None
    assert b'"return":"nan"' in _episode_json(episode, ending, 99, 1000, False)


_COMPILED = pytest.mark.skipif(
    native.NATIVE is None, reason="the extension is not built (no C compiler at install)"
)


@_COMPILED
@settings(max_examples=300, deadline=None)
@given(ended(), st.integers(-(2**62), 2**62))
def test_the_compiled_records_are_the_python_ones(
    case: tuple[Episode, dict[str, Any], int, int, bool], end_ns: int
) -> None:
    """Each common record (and its end time) is the Python path's bytes; for any other the
    compiled writer declines, and the Python path writes it."""
    episode, ending, _, offset, games = case
    episode.end_ns = end_ns
    got = native.episode_json([(episode, ending)], offset, games)
    if _plain_episode_json(episode, ending, end_ns + offset, offset, games) is None:
        assert got is None
    else:
        assert got == (
            [_episode_json(episode, ending, end_ns + offset, offset, games)],
            [end_ns + offset],
        )


@_COMPILED
@settings(max_examples=200, deadline=None)
@given(
    st.lists(ended(common=True), min_size=1, max_size=8),
    st.integers(-(2**40), 2**40),
    st.booleans(),
)
def test_the_compiled_episode_columns_make_the_python_block(
    cases: list[tuple[Episode, dict[str, Any], int, int, bool]], end_ns: int, games: bool
) -> None:
    """The episode block from the compiled columns is the Python path's, byte for byte (its
    Arrow IPC stream); the columns are declined where the records are."""
    ended = [(episode, ending) for episode, ending, *_ in cases]
    for episode, _ in ended:
        episode.end_ns = end_ns
    offset = cases[0][3]
    schema = EPISODE_BLOCK_SCHEMA if games else EPISODE_BLOCK_BASE
    records = native.episode_json(ended, offset, games)
    columns = native.episode_columns(ended, offset, games)
    if records is None:  # (a time past 64 bits): the Python path writes them all
        return
    ends = records[1]
    expected = _episode_batch(ended, ends, offset, games, schema)
    got = _columns_batch(len(ended), columns, schema)
    # (bytes, not equals(): a NaN term total is never equal to itself)
    assert ipc_stream(got) == ipc_stream(expected)


@_COMPILED
def test_the_compiled_records_decline_the_whole_list_for_one_uncommon_episode() -> None:
    def common(index: int) -> tuple[Episode, dict[str, Any]]:
        episode = Episode(index, 7, None, None, 10, 0, None)
        episode.steps, episode.ret, episode.end_ns = 21, 21.0, 50
        ending = {
            "outcome": "success",
            "failure_label": None,
            "truncation_reason": None,
            "terminated": True,
            "truncated": False,
            "error": None,
        }
        return episode, ending

    ended = [common(0), common(1)]
    datas, ends = native.episode_json(ended, 5, False) or ([], [])
    assert datas[1].startswith(b'{"episode":1,') and ends == [55, 55]
    for change in (
        lambda ep, e: setattr(ep, "index", np.int64(1)),  # (an int, but not a Python one)
        lambda ep, e: setattr(ep, "seed", 2**64),  # (beyond 64 bits)
        lambda ep, e: setattr(ep, "ret", math.inf),
        lambda ep, e: setattr(ep, "options", {"a": 1}),
        lambda ep, e: e.update(error={"type": "E", "message": "m", "during": "step"}),
        lambda ep, e: e.update(error_ns=60),
        lambda ep, e: e.update(terminated=1),
        lambda ep, e: e.update(failure_label=b"bytes"),
        lambda ep, e: e.pop("outcome"),
    ):
        ended = [common(0), common(1)]
        change(*ended[1])
        assert native.episode_json(ended, 5, False) is None


@_COMPILED
@pytest.mark.parametrize("kind", ["PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64"])
def test_an_rng_state_compiled_is_its_to_json(kind: str) -> None:
    generator = getattr(np.random, kind)(2**70 + 3)
    np.random.Generator(generator).integers(0, 10, size=5)
    state = generator.state
    assert native.rng_json(state) == to_json(state)


@_COMPILED
@settings(max_examples=200, deadline=None)
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | _TEXT,
        lambda inner: st.dictionaries(_TEXT, inner, max_size=3),
        max_leaves=8,
    ).filter(lambda v: isinstance(v, dict))
)
def test_a_dict_of_text_and_integers_compiled_is_its_to_json(state: dict[str, Any]) -> None:
    assert native.NATIVE.rng_json(state, json.encoder.encode_basestring_ascii) == to_json(state)


def test_the_totals_column_is_the_terms_column_of_the_totals() -> None:
    """Uniform names (some episodes without any), and any other mix: the same IPC bytes."""
    from episode_audit.format.columns import terms_column
    from episode_audit.record.episode_records import _totals_column

    rng = np.random.default_rng(3)
    shapes: list[Any] = [
        {"d": 0.0, "c": 0.0},
        {},
        {"c": 0.0, "d": 0.0},
        {"é": 0.0},
        {"x\udcff": 0.0},
        {"d": "n", "c": 0.0},
        {"d": 1, "c": 0.0},
    ]
    for _ in range(300):
        n = int(rng.integers(1, 30))
        picks = rng.integers(0, 2 if rng.random() < 0.7 else len(shapes), n)
        totals = [
            {k: (float(rng.normal()) if v == 0.0 else v) for k, v in shapes[int(i)].items()}
            for i in picks
        ]
        got, want = _totals_column(totals), terms_column(n, dict(enumerate(totals)))
        batches = [pa.RecordBatch.from_arrays([a], names=["t"]) for a in (got, want)]
        assert batches[0].serialize().to_pybytes() == batches[1].serialize().to_pybytes()
