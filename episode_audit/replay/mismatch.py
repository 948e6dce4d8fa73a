"""How the env replay built differs from the recording's description, if it does.

:func:`env_mismatch` (single-env and vector files): its spaces, its step limits, its env kwargs
and, for an env the user's factory built, its wrappers (without a spec, its class; without a
recorded spec, the class the recorder wrapped); :func:`unverified_match`: why a factory's env
that matched cannot be verified to be the recorded one (no spec on either side, wrappers that
record no arguments, a value held only as a placeholder); :func:`agents_mismatch` (PettingZoo).
An argument one spec names and the other does not has the other's default (the signature of
the callable its entry point names, read from a module this process has already imported:
nothing a file names is imported here); one whose default cannot be read does not match.
Values are compared as a file holds them (:func:`_held`): a function is its placeholder, its
type and qualified name (``format/unrecorded.py``); a value's placeholder, only its type, is
never told from another value (:func:`_difference`). What is compared: docs/replay.md.
"""

from __future__ import annotations

import inspect
import json
import sys
from collections.abc import Iterable, Mapping
from itertools import zip_longest
from typing import Any, Final, Literal

import gymnasium as gym
import numpy as np

from ..format.records import RunInfo
from ..format.spaces import describe_space
from ..format.unrecorded import placeholder, unrecorded
from ..format.wrappers import (
    RECORDED_WRAPPERS,
    declared_transparent,
    placed_limits,
    worker_sub_envs,
)
from ..record.time_limits import limit_places, step_limit
from .envs import MAX_ENV_KWARGS_DEPTH
from .envs import nesting_depth as _depth
from .envs import shown_value as _shown

__all__ = ["agents_mismatch", "env_mismatch", "unverified_match"]

_MISMATCH = "the rebuilt env does not match the recording: "


def env_mismatch(
    run: RunInfo, env: gym.Env[Any, Any], *, factory: bool = False, wrappers: bool = False
) -> str | None:
    """How the env replay built differs from the recorded description, or ``None``.

    Its observation and action spaces, its step limits (:func:`_limit_checks`) and, when it
    has a spec, its env kwargs (:func:`_arguments`; ``render_mode`` aside) and, when
    ``factory`` (the user's env factory built it: the reason then says to change that) or
    ``wrappers`` (built from the recorded wrappers' entry points), its wrappers
    (:func:`_wrappers`; one whose constructor adds wrappers of its own comes out twice, rebuilt
    entry by entry). A difference between two functions' placeholders is said only when
    nothing else differs. The limits of a factory's env are not held to those of a file
    whose sub-envs ran in workers (``wrappers.worker_sub_envs``: the recorder could not read
    them all, nor where they sat). Never raises: what cannot be read of the rebuilt env is not
    compared.
    """
    spec = run.env_spec if isinstance(run.env_spec, Mapping) else {}
    try:
        checks: list[tuple[str, Any, Any]] = [
            ("observation space", run.observation_space, _described(env.observation_space)),
            ("action space", run.action_space, _described(env.action_space)),
        ]
        if not (factory and worker_sub_envs(run.layout)):  # (its limits: the user's word)
            checks += _limit_checks(spec, env)
    except Exception:  # the env's own attributes: compare nothing more
        return None
    said = next(
        (f"{w} {_shown(r)} recorded vs {_shown(n)} rebuilt" for w, r, n in checks if r != n), None
    )
    if said is None:
        found = _spec_differences(run, env, factory or wrappers)
        said = next((text for text, kind in found if kind == "differs"), None)
        said = said or next((text for text, kind in found if kind == "functions"), None)
    return None if said is None else f"{_MISMATCH}{said}; {_as_recorded(factory)}"


Difference = Literal["differs", "functions", "untold"]
"""How an argument differs: in value, between two functions' placeholders (said only when
nothing else differs), or not to be told (a placeholder of a value: :func:`unverified_match`)."""


