"""The registry of recorded wrappers (format/wrappers.py) against the installed Gymnasium."""

from __future__ import annotations

import importlib
import inspect

import gymnasium as gym
import pytest

from episode_audit.format.wrappers import RECORDED_WRAPPERS, plan_wrappers

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
