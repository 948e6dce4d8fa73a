from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from episode_audit.outcomes import RewardTerms

AUTO_CASES: list[tuple[dict[Any, Any], dict[str, Any] | None]] = [
    ({}, None),
    ({"x": 1}, None),
    ({"reward_a": 1.0, "x": 2, "reward_b": -0.5}, {"reward_a": 1.0, "reward_b": -0.5}),
    ({"reward_terms": {"alive": 1.0}, "reward_a": 3.0}, {"alive": 1.0}),
    ({0: "not a name", "reward_a": 2.0}, {"reward_a": 2.0}),
    ({"reward_b": 1.0, "reward_a": 2.0}, {"reward_b": 1.0, "reward_a": 2.0}),
]


def test_auto_terms_follow_the_keys_of_each_step() -> None:
    # one extractor across steps whose keys change: the remembered names are per key tuple
    extract = RewardTerms().extractor
    for _ in range(3):
        for info, expected in AUTO_CASES:
            got = extract(info)
            assert got == expected
            assert got is None or list(got) == list(expected or {})  # the env's order


def test_auto_terms_of_ever_new_keys() -> None:
    extract = RewardTerms().extractor
    for i in range(200):  # more key tuples than are remembered
        assert extract({f"k{i}": 0, f"reward_{i}": float(i)}) == {f"reward_{i}": float(i)}


@pytest.mark.parametrize(
    ("source", "info", "expected"),
    [
        (["reward_a", "missing"], {"reward_a": 1.0, "reward_b": 2.0}, {"reward_a": 1.0}),
        (["missing"], {"reward_a": 1.0}, None),
        (lambda info: {"double": 2 * info["v"]}, {"v": 1.5}, {"double": 3.0}),
        (lambda info: None, {"v": 1.5}, None),
        (None, {"reward_a": 1.0}, None),
    ],
)
def test_other_sources(source: Any, info: dict[str, Any], expected: Any) -> None:
    terms = RewardTerms(source)
    assert terms.extract(info) == expected
    assert terms.extractor(info) == expected
    assert terms.extractor is terms.extractor  # built once


def test_the_extractor_cache_is_not_part_of_equality() -> None:
    used = RewardTerms()
    used.extract({"reward_a": 1.0})
    assert used == RewardTerms()
    assert repr(used) == repr(RewardTerms())


MANY_CASES: list[tuple[Any, list[dict[Any, Any]], bool]] = [
    ("auto", [{"reward_a": 1.0, "x": 2, "reward_b": -0.5}] * 3, True),
    ("auto", [{"reward_a": 1.0}, {"reward_a": True}, {"reward_a": 3}], True),
    ("auto", [{"reward_a": 1.0}, {"reward_b": 1.0}], False),  # names change
    ("auto", [{"reward_a": 1.0, "x": 0}, {"x": 0, "reward_a": 1.0}], False),  # order changes
    ("auto", [{"reward_terms": {"alive": 1.0}}] * 2, False),  # nested: step by step
    ("auto", [{"reward_a": "1.5"}], False),  # text is not a number
    ("auto", [{"x": 1.0}] * 2, False),  # no terms at all
    ("auto", [], False),
    (["reward_b", "nope"], [{"reward_a": 1.0, "reward_b": 2.0}] * 2, True),
    (lambda info: {"v": 1.0}, [{"x": 1.0}], False),
]


@pytest.mark.parametrize(("source", "infos", "batched"), MANY_CASES)
def test_extract_many_is_extract_for_each_step(
    source: Any, infos: list[dict[Any, Any]], batched: bool
) -> None:
    terms = RewardTerms(source)
    many = terms.extract_many(infos)
    assert (many is not None) is batched
    if many is not None:
        names, values = many
        assert values.dtype == np.float64 and values.shape == (len(infos), len(names))
        for info, row in zip(infos, values.tolist(), strict=True):
            one = terms.extract(info)
            assert one is not None and list(one) == list(names)
            assert [float(v) for v in one.values()] == row