def _spec_differences(
    run: RunInfo, env: gym.Env[Any, Any], wrappers: bool
) -> list[tuple[str, Difference]]:
    """How the rebuilt env's spec differs from the recorded one, each difference said.

    Its kwargs, then (``wrappers``) its wrappers; each with how it differs (:data:`Difference`).
    """
    spec = run.env_spec if isinstance(run.env_spec, Mapping) else {}
    if not spec:  # (nothing recorded of its arguments and wrappers)
        return _wrapped_class_difference(run, env)
    try:
        rebuilt = env.spec
    except Exception:  # the env's own attribute
        return []
    if rebuilt is None:
        return _class_difference(spec, env)
    found: list[tuple[str, Difference]] = []
    try:
        recorded, now = spec.get("kwargs"), rebuilt.kwargs
        if isinstance(recorded, Mapping) and isinstance(now, Mapping):
            entries = (spec.get("entry_point"), rebuilt.entry_point)
            found += _arguments("env kwarg", recorded, now, entries)
    except Exception:  # the env's own values: compare nothing more of them
        pass
    if wrappers:
        try:
            found += _wrappers(spec, rebuilt, declared_transparent(run.recorder))
        except Exception:
            pass
    return found


def _class_difference(
    spec: Mapping[str, Any], env: gym.Env[Any, Any]
) -> list[tuple[str, Difference]]:
    """A rebuilt env without a spec: its class against the class the recorded entry point names.

    Said only when that entry point names a class of a module this process has imported
    (:func:`_loaded`) and the env's ``unwrapped`` is not an instance of it; anything else
    (a function, a module not imported) is not compared. A subclass may step as the class
    does: its match is unverified (:func:`unverified_match`), not a difference.
    """
    entry = spec.get("entry_point")
    try:
        cls = type(env.unwrapped)
        named = _loaded(entry)
        if not isinstance(named, type) or issubclass(cls, named):
            return []
        now = f"{cls.__module__}:{cls.__qualname__}"
    except Exception:  # the env's own attribute
        return []
    return [(f"env entry point {_shown(entry)} recorded vs class {_shown(now)} rebuilt", "differs")]


def _wrapped_class_difference(run: RunInfo, env: gym.Env[Any, Any]) -> list[tuple[str, Difference]]:
    """A recording without a spec: the class the recorder wrapped against the rebuilt env's.

    The run names it (``reward_terms.info_of``, with terms read automatically): the env, or the
    outermost wrapper under the recorder. A difference when no layer of the rebuilt env (its
    wrappers, its ``unwrapped``) is of that class or a subclass (:func:`_same_class`). Not
    compared: a wrapper that never changes a step (the factory may leave it out), and, in a
    vector file, a class that is not a ``gymnasium.Env`` of a module this process has imported
    (it may be the vector env itself: an ``AsyncVectorEnv``'s sub-envs are not read).
    """
    terms = run.reward_terms if isinstance(run.reward_terms, Mapping) else {}
    wrapped = terms.get("info_of")
    if not isinstance(wrapped, str) or ":" not in wrapped:
        return []
    rule = RECORDED_WRAPPERS.get(wrapped)
    if rule.kind == "transparent" if rule else wrapped in declared_transparent(run.recorder):
        return []
    loaded = _loaded(wrapped)
    if run.layout.get("kind") != "single" and not (
        isinstance(loaded, type) and issubclass(loaded, gym.Env)
    ):
        return []
    try:
        layers: list[Any] = [env]
        while isinstance(layers[-1], gym.Wrapper) and len(layers) < 64:
            layers.append(layers[-1].env)
        if any(_same_class(wrapped, cls) for layer in layers for cls in type(layer).__mro__):
            return []
        now = f"{type(env.unwrapped).__module__}:{type(env.unwrapped).__qualname__}"
    except Exception:  # the env's own attributes
        return []
    return [
        (
            f"the recorder wrapped {_shown(wrapped[:200])} (the recording holds no env spec), "
            f"which the rebuilt env ({_shown(now[:200])}) neither is nor wraps",
            "differs",
        )
    ]


