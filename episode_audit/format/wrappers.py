"""The wrappers a file's env spec names, and what replay does with each (docs/security.md, rule 2).

One registry (:data:`RECORDED_WRAPPERS`, by entry point) classifies every wrapper replay knows:
``rebuilt`` (no state beyond an episode, no side effect: re-applied, each argument checked to be
plain data of the expected type and size), ``snapshot`` (rebuilt so, and its state across
episodes restored from the snapshot each episode's reset row holds: ``record/state.py``),
``transparent`` (never changes a step: left out, saying so), ``stateful`` (keeps state across
episodes that the file does not hold: not replayable) or ``refused`` (takes callables, converts
through an optional array library). Any other wrapper is unknown, refused too. Nothing here
imports what a file names: a wrapper is rebuilt only from ``gymnasium.wrappers`` by a name in
the registry. :func:`plan_wrappers` reads a spec's ``additional_wrappers`` into a
:class:`WrapperPlan`; ``--trust-entry-points`` bypasses all of this (the spec as recorded).
:func:`state_causes` says, from a file's run metadata alone, what makes the state its episodes
began in unrestorable (the recorder warns of the same at construction; ``check`` and replay
report it). :func:`reward_wrapper_names` names the reward-changing wrappers a recorder sat over
(:data:`LAYOUT_REWARD_WRAPPERS`); :data:`RUN_TRANSPARENT_WRAPPERS` holds the wrappers a user
declared transparent, which replay leaves out as it does the registry's.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .unrecorded import unrecorded

__all__ = [
    "LAYOUT_REWARD_WRAPPERS",
    "LAYOUT_STATE_SNAPSHOTS",
    "LAYOUT_UNREAD_CAUSE",
    "LAYOUT_UNSAVED_STATE",
    "LAYOUT_UNREAD_LIMITS",
    "LAYOUT_VECTOR_WRAPPERS",
    "MULTI_STEP_WRAPPERS",
    "RECORDED_WRAPPERS",
    "REWARD_CHANGING",
    "RUN_TRANSPARENT_WRAPPERS",
    "UNREAD_IN_WORKERS",
    "UNREAD_ZEROED",
    "WrapperKind",
    "WrapperPlan",
    "WrapperRule",
    "autoreset_wrapped",
    "declared_transparent",
    "limits_text",
    "multi_step",
    "placed_limits",
    "plan_wrappers",
    "reward_wrapper_names",
    "reward_wrapper_setups",
    "state_causes",
    "stateful_wrapper",
    "unplaced_limits",
    "unread_limits",
    "unsaved_state",
    "vector_wrapper_cause",
    "worker_limits",
    "worker_sub_envs",
]

WrapperKind = Literal["rebuilt", "snapshot", "transparent", "stateful", "refused"]

Check = Callable[[Any], str | None]
"""What is wrong with an argument's value (``None``: nothing), said as "expected …"."""

_MAX_ITEMS = 4096
_MAX_TEXT = 256


def _real(value: Any) -> bool:
    return type(value) in (int, float) and math.isfinite(value)


def _int(low: int, high: int) -> Check:
    def check(value: Any) -> str | None:
        if type(value) is int and low <= value <= high:
            return None
        return f"an int from {low} to {high}"

    return check


def _ints(low: int, high: int, most: int) -> Check:
    """An int, or a list of at most ``most`` of them, each from ``low`` to ``high``."""
    one = _int(low, high)

    def check(value: Any) -> str | None:
        items = value if isinstance(value, list) and 0 < len(value) <= most else [value]
        if all(one(v) is None for v in items):
            return None
        return f"an int from {low} to {high}, or a list of at most {most}"

    return check


def _numbers(optional: bool = False) -> Check:
    """A finite number, or a list of at most 4096 (``optional``: or None)."""

    def check(value: Any) -> str | None:
        if optional and value is None:
            return None
        items = value if isinstance(value, list) and 0 < len(value) <= _MAX_ITEMS else [value]
        if all(_real(v) for v in items):
            return None
        return f"a finite number or a list of at most {_MAX_ITEMS}" + (", or null" * optional)

    return check


def _probability(value: Any) -> str | None:
    return None if _real(value) and 0 <= value <= 1 else "a number from 0 to 1"


def _positive(value: Any) -> str | None:
    return None if _real(value) and value > 0 else "a finite number > 0"


def _bool(value: Any) -> str | None:
    return None if type(value) is bool else "true or false"


def _text(*choices: str) -> Check:
    """A short string (``choices``: one of them)."""

    def check(value: Any) -> str | None:
        if choices:
            return None if value in choices else f"one of {', '.join(map(repr, choices))}"
        if isinstance(value, str) and 0 < len(value) <= _MAX_TEXT:
            return None
        return f"a string of 1 to {_MAX_TEXT} characters"

    return check


def _keys(value: Any) -> str | None:
    ok = isinstance(value, list) and 0 < len(value) <= _MAX_ITEMS
    if ok and all(_text()(k) is None or _int(-(2**31), 2**31)(k) is None for k in value):
        return None
    return f"a list of at most {_MAX_ITEMS} keys (short strings or ints)"


