from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from episode_audit.errors import ConfigurationError
from episode_audit.record.rules import Ending, EndingRules, RewardTerms, named_terms

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


NAME_CASES: list[tuple[list[Any], list[float], dict[str, float], str | None]] = [
    (["a", "b"], [1.0, 2.0], {"a": 1.0, "b": 2.0}, None),
    ([b"a", 0, True], [1.0, 2.0, 3.0], {"b'a'": 1.0, "0": 2.0, "True": 3.0}, None),
    (["a\udcff"], [1.0], {"a\\udcff": 1.0}, None),  # as the file stores it
    (
        [1, "x", "1", 1.0],
        [0.5, 2.0, 0.25, 0.125],
        {"1": 0.5 + 0.25, "x": 2.0, "1.0": 0.125},
        "keys 1, '1' share the name '1': recorded as one term, their sum",
    ),
    (
        ["a\udcff", "a\\udcff", b"z", "b'z'"],
        [1.0, 2.0, 3.0, 4.0],
        {"a\\udcff": 3.0, "b'z'": 7.0},
        "keys 'a\\udcff', 'a\\\\udcff' share the name 'a\\\\udcff': recorded as one term, their "
        "sum; keys b'z', \"b'z'\" share the name \"b'z'\": recorded as one term, their sum",
    ),
]


@pytest.mark.parametrize(("keys", "values", "terms", "collided"), NAME_CASES)
def test_named_terms_name_every_key_by_one_rule_and_sum_the_names_that_collide(
    keys: list[Any], values: list[float], terms: dict[str, float], collided: str | None
) -> None:
    got, why = named_terms(keys, values)
    assert got == terms and list(got) == list(terms)  # first-seen order
    assert why == collided


def test_a_term_name_whose_str_raises_still_has_a_name() -> None:
    class Nameless:
        def __str__(self) -> str:
            raise RuntimeError("no")

    assert named_terms([Nameless()], [1.0]) == (
        {"<Nameless: str() raised RuntimeError>": 1.0},
        None,
    )


@pytest.mark.parametrize(
    "source", [["reward_a", b"reward_b"], ["reward_\udcff"], [1]], ids=["bytes", "surrogate", "int"]
)
def test_names_that_are_not_plain_text_are_left_to_extract(source: list[Any]) -> None:
    """names_for / extract_many give only names written as they are; the rest go through
    extract() and named_terms, the one rule for every path."""
    info = {key: 1.0 for key in [*source, "reward_a"]}
    terms = RewardTerms(source)
    assert terms.names_for(tuple(info)) is None
    assert terms.extract_many([info] * 2) is None
    assert terms.extract(info) == {key: 1.0 for key in source}


def classified(
    info: Any, rules: EndingRules | None = None, terminated: bool = True
) -> tuple[Ending, str | None, list[str]]:
    notes: list[str] = []
    ending, why = (rules or EndingRules()).classify_or_note(
        terminated, not terminated, info, time_limit_hit=False, notes=notes
    )
    return ending, why, notes


@pytest.mark.parametrize(
    ("info", "outcome", "note"),
    [
        ({"success": True}, "success", None),
        ({"is_success": np.float32(1.0)}, "success", None),
        (
            {"success": "no"},
            "success",
            "success_not_bool: info['success'] is 'no' (str): taken "
            "by its truth value as a success",
        ),
        (
            {"failure": 3},
            "failure",
            "failure_label_not_text: info['failure'] is 3 (int): "
            "recorded as unlabeled; give a string, or pass failure_fn",
        ),
        ({"success": [], "failure": 3}, "failure", None),  # both: two notes (below)
        ({"failure": True}, "failure", None),
    ],
)
def test_classify_or_note_hands_back_notes_and_classify_stays_as_it_was(
    info: dict[str, Any], outcome: str, note: str | None
) -> None:
    ending, why, notes = classified(info)
    assert why is None and ending.outcome == outcome
    assert ending == EndingRules().classify(True, False, info, time_limit_hit=False)
    if note is not None:
        assert notes == [note]
    elif "failure" in info and "success" in info:
        assert [n.partition(":")[0] for n in notes] == [
            "success_not_bool",
            "failure_label_not_text",
        ]
    else:
        assert notes == []
    # without notes=, as before: the same ending, nothing else
    assert EndingRules().classify_or_note(True, False, info, time_limit_hit=False) == (ending, None)


def test_notes_are_bounded_and_left_out_when_the_ending_is_unreadable() -> None:
    ending, why, notes = classified({"success": "x" * 10_000})
    assert ending.outcome == "success" and len(notes) == 1 and len(notes[0]) <= 300
    broken = EndingRules(success_fn=lambda info: "", failure_fn=lambda info: info["missing"])
    ending, why, notes = classified({}, broken)
    assert ending.failure_label == "unlabeled" and why == "KeyError: 'missing'"
    assert notes == []  # the ending is by the flags alone: nothing was read
    ending, why, notes = classified({"success": "no"}, terminated=False)
    assert ending.outcome == "truncated" and notes == []  # success is not read for truncations