def _same_class(entry_point: str, cls: type) -> bool:
    """Whether ``entry_point`` (``module:qualname``) names ``cls``.

    Gymnasium's wrappers by their package (:func:`_entry`); a class of ``__main__`` (a script's
    own, which the factory imports by its module's name) by its qualified name.
    """
    named = f"{getattr(cls, '__module__', '')}:{getattr(cls, '__qualname__', '')}"
    return _entry(entry_point) == _entry(named) or _same_placeholder(
        f"class {entry_point}", f"class {named}"
    )


def unverified_match(run: RunInfo, env: Any, *, factory: bool) -> str | None:
    """Why a matching rebuilt env cannot be verified to be the recorded one, or ``None``.

    Asked of an env :func:`env_mismatch` (or :func:`agents_mismatch`) found no difference in.
    Unverified, when the user's ``factory`` built it: any env, where the recording holds no
    spec (nothing recorded says how its env was built); an env without a spec (built by its
    class, not ``gym.make``), whose constructor's arguments and wrappers cannot be compared
    with the recording's; wrappers that record no arguments (their spec's ``kwargs`` null: not
    deriving from ``gymnasium.utils.RecordConstructorArgs``, as SB3's Atari wrappers) on either
    side, whose constructor takes any besides the env; an argument either side holds only as
    a value's placeholder (:func:`_untold`); a PettingZoo env, whose constructor
    arguments cannot be compared with the recorded ``env_kwargs``. And a PettingZoo env replay
    built from the file with its defaults, the recording holding no ``env_kwargs``, or one whose
    wrappers are not the recorded env's (:func:`_unverified_game`). Replay then gives an episode
    that differs ``not_replayable`` with this cause, not ``diverged``
    (``results.not_told_unverified``). Never raises.
    """
    spec = run.env_spec if isinstance(run.env_spec, Mapping) else {}
    if str(run.layout.get("kind", "")).startswith("pettingzoo_"):
        return _unverified_game(run.layout, env, factory=factory)
    if not factory:
        return None
    if not spec:
        return _NO_SPEC
    try:
        rebuilt = env.spec
    except Exception:  # the env's own attribute
        rebuilt = None
    if rebuilt is None:
        return (
            f"the env factory's env has no spec, so its arguments cannot be compared with the "
            f"recording's ({_shown(run.env_id)}, kwargs {_shown(spec.get('kwargs'))}); make the "
            "factory build it with gymnasium.make so they can be"
        )
    try:
        recorded, now = _compared_wrappers(spec, rebuilt, declared_transparent(run.recorder))
        unknown = [
            _name(entry)
            for (entry, kwargs), (_, now_kwargs) in zip(recorded, now, strict=False)
            if not (isinstance(kwargs, Mapping) and isinstance(now_kwargs, Mapping))
            and _takes_arguments(entry)
        ]
    except Exception:  # the env's own values
        return None
    if not unknown:
        return _untold(run, env)
    listed = ", ".join(unknown[:6]) + (f" and {len(unknown) - 6} more" if len(unknown) > 6 else "")
    return (
        f"the arguments of wrapper(s) {listed} are not recorded (they do not derive from "
        "gymnasium.utils.RecordConstructorArgs), so the rebuilt ones' cannot be compared with "
        "the recording's"
    )


def _untold(run: RunInfo, env: Any) -> str | None:
    """Why a rebuilt env's spec cannot be told from the recorded one, or ``None``.

    The first argument either spec holds only as a value's placeholder (:func:`_difference`):
    whether the two values differ is unknown.
    """
    said = next((t for t, kind in _spec_differences(run, env, True) if kind == "untold"), None)
    if said is None:
        return None
    return f"{said}, and a placeholder (a value JSON cannot hold) keeps only its type"


_NO_SPEC = (
    "the recording holds no env spec (its env was not made with gymnasium.make) to verify the "
    "env factory's env against; record an env made with gymnasium.make so it can be"
)


