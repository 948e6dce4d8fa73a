"""An env factory's env held to the recording's description (replay/mismatch.py).

The env kwargs one spec names and the other leaves at its default, the wrappers (their classes,
order and arguments) and the functions a spec holds only as placeholders: an env that differs
from the recording is ``not_replayable`` naming the difference, never ``diverged``; one that
matches replays identical.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from episode_audit import RecordEvidence, replay
from tests.support.hostile import rewrite

_AS_RECORDED = "; make the --env-factory build the env as recorded"
_MISMATCH = "the rebuilt env does not match the recording: "


class _Shaped(CartPoleEnv):
    """CartPole whose reward a function given to it reshapes; it takes any other argument too
    (``**kwargs``: no default of theirs to read)."""

    def __init__(
        self,
        reward_fn: Callable[[float], float] | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(render_mode=render_mode)
        self.reward_fn = reward_fn
        self.extra = kwargs

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        shaped = self.reward_fn(float(reward)) if self.reward_fn is not None else reward
        return obs, shaped, terminated, truncated, info


gym.register("EpisodeAuditShaped-v0", entry_point=_Shaped, max_episode_steps=8)
_SHAPED = f"{__name__}:_Shaped"


def _double(reward: float) -> float:
    return 2.0 * reward


def _triple(reward: float) -> float:
    return 3.0 * reward


def _record(path: Path, env: gym.Env[Any, Any], steps: int = 8) -> Path:
    """Two episodes (seeds 0 and 1) of ``steps`` random steps, or fewer where one ends."""
    with RecordEvidence(env, path) as rec:
        rec.action_space.seed(0)
        for seed in (0, 1):
            rec.reset(seed=seed)
            for _ in range(steps):
                _, _, terminated, truncated, _ = rec.step(rec.action_space.sample())
                if terminated or truncated:
                    break
    return path


def _verdicts(path: Path, factory: Callable[[], gym.Env[Any, Any]]) -> set[tuple[str, Any]]:
    return {(e.status, e.reason) for e in replay([path], env_factory=factory).episodes}


def _not_matching(said: str) -> set[tuple[str, Any]]:
    return {("not_replayable", f"{_MISMATCH}{said}{_AS_RECORDED}")}


def _pendulum(**kwargs: Any) -> gym.Env[Any, Any]:
    return gym.make("Pendulum-v1", max_episode_steps=8, **kwargs)


@pytest.mark.parametrize(
    ("recorded", "rebuilt", "said"),
    [
        (
            {"g": 5.0},
            {},
            "env kwarg 'g' 5.0 recorded vs 10.0 rebuilt (the rebuilt env's spec does not name "
            "it: its default)",
        ),
        (
            {},
            {"g": 5.0},
            "env kwarg 'g' 10.0 recorded vs 5.0 rebuilt (the recorded spec does not name it: its "
            "default)",
        ),
    ],
    ids=["factory-left-it-out", "factory-added-it"],
)
def test_a_kwarg_one_spec_leaves_at_another_default_is_named_not_diverged(
    tmp_path: Path, recorded: dict[str, Any], rebuilt: dict[str, Any], said: str
) -> None:
    """Pendulum's gravity: named by one spec only, the other's is its default (10.0)."""
    path = _record(tmp_path / "p.mcap", _pendulum(**recorded))
    assert _verdicts(path, lambda: _pendulum(**rebuilt)) == _not_matching(said)


@pytest.mark.parametrize(("recorded", "rebuilt"), [({}, {"g": 10.0}), ({"g": 10}, {})])
def test_a_kwarg_named_at_its_default_by_one_spec_only_matches(
    tmp_path: Path, recorded: dict[str, Any], rebuilt: dict[str, Any]
) -> None:
    path = _record(tmp_path / "p.mcap", _pendulum(**recorded))
    assert _verdicts(path, lambda: _pendulum(**rebuilt)) == {("identical", None)}


@pytest.mark.parametrize(
    ("recorded", "rebuilt", "said"),
    [
        (
            {"size": 3},
            {},
            "env kwarg 'size' 3 recorded, not named by the rebuilt env's spec and its default is "
            "unknown",
        ),
        (
            {},
            {"size": 3},
            "env kwarg 'size' not named by the recorded spec and its default is unknown, 3 rebuilt",
        ),
    ],
    ids=["factory-left-it-out", "factory-added-it"],
)
def test_a_kwarg_whose_default_cannot_be_read_does_not_match(
    tmp_path: Path, recorded: dict[str, Any], rebuilt: dict[str, Any], said: str
) -> None:
    """``size`` reaches the env through ``**kwargs``: what the other env has is unknown."""
    path = _record(tmp_path / "s.mcap", gym.make("EpisodeAuditShaped-v0", **recorded))
    factory = lambda: gym.make("EpisodeAuditShaped-v0", **rebuilt)  # noqa: E731
    assert _verdicts(path, factory) == _not_matching(said)


def test_a_function_kwarg_is_compared_by_what_the_file_holds_of_it(tmp_path: Path) -> None:
    """The file holds a function as its type and name: the same function matches (the kwarg
    is not read as an object's address), another does not."""
    path = _record(tmp_path / "s.mcap", gym.make("EpisodeAuditShaped-v0", reward_fn=_double))
    same = lambda: gym.make("EpisodeAuditShaped-v0", reward_fn=_double)  # noqa: E731
    assert _verdicts(path, same) == {("identical", None)}
    other = lambda: gym.make("EpisodeAuditShaped-v0", reward_fn=_triple)  # noqa: E731
    said = (
        f'env kwarg \'reward_fn\' {{"episode_audit.unrecorded": "function {__name__}:_double"}} '
        f'recorded vs {{"episode_audit.unrecorded": "function {__name__}:_triple"}} rebuilt'
    )
    assert _verdicts(path, other) == _not_matching(said)


def _skipped(skip: int) -> gym.Env[Any, Any]:
    return gym.wrappers.MaxAndSkipObservation(_pendulum(), skip=skip)


def test_a_wrapper_the_factory_changed_or_left_out_is_named_not_diverged(tmp_path: Path) -> None:
    path = _record(tmp_path / "skip.mcap", _skipped(4))
    assert _verdicts(path, lambda: _skipped(4)) == {("identical", None)}
    said = "MaxAndSkipObservation's argument 'skip' 4 recorded vs 2 rebuilt"
    assert _verdicts(path, lambda: _skipped(2)) == _not_matching(said)
    said = 'the innermost wrapper: "MaxAndSkipObservation" recorded vs none rebuilt'
    assert _verdicts(path, _pendulum) == _not_matching(said)


def _stacked(rescaled_first: bool) -> gym.Env[Any, Any]:
    """Pendulum's observations rescaled to [0, 1] and stacked (zeros before the first), in
    either order: rescaled after stacking, the padding is 0.5, not 0."""
    env = _pendulum()

    def stack(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
        return gym.wrappers.FrameStackObservation(env, 2, padding_type="zero")

    return stack(_rescaled(env)) if rescaled_first else _rescaled(stack(env))


def _rescaled(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    return gym.wrappers.RescaleObservation(env, np.float32(0.0), np.float32(1.0))


def test_wrappers_the_factory_reordered_are_named_not_diverged(
    tmp_path: Path,
) -> None:
    path = _record(tmp_path / "stack.mcap", _stacked(rescaled_first=True))
    assert _verdicts(path, lambda: _stacked(rescaled_first=True)) == {("identical", None)}
    said = 'the innermost wrapper: "RescaleObservation" recorded vs "FrameStackObservation" rebuilt'
    assert _verdicts(path, lambda: _stacked(rescaled_first=False)) == _not_matching(said)


def _doubled() -> gym.Env[Any, Any]:
    return gym.wrappers.TransformReward(_pendulum(), lambda r: 2 * r)


def _tripled() -> gym.Env[Any, Any]:
    return gym.wrappers.TransformReward(_pendulum(), lambda r: 3 * r)


def test_a_wrapper_given_another_function_is_named_not_diverged(tmp_path: Path) -> None:
    path = _record(tmp_path / "doubled.mcap", _doubled())
    assert _verdicts(path, _doubled) == {("identical", None)}
    said = (
        "TransformReward's argument 'func' {\"episode_audit.unrecorded\": \"function "
        f'{__name__}:_doubled.<locals>.<lambda>"}} recorded vs {{"episode_audit.unrecorded": '
        f'"function {__name__}:_tripled.<locals>.<lambda>"}} rebuilt'
    )
    assert _verdicts(path, _tripled) == _not_matching(said)


def test_a_script_s_own_function_matches_the_same_one_imported(tmp_path: Path) -> None:
    """A script run as ``__main__`` records its functions there; the factory imports them from
    the script's module."""
    path = _record(tmp_path / "doubled.mcap", _doubled())

    def from_a_script(meta: dict[str, str]) -> dict[str, str]:
        spec = json.loads(meta["env_spec"])
        (wrapper,) = spec["additional_wrappers"]
        wrapper["kwargs"]["func"]["episode_audit.unrecorded"] = (
            "function __main__:_doubled.<locals>.<lambda>"
        )
        return {**meta, "env_spec": json.dumps(spec)}

    script = rewrite(path, tmp_path / "script.mcap", run=from_a_script)
    assert _verdicts(script, _doubled) == {("identical", None)}
    said = (
        "TransformReward's argument 'func' {\"episode_audit.unrecorded\": \"function __main__:"
        '_doubled.<locals>.<lambda>"} recorded vs {"episode_audit.unrecorded": "function '
        f'{__name__}:_tripled.<locals>.<lambda>"}} rebuilt'
    )
    assert _verdicts(script, _tripled) == _not_matching(said)


def test_a_value_difference_is_said_before_one_between_functions(tmp_path: Path) -> None:
    """Both the function and the skip differ: the skip is named (the functions' names may
    differ with nothing else different)."""
    path = _record(tmp_path / "both.mcap", gym.wrappers.MaxAndSkipObservation(_doubled(), 4))
    both = lambda: gym.wrappers.MaxAndSkipObservation(_tripled(), 2)  # noqa: E731
    said = "MaxAndSkipObservation's argument 'skip' 4 recorded vs 2 rebuilt"
    assert _verdicts(path, both) == _not_matching(said)


class _Logger(gym.Wrapper[Any, Any, Any, Any]):
    """A user's wrapper that never changes a step (declared transparent when recorded)."""


def test_a_wrapper_that_never_changes_a_step_may_be_left_out(tmp_path: Path) -> None:
    path = tmp_path / "logged.mcap"
    with RecordEvidence(_Logger(_skipped(4)), path, transparent_wrappers=[_Logger]) as rec:
        rec.reset(seed=0)
        rec.step(rec.action_space.sample())
    assert _verdicts(path, lambda: _skipped(4)) == {("identical", None)}
    assert _verdicts(path, lambda: _Logger(_skipped(4))) == {("identical", None)}


# ----------------------------------------------- --trust-entry-points: the recorded wrappers


class _Shift(gym.ObservationWrapper[Any, Any, Any]):
    """Shifts observations by ``by``; it does not record its arguments (its spec's kwargs: null)."""

    def __init__(self, env: gym.Env[Any, Any], by: float = 0.0) -> None:
        super().__init__(env)
        self.by = by

    def observation(self, observation: Any) -> Any:
        return observation + np.float32(self.by)


class _Nudge(gym.ObservationWrapper[Any, Any, Any], gym.utils.RecordConstructorArgs):
    """Adds 0.25 to observations."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env)

    def observation(self, observation: Any) -> Any:
        return observation + np.float32(0.25)


class _Composite(gym.Wrapper[Any, Any, Any, Any], gym.utils.RecordConstructorArgs):
    """A wrapper that wraps the env in another of its own (as SB3's ``AtariWrapper`` does):
    the spec lists both, and rebuilding each entry applies the inner one twice."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(_Nudge(env))


def _trusted(path: Path) -> set[tuple[str, Any]]:
    return {(e.status, e.reason) for e in replay([path], trust_entry_points=True).episodes}


def test_a_trusted_wrapper_that_did_not_record_its_arguments_is_not_rebuilt_with_defaults(
    tmp_path: Path,
) -> None:
    # it was rebuilt with its defaults (by=0.0 where 0.5 was recorded), and replay said diverged
    path = _record(tmp_path / "shift.mcap", _Shift(gym.make("CartPole-v1"), by=0.5))
    assert _trusted(path) == {
        (
            "not_replayable",
            "the recorded wrapper _Shift did not record its arguments (it does not derive from "
            "gymnasium.utils.RecordConstructorArgs), so it cannot be rebuilt as recorded; pass "
            "--env-factory MODULE:CALLABLE that builds the env",
        )
    }


def test_a_wrapper_trust_would_refuse_is_not_told_to_be_trusted(tmp_path: Path) -> None:
    """A wrapper without recorded arguments is refused with --trust-entry-points too: replay
    does not suggest the flag, for a registered id or an unregistered one."""
    path = _record(tmp_path / "shift.mcap", _Shift(gym.make("CartPole-v1"), by=0.5))
    ((status, reason),) = {(e.status, e.reason) for e in replay([path]).episodes}
    assert status == "not_replayable" and "--trust-entry-points" not in reason, reason
    assert reason.endswith(
        "is not one replay knows; pass --env-factory MODULE:CALLABLE that builds the env"
    ), reason
    gym.register("Unregistered-v0", entry_point="gymnasium.envs.classic_control:CartPoleEnv")
    try:
        path = _record(tmp_path / "u.mcap", _Shift(gym.make("Unregistered-v0"), by=0.5))
    finally:
        del gym.registry["Unregistered-v0"]
    ((status, reason),) = {(e.status, e.reason) for e in replay([path]).episodes}
    assert reason == (
        "env id 'Unregistered-v0' is not registered in this process; pass --import MODULE that "
        "registers it, or --env-factory MODULE:CALLABLE"
    )


def test_a_trusted_wrapper_that_adds_its_own_wrappers_is_not_applied_twice_unnoticed(
    tmp_path: Path,
) -> None:
    # the spec lists _Nudge and _Composite; rebuilt entry by entry, _Nudge came twice: diverged
    path = _record(tmp_path / "composite.mcap", _Composite(gym.make("CartPole-v1")))
    ((status, reason),) = _trusted(path)
    assert status == "not_replayable"
    assert reason.startswith(
        f'{_MISMATCH}the wrapper over "_Nudge": "_Composite" recorded vs "_Nudge" rebuilt'
    ), reason
    assert reason.endswith("; pass --env-factory MODULE:CALLABLE that builds the env as recorded")
    factory = lambda: _Composite(gym.make("CartPole-v1"))  # noqa: E731 - the env as recorded
    assert {s for s, _ in _verdicts(path, factory)} == {"identical"}
