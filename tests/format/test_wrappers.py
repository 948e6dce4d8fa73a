"""The registry of recorded wrappers (format/wrappers.py) against the installed Gymnasium."""

from __future__ import annotations

import importlib
import inspect

import gymnasium as gym
import pytest

from episode_audit.format.wrappers import (
    RECORDED_WRAPPERS,
    plan_wrappers,
    unplaced_limits,
    worker_limits,
    worker_sub_envs,
)

_GYMNASIUM = {
    entry: rule
    for entry, rule in RECORDED_WRAPPERS.items()
    if entry.startswith("gymnasium.wrappers.")
}
_OPTIONAL = {"ArrayConversion", "JaxToNumpy", "JaxToTorch", "NumpyToTorch"}  # (jax / torch)
# wrappers newer than the oldest Gymnasium supported, and the release that added them
_ADDED = {
    **dict.fromkeys(
        [
            "AddWhiteNoise",
            "ArrayConversion",
            "DiscretizeAction",
            "DiscretizeObservation",
            "ObstructView",
        ],
        (1, 2),
    ),
    "RepeatAction": (1, 3),
}


def test_every_gymnasium_wrapper_is_classified_under_its_own_entry_point() -> None:
    """A wrapper a new Gymnasium adds, or one it moves, fails here (then classify it)."""
    names = {n for n in gym.wrappers.__all__ if n != "vector"}
    classified = {e.rpartition(":")[2] for e in _GYMNASIUM}
    assert names <= classified
    installed = tuple(int(part) for part in gym.__version__.split(".")[:2])
    not_here = classified - names  # only those a later Gymnasium added
    assert not_here == {n for n in not_here if installed < _ADDED.get(n, (0, 0))}
    for entry, rule in _GYMNASIUM.items():
        module, _, name = entry.partition(":")
        if name not in names:
            continue
        if name in _OPTIONAL:
            assert rule.kind == "refused"
            continue
        cls = getattr(gym.wrappers, name)
        assert cls.__module__ == module and issubclass(cls, gym.Wrapper)
        if rule.kind == "rebuilt":  # every argument it takes is checked, and only those
            taken = set(inspect.signature(cls.__init__).parameters) - {"self", "env"}
            assert set(rule.args) == taken, name


@pytest.mark.parametrize(
    ("kwargs", "ok"),
    [
        ({"min_action": -0.5, "max_action": [0.5, 1.0]}, True),
        ({"min_action": float("nan"), "max_action": 1.0}, False),
        ({"min_action": True, "max_action": 1.0}, False),
        ({"min_action": [0.0] * 4097, "max_action": 1.0}, False),
        ({"min_action": {"a": 1}, "max_action": 1.0}, False),
    ],
)
def test_rebuilt_arguments_are_plain_data_of_the_expected_type_and_size(
    kwargs: dict[str, object], ok: bool
) -> None:
    entry = "gymnasium.wrappers.transform_action:RescaleAction"
    plan = plan_wrappers([{"entry_point": entry, "kwargs": kwargs}])
    assert (plan.refused is None) == ok
    if not ok:
        assert plan.refused is not None
        assert plan.refused.startswith("the recorded wrapper RescaleAction's argument min_action")
    else:
        assert plan.rebuild == [("RescaleAction", kwargs)]


def test_vector_wrappers_that_change_no_step_are_those_of_the_installed_gymnasium() -> None:
    from episode_audit.format.wrappers import _VECTOR_STEP_SAFE, vector_wrapper_cause

    for entry in _VECTOR_STEP_SAFE:
        module, _, name = entry.partition(":")
        assert getattr(importlib.import_module(module), name).__module__ == module
        assert vector_wrapper_cause(entry) is None
    cause = vector_wrapper_cause("gymnasium.wrappers.vector:RescaleAction")
    assert cause is not None and cause.startswith("the recorder wrapped the vector wrapper")


_SKIP = {"entry_point": "gymnasium.wrappers.stateful_observation:MaxAndSkipObservation"}


@pytest.mark.parametrize(
    ("text", "cause", "workers"),
    [
        ("the sub-envs ran in Remote workers, whose wrapper chains ...", "workers", True),
        ("any other wording of the same cause", "workers", True),
        ("the sub-envs ran in workers, a later text of the zeroed count", "zeroed", False),
        ("a sub-env's TimeLimit under MaxAndSkipObservation counts ...", "zeroed", False),
    ],
)
def test_the_layout_cause_code_says_whether_sub_envs_ran_in_workers(
    text: str, cause: str, workers: bool
) -> None:
    """The layout's ``unread_time_limits_cause`` decides, whatever its text says."""
    layout = {"kind": "vector", "vector_class": "SyncVectorEnv", "unread_time_limits": text}
    layout["unread_time_limits_cause"] = cause
    assert worker_sub_envs(layout) == (text if workers else None)
    assert (unplaced_limits({"additional_wrappers": [_SKIP]}, layout) is not None) is workers


def test_a_coded_worker_file_is_said_by_its_vector_class_not_cut_from_its_text() -> None:
    layout = {
        "kind": "vector",
        "vector_class": "SubprocVecEnv",
        "unread_time_limits": "the sub-envs ran in workers: reworded; record otherwise",
        "unread_time_limits_cause": "workers",
    }
    said = unplaced_limits({"additional_wrappers": [_SKIP]}, layout)
    assert said is not None
    assert said.startswith(
        "the sub-envs ran in SubprocVecEnv workers, whose wrapper chains the recorder cannot "
        "walk, and its spec holds MaxAndSkipObservation"
    )
    assert said.endswith("builds the sub-env as recorded, or record with DummyVecEnv")


@pytest.mark.parametrize(
    ("layout", "workers"),
    [
        ({"kind": "vector", "vector_class": "AsyncVectorEnv"}, True),
        ({"kind": "vector", "vector_class": "SyncVectorEnv"}, False),
        (
            {
                "kind": "vector",
                "vector_class": "Remote",
                "unread_time_limits": worker_limits("Remote"),
            },
            True,
        ),
        (
            {
                "kind": "vector",
                "vector_class": "SyncVectorEnv",
                "unread_time_limits": "a sub-env's TimeLimit under MaxAndSkipObservation ...",
            },
            False,
        ),
    ],
    ids=["async", "sync", "custom-workers", "zeroed"],
)
def test_a_file_without_the_cause_code_is_read_by_its_text(
    layout: dict[str, str], workers: bool
) -> None:
    """Files recorded before the cause code: the text's first clause, else the vector class."""
    said = worker_sub_envs(layout)
    assert (said is not None) is workers
    placed = unplaced_limits({"additional_wrappers": [_SKIP]}, layout)
    if workers:
        name = layout["vector_class"]
        instead = {"AsyncVectorEnv": "SyncVectorEnv"}.get(name, "sub-envs in this process")
        assert placed is not None
        assert placed.startswith(f"the sub-envs ran in {name} workers, whose wrapper chains")
        assert placed.endswith(f"or record with {instead}")
    else:
        assert placed is None