def _takes_arguments(entry_point: str) -> bool:
    """Whether the wrapper class ``entry_point`` names takes arguments besides the env.

    Unknown (its module not imported, no signature Python can read): it may.
    """
    target = _loaded(entry_point)
    if target is None:
        return True
    try:
        return len(inspect.signature(target).parameters) > 1
    except (TypeError, ValueError):
        return True


def _limit_checks(spec: Mapping[str, Any], env: gym.Env[Any, Any]) -> list[tuple[str, Any, Any]]:
    """The rebuilt env's step limits against the recorded ones (what, recorded, rebuilt).

    A spec with ``TimeLimit``s among its wrappers (over a multi-step wrapper:
    ``record/time_limits.py``): its ``max_episode_steps`` against the rebuilt env's limit
    under no multi-step wrapper, and those wrappers' limits against the rebuilt env's over one.
    Any other (every file recorded before they were placed, too): its ``max_episode_steps``
    against the smallest of the rebuilt env's ``TimeLimit``s', one where the recording had none
    too.
    """
    placed = placed_limits(spec)
    if placed:
        places = limit_places(env)
        return [
            ("max episode steps", spec.get("max_episode_steps"), places.inner),
            ("time limits over multi-step wrappers", placed, [n for _, n in places.placed]),
        ]
    limit = step_limit(env)
    if "max_episode_steps" in spec and (limit is not None or spec["max_episode_steps"]):
        return [("max episode steps", spec.get("max_episode_steps"), limit)]
    return []


_UNKNOWN: Final = object()
"""An argument's default that cannot be read."""

_UNCOMPARED = frozenset({"render_mode"})  # (it changes no step)
_COMPARED_BYTES = 4096


def _arguments(
    what: str,
    recorded: Mapping[Any, Any],
    now: Mapping[Any, Any],
    entries: tuple[Any, Any],
    dtype_names: bool = False,
) -> list[tuple[str, Difference]]:
    """How the recorded arguments of a callable differ from those it was rebuilt with.

    ``entries``: each side's entry point (whose signature gives an argument that side does not
    name its default); ``dtype_names``: a rebuilt numpy dtype is held as its name, as the
    recorder holds one given to a wrapper it knows. Not compared: ``render_mode``, and a value
    nested deeper than :data:`~.envs.MAX_ENV_KWARGS_DEPTH` or larger than 4 KiB of JSON (a map,
    a table: too large to show, and a file's may be made up to be slow to compare).
    """
    sides = (
        {str(k): v for k, v in recorded.items()},
        {str(k): _held(v, dtype_names) for k, v in now.items()},
    )
    found: list[tuple[str, Difference]] = []
    for name in dict.fromkeys([*sides[0], *sides[1]]):
        if name in _UNCOMPARED or not all(_compared(side.get(name)) for side in sides):
            continue
        values = [
            side[name] if name in side else _held(_default(entry, name), dtype_names)
            for side, entry in zip(sides, entries, strict=True)
        ]
        named = f"{what} {name[:80]!r}"
        unnamed = next((i for i, side in enumerate(sides) if name not in side), None)
        if unnamed is not None and values[unnamed] is _UNKNOWN:
            found.append((_unknown_default(named, values[1 - unnamed], unnamed == 1), "differs"))
            continue
        kind = _difference(values[0], values[1])
        if kind is not None:
            note = "" if unnamed is None else f" ({_SPECS[unnamed]} does not name it: its default)"
            said = f"{named} {_shown(values[0])} recorded vs {_shown(values[1])} rebuilt{note}"
            found.append((said, kind))
    return found


_SPECS = ("the recorded spec", "the rebuilt env's spec")


def _unknown_default(named: str, value: Any, rebuilt_unnamed: bool) -> str:
    """An argument one spec names as ``value`` and the other leaves at a default not known."""
    if rebuilt_unnamed:
        return (
            f"{named} {_shown(value)} recorded, not named by the rebuilt env's spec and its "
            "default is unknown"
        )
    return (
        f"{named} not named by the recorded spec and its default is unknown, {_shown(value)} "
        "rebuilt"
    )