_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64"}
    | {"float16", "float32", "float64"}
)
_LARGE = 2**31 - 1
_SIZE = _ints(1, 4096, 2)  # a screen size: one side, or both


@dataclass(frozen=True)
class WrapperRule:
    """What replay does with one recorded wrapper.

    ``args``: for a ``rebuilt`` (or ``snapshot``) wrapper, each argument it may be given and
    its check (an argument not listed is refused); ``why``: for the others, the reason in words.
    ``renders``: it calls ``render()`` inside a step (left out, it no longer does);
    ``render_bound``: a rebuilt wrapper whose step depends on those calls; ``tuples``: the
    arguments it needs as a tuple where given a sequence (a file holds a list); ``dtypes``:
    the arguments it needs as a numpy scalar type where the file holds its name (Gymnasium
    1.1's ``DtypeObservation`` calls its ``dtype`` on each observation).
    """

    kind: WrapperKind
    args: Mapping[str, Check] = field(default_factory=dict)
    why: str = ""
    renders: bool = False
    render_bound: bool = False
    tuples: frozenset[str] = frozenset()
    dtypes: frozenset[str] = frozenset()

    def built(self, kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
        """Recorded (checked) ``kwargs`` as the wrapper is built.

        :attr:`tuples` as tuples, :attr:`dtypes` as numpy scalar types.

        >>> RECORDED_WRAPPERS["gymnasium.wrappers:ReshapeObservation"].built({"shape": [3, 1]})
        {'shape': (3, 1)}
        >>> RECORDED_WRAPPERS["gymnasium.wrappers:DtypeObservation"].built({"dtype": "float32"})
        {'dtype': <class 'numpy.float32'>}
        """
        out = dict(kwargs or {})
        for k, v in out.items():
            if k in self.tuples and isinstance(v, list):
                out[k] = tuple(v)
            elif k in self.dtypes and isinstance(v, str):
                out[k] = np.dtype(v).type
        return out


def _rebuilt(
    render_bound: bool = False,
    *,
    tuples: Collection[str] = (),
    dtypes: Collection[str] = (),
    **args: Check,
) -> WrapperRule:
    return WrapperRule(
        "rebuilt",
        args,
        render_bound=render_bound,
        tuples=frozenset(tuples),
        dtypes=frozenset(dtypes),
    )


_NO_STEP = "it never changes a step"
_CALLABLE = "its argument {} is a function, which a file cannot hold"
_CONVERTS = "it converts arrays through an optional library (jax / torch) the file names"
_STATS = "it keeps running statistics across episodes, which the file does not hold"
_GYMNASIUM_WRAPPERS: dict[str, tuple[str, WrapperRule]] = {
    # module in gymnasium.wrappers, rule; by class name (Gymnasium 1.x)
    "TimeLimit": ("common", _rebuilt(max_episode_steps=_int(1, _LARGE))),
    # (right under a recorder, its resets inside a step are recorded as episodes; deeper, they
    # are steps after an episode's end, which check names: autoreset_wrapped)
    "Autoreset": ("common", _rebuilt()),
    "RecordEpisodeStatistics": (
        "common",
        _rebuilt(buffer_length=_int(1, 1_000_000), stats_key=_text()),
    ),
    "OrderEnforcing": ("common", WrapperRule("transparent", why=_NO_STEP)),
    "PassiveEnvChecker": ("common", WrapperRule("transparent", why=_NO_STEP)),
    "FlattenObservation": ("transform_observation", _rebuilt()),
    "FilterObservation": ("transform_observation", _rebuilt(filter_keys=_keys)),
    "GrayscaleObservation": ("transform_observation", _rebuilt(keep_dim=_bool)),
    "ResizeObservation": ("transform_observation", _rebuilt(tuples={"shape"}, shape=_SIZE)),
    "ReshapeObservation": (
        "transform_observation",
        _rebuilt(tuples={"shape"}, shape=_ints(1, _LARGE, 32)),
    ),
    "RescaleObservation": (
        "transform_observation",
        _rebuilt(min_obs=_numbers(), max_obs=_numbers()),
    ),
    "DtypeObservation": (
        "transform_observation",
        _rebuilt(dtypes={"dtype"}, dtype=_text(*sorted(_DTYPES))),
    ),
    "DiscretizeObservation": (
        "transform_observation",
        _rebuilt(bins=_ints(1, 1_000_000, _MAX_ITEMS), multidiscrete=_bool),
    ),
    "AddRenderObservation": (
        "transform_observation",
        _rebuilt(True, render_only=_bool, render_key=_text(), obs_key=_text()),
    ),
    "TransformObservation": (
        "transform_observation",
        WrapperRule("refused", why=_CALLABLE.format("func")),
    ),
    "ClipAction": ("transform_action", _rebuilt()),
    "RescaleAction": (
        "transform_action",
        _rebuilt(min_action=_numbers(), max_action=_numbers()),
    ),
    "DiscretizeAction": (
        "transform_action",
        _rebuilt(bins=_ints(1, 1_000_000, _MAX_ITEMS), multidiscrete=_bool),
    ),
    "TransformAction": ("transform_action", WrapperRule("refused", why=_CALLABLE.format("func"))),
    "ClipReward": (
        "transform_reward",
        _rebuilt(min_reward=_numbers(optional=True), max_reward=_numbers(optional=True)),
    ),
    "TransformReward": ("transform_reward", WrapperRule("refused", why=_CALLABLE.format("func"))),
    "DelayObservation": ("stateful_observation", _rebuilt(delay=_int(0, 10_000))),
    "FrameStackObservation": (
        "stateful_observation",
        _rebuilt(stack_size=_int(1, 10_000), padding_type=_text("reset", "zero")),
    ),
    "TimeAwareObservation": (
        "stateful_observation",
        _rebuilt(flatten=_bool, normalize_time=_bool, dict_time_key=_text()),
    ),
    "MaxAndSkipObservation": ("stateful_observation", _rebuilt(skip=_int(1, 1_000))),
    "NormalizeObservation": (
        "stateful_observation",
        WrapperRule("snapshot", {"epsilon": _positive}, why=_STATS),
    ),
    "StickyAction": (
        "stateful_action",
        _rebuilt(
            tuples={"repeat_action_duration"},
            repeat_action_probability=_probability,
            repeat_action_duration=_ints(1, 10_000, 2),
        ),
    ),
    "RepeatAction": ("stateful_action", _rebuilt(num_repeats=_int(1, 1_000))),
    "NormalizeReward": (
        "stateful_reward",
        WrapperRule("snapshot", {"gamma": _probability, "epsilon": _positive}, why=_STATS),
    ),
    "AtariPreprocessing": (
        "atari_preprocessing",
        _rebuilt(
            tuples={"screen_size"},
            noop_max=_int(0, 10_000),
            frame_skip=_int(1, 1_000),
            screen_size=_SIZE,
            terminal_on_life_loss=_bool,
            grayscale_obs=_bool,
            grayscale_newaxis=_bool,
            scale_obs=_bool,
        ),
    ),
    # render() only; they draw from the env's RNG there, so a step depends on who renders
    "AddWhiteNoise": (
        "rendering",
        _rebuilt(
            True,
            probability_of_noise_per_pixel=_probability,
            is_noise_grayscale=_bool,
        ),
    ),
    "ObstructView": (
        "rendering",
        _rebuilt(
            True,
            obstructed_pixels_ratio=_probability,
            obstruction_width=_int(1, 100_000),
            is_noise_grayscale=_bool,
        ),
    ),
    # they write files / open a window / keep every frame when built, and never change a step
    "RecordVideo": ("rendering", WrapperRule("transparent", why=_NO_STEP, renders=True)),
    "HumanRendering": ("rendering", WrapperRule("transparent", why=_NO_STEP, renders=True)),
    "RenderCollection": ("rendering", WrapperRule("transparent", why=_NO_STEP, renders=True)),
    "ArrayConversion": ("array_conversion", WrapperRule("refused", why=_CONVERTS)),
    "JaxToNumpy": ("jax_to_numpy", WrapperRule("refused", why=_CONVERTS)),
    "JaxToTorch": ("jax_to_torch", WrapperRule("refused", why=_CONVERTS)),
    "NumpyToTorch": ("numpy_to_torch", WrapperRule("refused", why=_CONVERTS)),
}

RECORDED_WRAPPERS: Mapping[str, WrapperRule] = {
    **{
        f"gymnasium.wrappers.{module}:{name}": rule
        for name, (module, rule) in _GYMNASIUM_WRAPPERS.items()
    },
    **{f"gymnasium.wrappers:{name}": rule for name, (_, rule) in _GYMNASIUM_WRAPPERS.items()},
    # Stable-Baselines3's episode statistics (it writes a CSV file when built with one)
    "stable_baselines3.common.monitor:Monitor": WrapperRule("transparent", why=_NO_STEP),
}
"""Every wrapper replay knows, by the entry point a spec names it with."""


_MULTI_STEP = (
    "MaxAndSkipObservation",  # its step: `skip` steps of the env
    "AtariPreprocessing",  # `frame_skip` steps; no-op steps in its reset
    "RepeatAction",  # `num_repeats` steps
    "Autoreset",  # a reset inside a step
)
MULTI_STEP_WRAPPERS: frozenset[str] = frozenset(
    {f"gymnasium.wrappers.{_GYMNASIUM_WRAPPERS[name][0]}:{name}" for name in _MULTI_STEP}
    | {f"gymnasium.wrappers:{name}" for name in _MULTI_STEP}
    | {
        f"stable_baselines3.common.atari_wrappers:{name}"
        # frame skipping; no-op or FIRE steps in reset; a life's end without the env's reset
        for name in ("MaxAndSkipEnv", "NoopResetEnv", "FireResetEnv", "EpisodicLifeEnv")
    }
)
"""The wrappers (by entry point) whose step or reset is not one step or reset of the env below.

A ``TimeLimit`` under one counts the env's own steps, one over it the wrapper's: the two are
not one limit (``record/time_limits.py`` keeps each where it is). Any other wrapper is taken to
step the env once per step.
"""


def multi_step(entry_point: str) -> bool:
    """Whether the wrapper of ``entry_point`` steps or resets the env below otherwise than once.

    >>> multi_step("gymnasium.wrappers.stateful_observation:MaxAndSkipObservation")
    True
    >>> multi_step("gymnasium.wrappers.transform_observation:FlattenObservation")
    False
    """
    return entry_point in MULTI_STEP_WRAPPERS


_TIME_LIMITS = frozenset({"gymnasium.wrappers.common:TimeLimit", "gymnasium.wrappers:TimeLimit"})


def placed_limits(env_spec: Any) -> list[Any]:
    """The limits of the ``TimeLimit``s a recorded spec holds among its wrappers, innermost first.

    The recorder puts one there when it sat over a multi-step wrapper (the spec's
    ``max_episode_steps`` is the limit of those under none: ``record/time_limits.py``).

    >>> skip = {"entry_point": "gymnasium.wrappers.stateful_observation:MaxAndSkipObservation"}
    >>> limit = {"entry_point": "gymnasium.wrappers.common:TimeLimit",
    ...          "kwargs": {"max_episode_steps": 30}}
    >>> placed_limits({"max_episode_steps": 200, "additional_wrappers": [skip, limit]})
    [30]
    """
    wrappers = env_spec.get("additional_wrappers") if isinstance(env_spec, Mapping) else None
    return [
        w["kwargs"].get("max_episode_steps") if isinstance(w.get("kwargs"), Mapping) else None
        for w in _listed(wrappers)
        if isinstance(w, Mapping) and w.get("entry_point") in _TIME_LIMITS
    ]


def limits_text(env_spec: Any) -> str:
    """A recorded spec's time limits in words: its ``max_episode_steps``, and those placed.

    >>> limits_text({"max_episode_steps": 500})
    '500'
    >>> skip = {"entry_point": "gymnasium.wrappers:MaxAndSkipObservation"}
    >>> limit = {"entry_point": "gymnasium.wrappers:TimeLimit", "kwargs": {"max_episode_steps": 9}}
    >>> limits_text({"max_episode_steps": None, "additional_wrappers": [skip, limit]})
    'None (over a multi-step wrapper: 9)'
    """
    limit = env_spec.get("max_episode_steps") if isinstance(env_spec, Mapping) else None
    placed = placed_limits(env_spec)
    over = f" (over a multi-step wrapper: {', '.join(map(str, placed))})" if placed else ""
    return f"{limit}{over}"


_AUTORESET = frozenset({"gymnasium.wrappers.common:Autoreset", "gymnasium.wrappers:Autoreset"})


def autoreset_wrapped(spec: Any) -> bool:
    """Whether a recorded env spec's wrappers hold Gymnasium's ``Autoreset``.

    It resets the env inside the step after an episode's end: a recorder it was not right
    under recorded the episodes after as steps after the end.

    >>> wrappers = [{"entry_point": "gymnasium.wrappers.common:Autoreset", "kwargs": {}}]
    >>> autoreset_wrapped({"additional_wrappers": wrappers}), autoreset_wrapped({})
    (True, False)
    """
    wrappers = spec.get("additional_wrappers") if isinstance(spec, Mapping) else None
    return isinstance(wrappers, list) and any(
        isinstance(w, Mapping) and w.get("entry_point") in _AUTORESET for w in wrappers
    )


@dataclass
class WrapperPlan:
    """What replay does with a spec's recorded wrappers, innermost first.

    ``rebuild``: the ``gymnasium.wrappers`` class names to re-apply, with their kwargs;
    ``notes``: what was left out, and why; ``refused``: why the env cannot be rebuilt
    (``None``: it can).
    """

    rebuild: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    refused: str | None = None


_FACTORY_ONLY = "pass --env-factory MODULE:CALLABLE that builds the env"
_WAY_AROUND = f"{_FACTORY_ONLY}, or --trust-entry-points to build the recorded wrappers as they are"


def _holds_placeholder(wrapper: Any) -> bool:
    """Whether a recorded wrapper has an argument the file holds only a placeholder of."""
    kwargs = wrapper.get("kwargs") if isinstance(wrapper, Mapping) else None
    return isinstance(kwargs, Mapping) and any(unrecorded(v) is not None for v in kwargs.values())


def unrecorded_arguments(recorded: Sequence[Any], transparent: Collection[str] = ()) -> str | None:
    """The class name of the first recorded wrapper whose arguments the spec lacks, or ``None``.

    A wrapper not deriving from ``gymnasium.utils.RecordConstructorArgs`` (SB3's
    ``AtariWrapper``, one of one's own) is in the spec with ``kwargs`` null: rebuilt with its
    defaults it may be another env, so ``--trust-entry-points`` refuses it. Wrappers that never
    change a step (the registry's ``transparent``, or declared so: ``transparent``) are left
    aside.
    """
    for wrapper in recorded:
        if not isinstance(wrapper, Mapping) or wrapper.get("kwargs") is not None:
            continue
        entry = str(wrapper.get("entry_point"))
        rule = RECORDED_WRAPPERS.get(entry)
        if not (rule.kind == "transparent" if rule else entry in transparent):
            return entry.rpartition(":")[2][:80]
    return None


def plan_wrappers(recorded: Sequence[Any], transparent: Collection[str] = ()) -> WrapperPlan:
    """What to do with a spec's ``additional_wrappers`` (see :data:`RECORDED_WRAPPERS`).

    ``transparent``: entry points the recording declared transparent (never changing a step,
    :data:`RUN_TRANSPARENT_WRAPPERS`); they are left out, saying so, unless the registry
    knows them (its rule wins: a file cannot make a wrapper it knows transparent).
    """
    plan = WrapperPlan()
    renders: list[str] = []  # left out, though they call render() in a step
    bound: list[str] = []  # rebuilt, whose step depends on those calls
    for wrapper in recorded:
        entry = str(wrapper.get("entry_point")) if isinstance(wrapper, Mapping) else repr(wrapper)
        rule = RECORDED_WRAPPERS.get(entry)
        name = entry.rpartition(":")[2]
        if rule is None and entry in transparent:
            plan.notes.append(
                f"replayed without the recorded wrapper {name[:80]}: the recording declared it "
                "transparent (it never changes a step; a step it did change diverges)"
            )
        elif rule is None:
            plan.refused = f"the recorded wrapper {entry[:200]!r} is not one replay knows"
        elif rule.kind == "transparent":
            plan.notes.append(f"replayed without the recorded wrapper {name}: {rule.why}")
            renders += [name] if rule.renders else []
        elif rule.kind not in ("rebuilt", "snapshot"):
            plan.refused = f"the recorded wrapper {name}: {rule.why}"
        else:
            assert isinstance(wrapper, Mapping)
            plan.refused = _bad_argument(name, rule, wrapper.get("kwargs"))
            if plan.refused is None:
                plan.rebuild.append((name, rule.built(wrapper.get("kwargs"))))
                bound += [name] if rule.render_bound else []
        if plan.refused is not None:
            if _holds_placeholder(wrapper):  # trusted, replay refuses it too
                plan.refused += f"; {_FACTORY_ONLY}"
                return plan
            break
    if plan.refused is None and renders and bound:
        plan.refused = (
            f"the recorded wrapper {bound[0]} depends on the render() calls the recorded "
            f"{renders[0]} made in each step, and replay leaves {renders[0]} out (it has side "
            "effects)"
        )
    if plan.refused is not None:  # (--trust-entry-points only where it would not be refused)
        untrusted = unrecorded_arguments(recorded, transparent) is not None
        plan.refused += f"; {_FACTORY_ONLY if untrusted else _WAY_AROUND}"
    return plan


def _bad_argument(name: str, rule: WrapperRule, kwargs: Any) -> str | None:
    """What is wrong with a rebuilt wrapper's recorded kwargs, naming the argument."""
    if kwargs is None:
        return None
    if not isinstance(kwargs, Mapping):
        return f"the recorded wrapper {name}'s kwargs are not a mapping"
    for arg, value in kwargs.items():
        held = unrecorded(value)
        if held is not None:
            arg = str(arg)[:80]
            return (
                f"the recorded wrapper {name}'s argument {arg!r} is not in the file ({held}: "
                "JSON cannot hold it)"
            )
        check = rule.args.get(arg)
        if check is None:
            arg = str(arg)[:80]
            return f"the recorded wrapper {name} has an argument {arg!r} replay does not know"
        expected = check(value)
        if expected is not None:
            shown = repr(value)
            shown = shown if len(shown) <= 80 else shown[:77] + "..."
            return f"the recorded wrapper {name}'s argument {arg}: expected {expected}, got {shown}"
    return None


LAYOUT_STATE_SNAPSHOTS = "state_snapshots"
"""Layout key: ``true`` when every reset row holds a state snapshot (``format/state.py``), so a
``snapshot`` wrapper's state is restored (absent otherwise)."""
LAYOUT_UNSAVED_STATE = "unsaved_state"
"""Layout key of a vector file whose sub-env's own env keeps state a seed does not set (a state
adapter is registered for it: ALE's ``AtariEnv``) that no ``ResetRngInfo`` snapshot: ``{"env":
its class name, "adapter": the adapter's name, "needed": "unseeded" or "always"}`` (absent
otherwise). Read by :func:`unsaved_state`."""


def unsaved_state(layout: Any) -> tuple[str, bool] | None:
    """Why a vector file's sub-envs' own state is not in it, and whether every episode needs it.

    From the layout's :data:`LAYOUT_UNSAVED_STATE`: ``(why, always)``; ``always`` false when
    only the episodes an unseeded reset began need it (a seeded reset sets it anew). ``None``
    when the layout names none.

    >>> unsaved_state({"unsaved_state": {"env": "AtariEnv", "adapter": "ale_py.AtariEnv",
    ...     "needed": "unseeded"}})[0][:60]
    "the sub-envs' AtariEnv keeps state a seed does not set (ale_"
    """
    entry = layout.get(LAYOUT_UNSAVED_STATE) if isinstance(layout, Mapping) else None
    if not isinstance(entry, Mapping) or entry.get("needed") not in ("unseeded", "always"):
        return None
    env, adapter = (str(entry.get(k))[:80] for k in ("env", "adapter"))
    return (
        f"the sub-envs' {env} keeps state a seed does not set ({adapter}), and no ResetRngInfo "
        "in them snapshot it: wrap each sub-env in episode_audit.ResetRngInfo (outermost; in "
        "the env function, or make_vec_env(..., wrapper_class=ResetRngInfo))",
        entry.get("needed") == "always",
    )


LAYOUT_VECTOR_WRAPPERS = "vector_wrappers"
"""The layout key of a vector file's vector wrappers under the recorder (entry points, innermost
first; absent in files that predate it, and when there were none)."""


LAYOUT_UNREAD_LIMITS = "unread_time_limits"
"""Layout key of a vector file: why its recorder could not read every sub-env's ``TimeLimit``
at an episode's end (text; absent when it could). Its truncations by one it did not read are
``external``; replay does not call what such a limit explains a divergence
(:func:`unread_limits`)."""
LAYOUT_UNREAD_CAUSE = "unread_time_limits_cause"
"""Layout key beside :data:`LAYOUT_UNREAD_LIMITS`: its cause, :data:`UNREAD_IN_WORKERS` or
:data:`UNREAD_ZEROED` (absent in files recorded before it was written: the text says)."""
UNREAD_IN_WORKERS = "workers"
"""The sub-envs ran in worker processes (:func:`worker_limits`)."""
UNREAD_ZEROED = "zeroed"
"""A reset inside the step zeroed the count of a ``TimeLimit`` under a frame skip."""

_WORKERS = {"AsyncVectorEnv": "SyncVectorEnv", "SubprocVecEnv": "DummyVecEnv"}
_IN_WORKERS = "the sub-envs ran in "
_TO_REPLAY = " to replay such endings"


def worker_limits(vector_class: str) -> str:
    """Why a vector recorder could not read the ``TimeLimit``s of sub-envs in worker processes.

    >>> worker_limits("SubprocVecEnv")[:60]
    'the sub-envs ran in SubprocVecEnv workers, whose wrapper cha'
    """
    return (
        f"{_in_workers(vector_class)}: it read the outermost TimeLimit's limit only (one inside "
        "it, or under a frame-skipping wrapper, it did not); "
        f"{_record_locally(vector_class)}{_TO_REPLAY}"
    )


def _in_workers(vector_class: str) -> str:
    """Where the sub-envs of ``vector_class`` ran (:func:`worker_limits`'s first clause)."""
    return (
        f"{_IN_WORKERS}{vector_class[:80]} workers, whose wrapper chains the recorder cannot walk"
    )


def _record_locally(vector_class: str) -> str:
    """How to record the sub-envs of ``vector_class`` so that their limits are read."""
    return f"record with {_WORKERS.get(vector_class, 'sub-envs in this process')}"


def unread_limits(layout: Any) -> str | None:
    """Why a file's recorder could not read every ``TimeLimit`` of its sub-envs, or ``None``.

    The layout's :data:`LAYOUT_UNREAD_LIMITS`; in a vector file without it (one recorded before
    it was written), :func:`worker_limits` when its sub-envs ran in ``AsyncVectorEnv`` or
    ``SubprocVecEnv`` workers.

    >>> unread_limits({"kind": "vector", "vector_class": "SyncVectorEnv"}) is None
    True
    """
    if not isinstance(layout, Mapping):
        return None
    said = layout.get(LAYOUT_UNREAD_LIMITS)
    if isinstance(said, str) and said:
        return said[: _MAX_TEXT * 2]
    vector_class = layout.get("vector_class")
    if layout.get("kind") == "vector" and vector_class in _WORKERS:
        return worker_limits(str(vector_class))
    return None


def worker_sub_envs(layout: Any) -> str | None:
    """Why a file's spec may not hold its sub-envs' ``TimeLimit``s as they were, or ``None``.

    Its sub-envs ran in ``AsyncVectorEnv`` / ``SubprocVecEnv`` workers (:func:`worker_limits`):
    the spec is Gymnasium's, whose ``max_episode_steps`` is the outermost ``TimeLimit``'s
    limit, wherever it sat, and which names no other. (A ``SAME_STEP`` sub-env's unread limits
    are placed in its spec: not this.) The layout's :data:`LAYOUT_UNREAD_CAUSE` says; a file
    without it: the text of :data:`LAYOUT_UNREAD_LIMITS`, else its ``vector_class``.

    >>> worker_sub_envs({"kind": "vector", "vector_class": "SubprocVecEnv"})[:33]
    'the sub-envs ran in SubprocVecEnv'
    >>> worker_sub_envs({"kind": "vector", "vector_class": "SyncVectorEnv"}) is None
    True
    >>> worker_sub_envs({"unread_time_limits": "why", "unread_time_limits_cause": "workers"})
    'why'
    """
    why = unread_limits(layout)
    if why is None:
        return None
    cause = layout.get(LAYOUT_UNREAD_CAUSE)
    if not isinstance(cause, str):  # (a file recorded before the cause was written)
        return why if why.startswith(_IN_WORKERS) else None
    return why if cause == UNREAD_IN_WORKERS else None


def unplaced_limits(env_spec: Any, layout: Any) -> str | None:
    """Why where a worker file's ``TimeLimit``s sat is unknown, or ``None``.

    Its sub-envs ran in workers (:func:`worker_sub_envs`) and its spec holds a multi-step
    wrapper: the spec's ``max_episode_steps`` may be the limit of a ``TimeLimit`` over it or
    under it (counting its steps or the env's), and another may be under it unseen, so an env
    rebuilt from the spec may end an episode inside a frame skip where the recorded one did
    not, or the other way, at any step.

    >>> skip = {"entry_point": "gymnasium.wrappers.stateful_observation:MaxAndSkipObservation"}
    >>> unplaced_limits({"additional_wrappers": [skip]}, {"kind": "vector",
    ...     "vector_class": "AsyncVectorEnv"})[:48]
    'the sub-envs ran in AsyncVectorEnv workers, whos'
    """
    workers = worker_sub_envs(layout)
    wrappers = env_spec.get("additional_wrappers") if isinstance(env_spec, Mapping) else None
    if workers is None:
        return None
    multi = [
        str(w.get("entry_point")).rpartition(":")[2][:80]
        for w in _listed(wrappers)
        if isinstance(w, Mapping) and multi_step(str(w.get("entry_point")))
    ]
    if not multi:
        return None
    where, instead = _worker_clauses(layout, workers)
    return (
        f"{where}, and its spec holds {multi[0]}, which steps the env more than once a step: "
        "whether its TimeLimits sat over it or under it is unknown, so an env rebuilt from the "
        "spec may end an episode at another step; pass --env-factory MODULE:CALLABLE that builds "
        f"the sub-env as recorded, or {instead}"
    )


def _worker_clauses(layout: Mapping[str, Any], workers: str) -> tuple[str, str]:
    """Where a worker file's sub-envs ran, and how to record them so that their limits are read.

    From its ``vector_class`` when the layout has :data:`LAYOUT_UNREAD_CAUSE`; in a file
    without it, cut from ``workers``, the text of :func:`worker_limits`.
    """
    if isinstance(layout.get(LAYOUT_UNREAD_CAUSE), str):
        vector_class = str(layout.get("vector_class"))
        return _in_workers(vector_class), _record_locally(vector_class)
    return workers.partition(":")[0], workers.rpartition("; ")[2].removesuffix(_TO_REPLAY)


RUN_TRANSPARENT_WRAPPERS = "transparent_wrappers"
"""The key, in the run metadata's ``recorder`` record, of the entry points of the wrappers the
user declared transparent (``transparent_wrappers=``; absent when none)."""


def declared_transparent(recorder: Any) -> frozenset[str]:
    """The entry points a run's ``recorder`` metadata declares transparent (at most 64)."""
    listed = recorder.get(RUN_TRANSPARENT_WRAPPERS) if isinstance(recorder, Mapping) else None
    return frozenset(str(e)[:_MAX_TEXT] for e in _listed(listed) if isinstance(e, str))


LAYOUT_REWARD_WRAPPERS = "reward_wrappers"
"""The layout key of the wrappers that change the reward between the env and the recorder (entry
points, innermost first; absent when there were none, and in files that predate it)."""

REWARD_CHANGING = frozenset({"NormalizeReward", "TransformReward", "ClipReward", "VecNormalize"})
"""The class names of the Gymnasium (single and vector) and SB3 wrappers that change the reward
(``VecNormalize`` only with ``norm_reward``; the recorder decides)."""


def reward_wrapper_names(layout: Any) -> list[str]:
    """The class names of the wrappers between the env and the recorder that change the reward.

    From the layout's :data:`LAYOUT_REWARD_WRAPPERS` (innermost first; none in files that
    predate it).

    >>> reward_wrapper_names({"reward_wrappers": ["gymnasium.wrappers:NormalizeReward"]})
    ['NormalizeReward']
    """
    listed = layout.get(LAYOUT_REWARD_WRAPPERS) if isinstance(layout, Mapping) else None
    return [str(e).rpartition(":")[2][:80] for e in _listed(listed)]


def reward_wrapper_setups(layout: Any, env_spec: Any) -> list[str]:
    """:func:`reward_wrapper_names` with the settings the spec recorded of each, as text.

    Each wrapper of the layout is matched, in order, with the spec's ``additional_wrappers``
    entry of its entry point, whose ``kwargs`` are its settings: ``ClipReward(max_reward=1.0,
    min_reward=-1.0)``. A setting the spec does not hold (no entry, no kwargs, or a placeholder:
    ``TransformReward``'s function) is not there to differ: such a wrapper is its name alone.

    >>> spec = {"additional_wrappers": [{"entry_point": "g:TimeLimit", "kwargs": {}},
    ...     {"entry_point": "g:ClipReward", "kwargs": {"min_reward": -1, "max_reward": 0.5}}]}
    >>> reward_wrapper_setups({"reward_wrappers": ["g:ClipReward", "g:NormalizeReward"]}, spec)
    ['ClipReward(max_reward=0.5, min_reward=-1)', 'NormalizeReward']
    """
    listed = layout.get(LAYOUT_REWARD_WRAPPERS) if isinstance(layout, Mapping) else None
    spec_wrappers = env_spec.get("additional_wrappers") if isinstance(env_spec, Mapping) else None
    entries = [w for w in _listed(spec_wrappers) if isinstance(w, Mapping)]
    out: list[str] = []
    at = 0
    for entry_point in map(str, _listed(listed)):
        found = next(
            (i for i in range(at, len(entries)) if entries[i].get("entry_point") == entry_point),
            None,
        )
        kwargs = entries[found].get("kwargs") if found is not None else None
        at = at if found is None else found + 1
        settings = ", ".join(
            f"{key}={json.dumps(value, sort_keys=True, default=str)[:_MAX_TEXT]}"
            for key, value in sorted(kwargs.items() if isinstance(kwargs, Mapping) else ())
            if unrecorded(value) is None
        )
        name = entry_point.rpartition(":")[2][:80]
        out.append(f"{name}({settings})" if settings else name)
    return out


def stateful_wrapper(entry_point: str, *, snapshots: bool = False) -> str | None:
    """Why the wrapper of ``entry_point`` keeps state a file does not hold, or ``None``.

    ``None`` for every wrapper but those the registry calls ``stateful``, and those it calls
    ``snapshot`` in a file without state snapshots (``snapshots``: the file has them).
    """
    rule = RECORDED_WRAPPERS.get(entry_point)
    if rule is None or rule.kind not in ("stateful", "snapshot"):
        return None
    return None if rule.kind == "snapshot" and snapshots else rule.why


_VECTOR_STEP_SAFE = frozenset(
    f"gymnasium.wrappers.vector.{module}:{name}"
    for module, name in (
        ("dict_info_to_list", "DictInfoToList"),  # the recorder reads infos either way
        ("common", "RecordEpisodeStatistics"),  # adds episode totals to the infos
    )
)
"""Vector wrappers that change no sub-env's observation, action, reward or flags."""


def vector_wrapper_cause(entry_point: str) -> str | None:
    """Why a vector wrapper under the vector recorder makes its episodes unreplayable.

    ``None`` for those that change no sub-env's step (they only rearrange or add infos).
    """
    if entry_point in _VECTOR_STEP_SAFE:
        return None
    module, _, name = entry_point.rpartition(":")
    return (
        f"the recorder wrapped the vector wrapper {name[:80]} ({module[:120]}): the steps it "
        "recorded are that wrapper's, which no sub-env rebuilt alone gives; wrap the vector env "
        f"in RecordVectorEvidence first (innermost), then in {name[:80]}"
    )


def state_causes(env_spec: Any, layout: Any) -> list[str]:
    """What makes the state a file's episodes began in unrestorable, one reason per cause.

    From the run metadata alone (``env_spec``: the recorded env spec, a sub-env's for a vector
    file; ``layout``: the file's layout): each recorded wrapper that keeps state across episodes
    (:func:`stateful_wrapper`), each vector wrapper the vector recorder wrapped, and the
    sub-envs' own state that every episode needs, not snapshot (:func:`unsaved_state`).
    """
    causes: list[str] = []
    wrappers = env_spec.get("additional_wrappers") if isinstance(env_spec, Mapping) else None
    snapshots = isinstance(layout, Mapping) and layout.get(LAYOUT_STATE_SNAPSHOTS) is True
    for wrapper in _listed(wrappers):
        entry = str(wrapper.get("entry_point")) if isinstance(wrapper, Mapping) else ""
        why = stateful_wrapper(entry, snapshots=snapshots)
        if why is not None:
            name = entry.rpartition(":")[2]
            causes.append(
                f"the recorded wrapper {name} {why.removeprefix('it ')} (no state snapshot): "
                f"its episodes cannot begin in the state they were recorded in; "
                f"{_unrestorable_fix(name, entry, layout)}"
            )
    vector = layout.get(LAYOUT_VECTOR_WRAPPERS) if isinstance(layout, Mapping) else None
    causes += [c for entry in _listed(vector) if (c := vector_wrapper_cause(str(entry)))]
    unsaved = unsaved_state(layout)
    if unsaved is not None and unsaved[1]:  # (else only unseeded episodes: check says which)
        causes.append(unsaved[0])
    return causes


def _unrestorable_fix(name: str, entry_point: str, layout: Any) -> str:
    """What makes a recorded wrapper's state restorable, as advice.

    The recorder inside it; in a vector file's sub-envs (a vector recorder cannot sit inside a
    sub-env's wrapper), a ``ResetRngInfo`` outermost, which snapshots those with an adapter.
    """
    vector = isinstance(layout, Mapping) and layout.get("kind") == "vector"
    rule = RECORDED_WRAPPERS.get(entry_point)
    if not vector or rule is None or rule.kind != "snapshot":
        return f"record with the recorder inside {name} (innermost)"
    return (
        "wrap each sub-env in episode_audit.ResetRngInfo (outermost, in the env function), "
        f"which snapshots {name}"
    )


def _listed(value: Any) -> Iterable[Any]:
    """A recorded list (a single value: a list of it; none: empty), at most 64 items."""
    if value is None:
        return []
    return (value if isinstance(value, list) else [value])[:64]