@pytest.mark.parametrize(
    ("reason", "note"),
    [
        (
            3,
            "truncation_reason_not_text: info['truncation_reason'] is 3 (int): "
            "recorded as time_limit; give a string",
        ),
        (
            b"wall",
            "truncation_reason_not_text: info['truncation_reason'] is b'wall' (bytes): "
            "recorded as time_limit; give a string",
        ),
        (
            np.ones(2),
            "truncation_reason_not_text: info['truncation_reason'] is array([1., 1.]) "
            "(ndarray): recorded as time_limit; give a string",
        ),
        (None, None),
        ("", None),
        (False, None),
        (0, None),
        (True, None),  # "cut off", no reason: nothing lost
        (np.True_, None),
        ("wall", None),
    ],
)
@pytest.mark.parametrize("terminated", [False, True], ids=["truncated", "both_flags"])
def test_a_truncation_reason_that_is_not_text_is_noted_and_the_reason_stays_as_it_was(
    reason: Any, note: str | None, terminated: bool
) -> None:
    info = {"truncation_reason": reason, "success": True}
    notes: list[str] = []
    ending, why = EndingRules().classify_or_note(
        terminated, True, info, time_limit_hit=True, notes=notes
    )
    assert why is None
    assert ending == EndingRules().classify(terminated, True, info, time_limit_hit=True)
    assert ending.truncation_reason == (
        reason if isinstance(reason, str) and reason else "time_limit"
    )
    assert notes == ([] if note is None else [note])
    assert EndingRules().classify_or_note(terminated, True, info, time_limit_hit=True) == (
        ending,
        None,
    )


def _terms_fn(info: Any) -> dict[str, float]:
    return {"a": 1.0}


@pytest.mark.parametrize(
    "terms",
    [
        RewardTerms(),
        RewardTerms(None),
        RewardTerms(["reward_b", "reward_a"]),
        RewardTerms(("x",), {"alive": 1.0, "bonus": -0.5}),
        RewardTerms("auto", {"alive": 2}),
    ],
    ids=["auto", "none", "list", "list_constants", "auto_constants"],
)
def test_reward_terms_are_rebuilt_from_their_description(terms: RewardTerms) -> None:
    rebuilt = RewardTerms.from_description(terms.describe())
    assert rebuilt is not None
    assert rebuilt.describe() == terms.describe()
    info = {"reward_a": 1.0, "reward_b": 2.0, "x": 3.0, "reward_terms": None}
    assert rebuilt.extract(info) == terms.extract(info)


def test_reward_terms_from_a_callable_are_not_rebuilt() -> None:
    described = RewardTerms(_terms_fn).describe()
    assert described["source"] == "callable:_terms_fn"
    assert RewardTerms.from_description(described) is None


def test_reward_terms_described_without_a_source_are_auto() -> None:
    for description in (None, {}, {"constants": None}):
        assert RewardTerms.from_description(description) == RewardTerms()


@pytest.mark.parametrize(
    "rules",
    [
        EndingRules(),
        EndingRules(success_keys=("done", "won"), failure_key="why", truncation_reason_key="cut"),
        EndingRules(success_keys=()),
        EndingRules(success_keys=["is_success"]),
    ],
    ids=["default", "custom", "no_success_keys", "list"],
)
def test_ending_rules_are_rebuilt_from_their_description(rules: EndingRules) -> None:
    rebuilt = EndingRules.from_description(rules.describe())
    assert rebuilt is not None
    assert rebuilt.describe() == rules.describe()
    info = {"success": True, "won": True, "why": "fell", "failure": "slipped"}
    assert rebuilt.classify(True, False, info, time_limit_hit=False) == rules.classify(
        True, False, info, time_limit_hit=False
    )


@pytest.mark.parametrize(
    "rules",
    [
        EndingRules(success_fn=lambda info: True),
        EndingRules(failure_fn=lambda info: "fell"),
        EndingRules(success_fn=lambda info: True, failure_fn=lambda info: "fell"),
    ],
    ids=["success_fn", "failure_fn", "both"],
)
def test_ending_rules_with_a_callable_are_not_rebuilt(rules: EndingRules) -> None:
    assert EndingRules.from_description(rules.describe()) is None


def test_ending_rules_described_without_keys_take_the_defaults() -> None:
    for description in (None, {}, {"success_keys": None, "failure_key": None}):
        assert EndingRules.from_description(description) == EndingRules()


def test_reward_terms_from_a_description_refuse_a_constant_describe_never_gives() -> None:
    with pytest.raises(ConfigurationError, match="constant reward term 'a': expected a finite"):
        RewardTerms.from_description({"source": "auto", "constants": {"a": float("nan")}})