def _compared(value: Any) -> bool:
    """Whether an argument's value is compared (absent: yes; see :func:`_arguments`)."""
    if value is None:
        return True
    return (
        _depth(value) <= MAX_ENV_KWARGS_DEPTH
        and len(json.dumps(value, default=repr)) <= _COMPARED_BYTES
    )


def _held(value: Any, dtype_names: bool = False) -> Any:
    """``value`` as a file holds it: JSON, else its placeholder (``format/unrecorded.py``).

    With ``dtype_names``, a numpy dtype is its name, as the recorder holds one given to a
    wrapper it knows. :data:`_UNKNOWN` stays itself.
    """
    if value is _UNKNOWN:
        return value
    if dtype_names and (
        isinstance(value, np.dtype) or (isinstance(value, type) and issubclass(value, np.generic))
    ):
        return np.dtype(value).name
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError, RecursionError):
        return placeholder(value)


def _difference(recorded: Any, rebuilt: Any) -> Difference | None:
    """How two held values differ (:data:`Difference`), or ``None`` when they are the same.

    Numbers by value (``1`` is ``1.0``, NaN is NaN). A function's or a class's placeholder is
    the same as another of the same type and qualified name, the module too unless one is
    ``__main__`` (a script's own function, which the factory imports by its module's name),
    and differs from another's. Any other placeholder keeps only a type (a value JSON cannot
    hold, ``np.float32(2.0)``; NaN or infinity where the spec needed placeholders): against
    anything, it cannot be told whether the values differ.

    >>> _difference({"episode_audit.unrecorded": "float32"}, 2.0)
    'untold'
    >>> _difference(2, 2.0), _difference(2, 3)
    (None, 'differs')
    """
    a, b = unrecorded(recorded), unrecorded(rebuilt)
    if a is None and b is None:
        same = bool(recorded == rebuilt) or _text(recorded) == _text(rebuilt)
        return None if same else "differs"
    if a is None or b is None or not (_names_one(a) and _names_one(b)):
        return "untold"
    return None if _same_placeholder(a, b) else "functions"


def _names_one(held: str) -> bool:
    """Whether a placeholder names a function or a class (``type module:qualname``).

    >>> _names_one("function train:clip"), _names_one("float32")
    (True, False)
    """
    return ":" in held.partition(" ")[2]


def _text(value: Any) -> str:
    """A JSON value's text, keys sorted (NaN is ``NaN``, so it equals itself)."""
    return json.dumps(value, sort_keys=True)


def _same_placeholder(a: str, b: str) -> bool:
    """Whether two placeholders describe the same thing (``type module:qualname``).

    >>> _same_placeholder("function __main__:make.<locals>.<lambda>",
    ...                   "function train:make.<locals>.<lambda>")
    True
    >>> _same_placeholder("function train:clip", "function train:scale")
    False
    """
    if a == b:
        return True
    kind_a, _, where_a = a.partition(" ")
    kind_b, _, where_b = b.partition(" ")
    module_a, _, name_a = where_a.partition(":")
    module_b, _, name_b = where_b.partition(":")
    return (
        kind_a == kind_b
        and bool(name_a)
        and name_a == name_b
        and "__main__" in (module_a, module_b)
    )


def _default(entry_point: Any, name: str) -> Any:
    """The default of argument ``name`` of what ``entry_point`` names, or :data:`_UNKNOWN`.

    ``entry_point``: a callable, or ``module:qualname`` of a module already imported (none is
    imported here). Unknown: a module not imported, a name it lacks, no such keyword argument
    (or only ``**kwargs``), one without a default, or a signature that cannot be read.
    """
    target = entry_point if callable(entry_point) else _loaded(entry_point)
    if target is None:
        return _UNKNOWN
    try:
        parameter = inspect.signature(target).parameters.get(name)
    except (TypeError, ValueError):  # no signature Python can read (a builtin, say)
        return _UNKNOWN
    if parameter is None or parameter.default is inspect.Parameter.empty:
        return _UNKNOWN
    if parameter.kind not in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY):
        return _UNKNOWN
    return parameter.default


def _loaded(entry_point: Any) -> Any:
    """The callable ``module:qualname`` names in a module this process has imported, or ``None``."""
    if not isinstance(entry_point, str) or ":" not in entry_point:
        return None
    module, _, qualname = entry_point.partition(":")
    found: Any = sys.modules.get(module)
    for part in qualname.split("."):
        if found is None:
            return None
        found = inspect.getattr_static(found, part, None)
    return found if callable(found) else None


def _wrappers(
    spec: Mapping[str, Any], rebuilt: gym.envs.registration.EnvSpec, transparent: frozenset[str]
) -> list[tuple[str, Difference]]:
    """How the rebuilt env's wrappers differ from the recorded spec's ``additional_wrappers``.

    Their classes, in order (innermost first), then each one's arguments (:func:`_arguments`).
    Not compared: ``TimeLimit``s (its limits are: :func:`_limit_checks`), the wrappers that
    never change a step (the registry's ``transparent`` ones and those the recording declared
    so), which replay leaves out itself, and the arguments of a wrapper that records none on
    either side (``kwargs`` null: there is nothing to compare them with;
    :func:`unverified_match` says so).
    """
    compared = _compared_wrappers(spec, rebuilt, transparent)
    below = "the innermost wrapper"
    for r, n in zip_longest(*compared):
        if r is None or n is None or _entry(r[0]) != _entry(n[0]):
            names = [_shown(_name(w[0])) if w is not None else "none" for w in (r, n)]
            return [(f"{below}: {names[0]} recorded vs {names[1]} rebuilt", "differs")]
        below = f"the wrapper over {_shown(_name(r[0]))}"
    found: list[tuple[str, Difference]] = []
    for (entry, recorded_kwargs), (now_entry, now_kwargs) in zip(*compared, strict=True):
        name = _name(entry)
        if isinstance(recorded_kwargs, Mapping) and isinstance(now_kwargs, Mapping):
            entries, dtypes = (entry, now_entry), now_entry in RECORDED_WRAPPERS
            found += _arguments(f"{name}'s argument", recorded_kwargs, now_kwargs, entries, dtypes)
    return found


def _compared_wrappers(
    spec: Mapping[str, Any], rebuilt: gym.envs.registration.EnvSpec, transparent: frozenset[str]
) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """The recorded and the rebuilt wrappers compared (:func:`_kept`): ``(entry point, kwargs)``."""
    listed = spec.get("additional_wrappers")
    recorded = [
        (w.get("entry_point"), w.get("kwargs")) if isinstance(w, Mapping) else (repr(w), None)
        for w in (listed if isinstance(listed, list) else [])
    ]
    now = [(w.entry_point, w.kwargs) for w in rebuilt.additional_wrappers]
    return _kept(recorded, transparent), _kept(now, transparent)


_TIME_LIMIT = "gymnasium.wrappers:TimeLimit"


def _kept(
    wrappers: Iterable[tuple[Any, Any]], transparent: frozenset[str]
) -> list[tuple[str, Any]]:
    """The wrappers :func:`_wrappers` compares: not ``TimeLimit``, nor transparent ones."""
    kept = []
    for entry, kwargs in wrappers:
        entry = entry if isinstance(entry, str) else repr(entry)
        rule = RECORDED_WRAPPERS.get(entry)
        if _entry(entry) == _TIME_LIMIT or (
            rule.kind == "transparent" if rule else entry in transparent
        ):
            continue
        kept.append((entry, kwargs))
    return kept


def _entry(entry_point: str) -> str:
    """A wrapper's entry point, Gymnasium's by their package (whose modules move between versions).

    >>> _entry("gymnasium.wrappers.stateful_observation:MaxAndSkipObservation")
    'gymnasium.wrappers:MaxAndSkipObservation'
    """
    if entry_point.startswith(("gymnasium.wrappers.", "gymnasium.wrappers:")):
        return f"gymnasium.wrappers:{entry_point.rpartition(':')[2]}"
    return entry_point


def _name(entry_point: str) -> str:
    """A wrapper's class name, from its entry point."""
    return entry_point.rpartition(":")[2][:80]


_BUILD_AS_RECORDED = "pass --env-factory MODULE:CALLABLE that builds the env as recorded"


def _as_recorded(factory: bool) -> str:
    """What to do about a rebuilt env that differs (``factory``: the user's factory built it)."""
    return "make the --env-factory build the env as recorded" if factory else _BUILD_AS_RECORDED


def agents_mismatch(
    layout: Mapping[str, Any], run: RunInfo, env: Any, *, factory: bool = False
) -> str | None:
    """How a rebuilt PettingZoo env differs from the recording, or ``None``.

    Its PettingZoo env module and its name (:func:`_game_difference`), its agents, its
    ``max_cycles`` (when both the layout and the rebuilt env's ``unwrapped`` have one), and the
    first agent's observation and action spaces. ``factory``: the user's env factory built it.
    Never raises: what cannot be read of the rebuilt env is not compared.
    """
    advice = (
        _as_recorded(factory)
        if layout.get("env_kwargs") or factory
        else "the file holds no env_kwargs (the env's constructor arguments, which "
        "the recorder takes as env_kwargs=): record with them, or " + _BUILD_AS_RECORDED
    )
    named = _game_difference(layout, env)
    if named is not None:
        return f"{_MISMATCH}{named}; {advice}"
    try:
        agents = [str(a) for a in env.possible_agents]
        recorded = layout.get("agents")
        if isinstance(recorded, list) and [str(a) for a in recorded] != agents:
            return (
                f"{_MISMATCH}agents {_agents(recorded)} recorded vs {_agents(agents)} rebuilt; "
                f"{advice}"
            )
        cycles, now = layout.get("max_cycles"), getattr(env.unwrapped, "max_cycles", None)
        if isinstance(cycles, int) and isinstance(now, int) and cycles != now:
            return f"{_MISMATCH}max_cycles {cycles} recorded vs {now} rebuilt; {advice}"
        if agents:
            env_spaces = (env.observation_space(agents[0]), env.action_space(agents[0]))
            for what, rec, space in zip(
                ("observation space", "action space"),
                (run.observation_space, run.action_space),
                env_spaces,
                strict=True,
            ):
                if rec != _described(space):
                    shown = _shown(_described(space))
                    return f"{_MISMATCH}{what} {_shown(rec)} recorded vs {shown} rebuilt; {advice}"
    except Exception:  # the env's own attributes: compare nothing more
        return None
    return None


def _game_difference(layout: Mapping[str, Any], env: Any) -> str | None:
    """How a rebuilt PettingZoo env's module and name differ from the layout's, or ``None``.

    Its module, when both the layout's ``env_module`` and the rebuilt env's (``env_module_of``:
    its ``unwrapped`` class's PettingZoo family and its name) are PettingZoo's own; then its
    name (``metadata["name"]`` of its ``unwrapped``, else the name of its class or of a class it
    derives from, as the recorder takes it) against ``env_name``. Never raises.
    """
    from ..record.pettingzoo import env_module_of

    try:
        module, now = layout.get("env_module"), env_module_of(env)
        if (
            isinstance(module, str)
            and module.startswith("pettingzoo.")
            and now not in (None, module)
        ):
            return f"env module {_shown(module[:200])} recorded vs {_shown(now)} rebuilt"
        name, base = layout.get("env_name"), env.unwrapped
        if not isinstance(name, str):
            return None
        named = (getattr(base, "metadata", None) or {}).get("name")
        if isinstance(named, str):
            same = named == name
        else:
            named, same = type(base).__name__, any(c.__name__ == name for c in type(base).__mro__)
    except Exception:  # the env's own attributes
        return None
    return None if same else f"env name {_shown(name[:200])} recorded vs {_shown(named)} rebuilt"


_NO_KWARGS = (
    "the recording holds no env_kwargs (the env's constructor arguments, which the recorder "
    "takes as env_kwargs=)"
)


def _unverified_game(layout: Mapping[str, Any], env: Any, *, factory: bool) -> str | None:
    """Why a rebuilt PettingZoo env cannot be verified to be the recorded one, or ``None``.

    Its wrappers, when they are not the recorded env's (:func:`_wrapper_difference`). A
    factory's constructor arguments are not known: they cannot be compared with the layout's
    ``env_kwargs`` (nor with none, when the recording holds none). Built from the file, it is
    the recorded env when the recording holds its ``env_kwargs``; without them (``null``: the
    recorder was not given ``env_kwargs=``), it is built with its defaults, which the recorded
    env may not have had.
    """
    wrapped = _wrapper_difference(layout, env, factory=factory)
    if wrapped is not None:
        return wrapped
    kwargs = layout.get("env_kwargs")
    if not factory:
        if kwargs is not None:
            return None
        return (
            f"{_NO_KWARGS}: the env was rebuilt with its defaults, which may not be the "
            "recorded env's; record with env_kwargs= (env_kwargs={} for the defaults)"
        )
    if kwargs is None:
        return f"{_NO_KWARGS} to verify the env factory's env against; record with them"
    said = (
        f"the env factory's env cannot be verified to be built with the recorded env_kwargs "
        f"{_shown(kwargs)}"
    )
    if isinstance(layout.get("env_id"), str) or isinstance(layout.get("env_module"), str):
        return f"{said}; replay without --env-factory to build it with them"
    return said


_STEP_PRESERVING = frozenset(
    f"pettingzoo.utils.wrappers.{name}"
    for name in (
        "order_enforcing.OrderEnforcingWrapper",
        "assert_out_of_bounds.AssertOutOfBoundsWrapper",
        "capture_stdout.CaptureStdoutWrapper",
    )
)
"""PettingZoo's wrappers that only refuse misuse or capture printing: never a step's values."""


def _wrapper_difference(layout: Mapping[str, Any], env: Any, *, factory: bool) -> str | None:
    """How the rebuilt env's wrappers differ from the recorded env's (layout ``wrappers``).

    Compared outermost first, leaving out PettingZoo's wrappers that never change a step
    (:data:`_STEP_PRESERVING`). ``None`` when they are the same, or either side's cannot be
    read (a file without ``wrappers``: recorded before the recorder wrote them). Never raises.
    """
    from ..record.pettingzoo import wrappers_of

    recorded, rebuilt = layout.get("wrappers"), wrappers_of(env)
    if not isinstance(recorded, list) or rebuilt is None:
        return None
    mine = [str(w) for w in recorded if str(w) not in _STEP_PRESERVING]
    now = [w for w in rebuilt if w not in _STEP_PRESERVING]
    if mine == now:
        return None

    def names(layers: list[str]) -> str:
        short = [_shown(w.rpartition(".")[2][:60]) for w in layers[:4]]
        return ", ".join(short) + (f" and {len(layers) - 4} more" if len(layers) > 4 else "")

    return (
        f"the recorded env's wrappers ({names(mine) or 'none'}) are not the rebuilt env's "
        f"({names(now) or 'none'}), and may change a step; "
        + (
            "make the --env-factory build the env with the recorded wrappers"
            if factory
            else "pass --env-factory MODULE:CALLABLE that builds the env with them"
        )
    )


def _described(space: Any) -> Any:
    """A space's description as a file holds it (after a JSON round trip)."""
    return json.loads(json.dumps(describe_space(space)))


def _agents(agents: list[Any]) -> str:
    """A list of agents in a mismatch reason: how many, and the first and last names.

    >>> _agents(["a", "b"]), _agents([f"piston_{i}" for i in range(20)])
    ('2 (a, b)', '20 (piston_0 ... piston_19)')
    """
    names = [str(a)[:40] for a in agents]
    shown = ", ".join(names) if len(names) <= 3 else f"{names[0]} ... {names[-1]}"
    return f"{len(names)} ({shown})"
