"""Build the environment to replay a file's episodes in, safely (a file may come from anyone).

:func:`build_env` (a single env, for single-env and vector files) and
:func:`build_pettingzoo_env` (PettingZoo's AEC or Parallel env; imports ``pettingzoo`` only
when called): the user's ``env_factory``, else the recorded env id when it is registered in
this process, else only with ``trust_entry_points`` what the file names. The order and what each
step may import: docs/replay.md (how the env is built) and docs/security.md (rule 2). How a
built env differs from the recording: ``mismatch.py``.
"""

from __future__ import annotations

import importlib
import json
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import gymnasium as gym

from .._usercode import load_callable
from ..errors import ConfigurationError, ReplayError
from ..format.columns import error_text
from ..format.options import LAYOUT_SPEC_KWARGS_TYPED, decode_typed, spec_kwargs
from ..format.records import RunInfo
from ..format.unrecorded import unrecorded
from ..format.wrappers import (
    declared_transparent,
    plan_wrappers,
    unrecorded_arguments,
)

__all__ = [
    "MAX_ENV_KWARGS_BYTES",
    "MAX_ENV_KWARGS_DEPTH",
    "EnvFactory",
    "build_env",
    "build_pettingzoo_env",
    "nesting_depth",
    "replay_notes",
    "shown_value",
]

EnvFactory = Callable[[], gym.Env[Any, Any]]

MAX_ENV_KWARGS_BYTES = 64 << 10
"""Replay builds an env from at most this many bytes of recorded kwargs (as JSON) …"""
MAX_ENV_KWARGS_DEPTH = 16
"""… nested at most this deep (docs/security.md, rule 5)."""


def build_env(
    run: RunInfo,
    *,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
) -> gym.Env[Any, Any]:
    """Build the environment to replay a file's episodes in (see docs/replay.md).

    Raises :class:`~episode_audit.errors.ReplayError` when the file's episodes cannot be
    replayed in this process, :class:`~episode_audit.errors.ConfigurationError` when
    ``env_factory`` cannot be loaded, raises or returns something other than a ``gymnasium.Env``.
    """
    if env_factory is not None:
        return _from_factory(env_factory)
    spec = run.env_spec or {}
    env_id = run.env_id
    if not env_id:
        raise ReplayError("the file names no env id; pass --env-factory MODULE:CALLABLE")
    if not spec:  # the spec was not serializable: the bare id may be another env
        raise ReplayError(_no_spec_reason(run))
    _check_env_kwargs(spec.get("kwargs"))
    recorded = spec.get("additional_wrappers") or []
    recorded = recorded if isinstance(recorded, list) else [recorded]
    registered = ":" not in env_id and env_id in gym.registry
    if trust_entry_points:  # (built as recorded: no placeholder of what the file lacks)
        for wrapper in recorded:
            if isinstance(wrapper, Mapping) and isinstance(wrapper.get("kwargs"), Mapping):
                _refuse_placeholders(wrapper["kwargs"], f"{str(wrapper.get('name'))[:80]} argument")
    transparent = declared_transparent(run.recorder)
    if trust_entry_points:
        trusted = [w for w in recorded if isinstance(w, Mapping)]
        _refuse_unrecorded_arguments(trusted, transparent)
        if registered:
            return _from_registry(env_id, spec, trusted, _load_wrapper, run.layout)
        return _from_recorded_spec(spec, trusted, run.layout)
    if registered:
        plan = plan_wrappers(recorded, transparent)
        if plan.refused is not None:
            raise ReplayError(plan.refused)
        rebuilt = [{"entry_point": name, "kwargs": kwargs} for name, kwargs in plan.rebuild]
        return _from_registry(env_id, spec, rebuilt, _gymnasium_wrapper, run.layout)
    entry = spec.get("entry_point") if unrecorded_arguments(recorded, transparent) is None else None
    raise ReplayError(
        f"env id {env_id!r} is not registered in this process; pass --import MODULE that "
        "registers it, "
        + (
            f"--env-factory MODULE:CALLABLE, or --trust-entry-points to import {entry!r} named "
            "in the file"
            if entry
            else "or --env-factory MODULE:CALLABLE"
        )
    )


def _from_recorded_spec(
    spec: Mapping[str, Any], wrappers: Sequence[Mapping[str, Any]], layout: Mapping[str, Any]
) -> gym.Env[Any, Any]:
    """The env an unregistered id's recorded spec names, in its ``wrappers`` (trusted).

    The wrappers are put on as :func:`_from_registry` does (Gymnasium's ``make`` refuses one
    without recorded arguments, e.g. SB3's transparent ``Monitor``); the kwargs are the
    recorded ones, exactly where the layout holds them typed (``spec_kwargs_typed``).
    """
    try:
        bare = {**spec, "additional_wrappers": []}
        recorded_spec = gym.envs.registration.EnvSpec.from_json(json.dumps(bare))
        typed = layout.get(LAYOUT_SPEC_KWARGS_TYPED)
        recorded_spec = replace(recorded_spec, kwargs=spec_kwargs(recorded_spec.kwargs, typed))
        env = gym.make(_without_checks(recorded_spec))
    except Exception as exc:  # the env's own code, or an entry point that does not import
        raise ReplayError(
            f"cannot make the env from the recorded spec: {error_text(exc)}; {_WAY_AROUND}, "
            "or --import MODULE that registers its id"
        ) from None
    return _put_on(env, wrappers, _load_wrapper)


def _refuse_unrecorded_arguments(
    wrappers: Sequence[Mapping[str, Any]], transparent: frozenset[str]
) -> None:
    """Refuse to rebuild a recorded wrapper whose arguments the file does not hold.

    (:func:`~episode_audit.format.wrappers.unrecorded_arguments`; Gymnasium's ``make`` refuses
    such a spec too.)
    """
    name = unrecorded_arguments(wrappers, transparent)
    if name is not None:
        raise ReplayError(
            f"the recorded wrapper {name} did not record its arguments "
            "(it does not derive from gymnasium.utils.RecordConstructorArgs), so it cannot be "
            "rebuilt as recorded; pass --env-factory MODULE:CALLABLE that builds the env"
        )


def replay_notes(run: RunInfo, *, env_factory: Any, trust_entry_points: bool) -> list[str]:
    """What :func:`build_env` left out of the env it built from ``run`` (the wrappers, why)."""
    spec = run.env_spec
    if env_factory is not None or trust_entry_points or not isinstance(spec, Mapping):
        return []
    recorded = spec.get("additional_wrappers") or []
    plan = plan_wrappers(
        recorded if isinstance(recorded, list) else [recorded], declared_transparent(run.recorder)
    )
    return plan.notes if plan.refused is None else []


def _from_factory(env_factory: str | EnvFactory) -> gym.Env[Any, Any]:
    """The env the user's factory returns, checked to be one."""
    env: gym.Env[Any, Any] = _called(env_factory, (gym.Env,), "a gymnasium.Env")
    return env


def _called(env_factory: str | Callable[[], Any], kinds: tuple[type, ...], kind: str) -> Any:
    """What the user's ``env_factory`` returns, checked to be one of ``kinds`` (said ``kind``).

    Raises :class:`~episode_audit.errors.ConfigurationError` in one line when it cannot be
    loaded, raises, or returns something else: the user's own code is at fault, not the file.
    """
    factory = load_callable(env_factory) if isinstance(env_factory, str) else env_factory
    name = env_factory if isinstance(env_factory, str) else getattr(factory, "__name__", "")
    try:
        env = factory()
    except Exception as exc:  # the user's own code: say so, in one line
        raise ConfigurationError(
            f"--env-factory {name}: it raised {error_text(exc)}; it must take no "
            "arguments and return the env"
        ) from None
    if not isinstance(env, kinds):
        raise ConfigurationError(
            f"--env-factory {name}: it returned {type(env).__name__}, not {kind}"
        )
    return env


def _from_registry(
    env_id: str,
    spec: Mapping[str, Any],
    wrappers: Sequence[Mapping[str, Any]],
    load: Callable[[str], Any],
    layout: Mapping[str, Any],
) -> gym.Env[Any, Any]:
    """The registered ``env_id`` made with the recorded kwargs, in its wrappers.

    ``wrappers`` innermost first, each class loaded by ``load`` from its entry point. The
    kwargs are exact where the layout holds them typed (``spec_kwargs_typed``); in a file
    without it, one held as the registered one's JSON is the registered value
    (:func:`_as_registered`).
    """
    try:
        registered = _without_checks(gym.spec(env_id))
        held = dict(spec.get("kwargs") or {})
        typed = layout.get(LAYOUT_SPEC_KWARGS_TYPED)
        if typed is None:
            kwargs = _as_registered(held, registered.kwargs)
        else:
            kwargs = spec_kwargs(held, typed)
        if "max_episode_steps" in spec:  # null: no TimeLimit (not the registered one)
            kwargs.pop("max_episode_steps", None)
            registered = replace(registered, max_episode_steps=spec["max_episode_steps"])
        env = _put_on(gym.make(registered, **kwargs), wrappers, load)
    except (ConfigurationError, ReplayError):
        raise
    except Exception as exc:  # the env's own code, given what the file recorded
        raise ReplayError(
            f"cannot make {env_id!r} with the recorded kwargs: {error_text(exc)}"
        ) from None
    return env


def _as_registered(kwargs: dict[str, Any], registered: Mapping[str, Any]) -> dict[str, Any]:
    """``kwargs`` with each one whose JSON the registered kwarg of that name has replaced by it.

    The file holds kwargs as JSON: a tuple as a list, which an env may refuse (ALE's v0 / v4
    ids register ``frameskip=(2, 5)``, and ALE takes no list). Where the recorded value is the
    registered one as JSON, the registered value is what the recorded env was given.
    """
    out = dict(kwargs)
    for name, value in kwargs.items():
        if name not in registered or registered[name] is value:
            continue
        try:
            held = json.loads(json.dumps(registered[name]))
        except (TypeError, ValueError, RecursionError):
            continue
        if held == value and type(held) is type(value):
            out[name] = registered[name]
    return out


def _put_on(
    env: Any, wrappers: Sequence[Mapping[str, Any]], load: Callable[[str], Any]
) -> gym.Env[Any, Any]:
    """``env`` in ``wrappers`` (innermost first), each class loaded by ``load``."""
    for wrapper in wrappers:
        cls = load(str(wrapper["entry_point"]))
        if not (isinstance(cls, type) and issubclass(cls, gym.Wrapper)):
            raise ReplayError(
                f"the recorded wrapper {wrapper['entry_point']!r} is not a Wrapper class"
            )
        env = _wrapped(cls, env, wrapper)
    return env  # type: ignore[no-any-return]


def _wrapped(
    cls: type[gym.Wrapper[Any, Any, Any, Any]], env: Any, wrapper: Mapping[str, Any]
) -> Any:
    """``env`` in the recorded ``wrapper`` (its class ``cls``); an error names the wrapper."""
    kwargs = wrapper.get("kwargs") or {}
    try:
        return cls(env, **kwargs)
    except Exception as exc:  # the wrapper's own checks, given what the file recorded
        name = str(wrapper["entry_point"]).rpartition(":")[2][:80]
        raise ReplayError(
            f"cannot rebuild the recorded wrapper {name} with its recorded arguments "
            f"{shown_value(kwargs)}: {error_text(exc)}; {_WAY_AROUND}"
        ) from None


def _load_wrapper(entry_point: str) -> Any:
    """A wrapper class a trusted file names (this imports its module)."""
    return load_callable(entry_point)


def _gymnasium_wrapper(name: str) -> Any:
    """``gymnasium.wrappers.<name>``, for a name in the registry of recorded wrappers.

    The registry also names wrappers of newer Gymnasiums than the installed one: a file that
    used one cannot be replayed here, and says so.
    """
    cls = getattr(gym.wrappers, name, None)
    if cls is None:
        raise ReplayError(
            f"the recorded wrapper {name} is not in this Gymnasium ({gym.__version__}); "
            "replay with the Gymnasium version the file recorded"
        )
    return cls


def _check_env_kwargs(kwargs: Any, what: str = "env kwarg") -> None:
    """Refuse recorded env kwargs too deeply nested or too large to build an env from.

    Raises :class:`~episode_audit.errors.ReplayError` naming the kwarg (the largest one, for
    the total size) and its size.
    """
    if kwargs is None:
        return
    if not isinstance(kwargs, Mapping):
        raise ReplayError(
            f"the recorded {what}s are not a mapping ({type(kwargs).__name__}); {_WAY_AROUND}"
        )
    _refuse_placeholders(kwargs, what)
    _check_depths(kwargs, what)
    sizes = {str(name): len(json.dumps(value)) for name, value in kwargs.items()}
    total = sum(sizes.values())
    if total > MAX_ENV_KWARGS_BYTES:
        name = max(sizes, key=lambda k: sizes[k])
        raise ReplayError(
            f"the recorded {what} {name[:80]!r} is {sizes[name]} bytes of JSON (all: {total}), "
            f"more than the {MAX_ENV_KWARGS_BYTES} replay builds an env from; {_WAY_AROUND}"
        )


def _check_depths(kwargs: Mapping[Any, Any], what: str) -> None:
    """Refuse recorded kwargs one of which is nested deeper than replay builds an env from."""
    for name, value in kwargs.items():
        depth = nesting_depth(value)
        if depth > MAX_ENV_KWARGS_DEPTH:
            raise ReplayError(
                f"the recorded {what} {str(name)[:80]!r} is nested {depth} deep, more than the "
                f"{MAX_ENV_KWARGS_DEPTH} replay builds an env from; {_WAY_AROUND}"
            )


_WAY_AROUND = "pass --env-factory MODULE:CALLABLE that builds the env"


def _refuse_placeholders(kwargs: Mapping[str, Any], what: str) -> None:
    """Refuse recorded arguments one of which is a placeholder (what the file could not hold)."""
    for name, value in kwargs.items():
        held = unrecorded(value)
        if held is not None:
            raise ReplayError(
                f"the recorded {what} {str(name)[:80]!r} is not in the file ({held}: JSON "
                f"cannot hold it); {_WAY_AROUND}"
            )


def nesting_depth(value: Any) -> int:
    """How deeply lists, tuples and dicts nest in a value (a scalar: 0), without recursion."""
    deepest, level = 0, [value]
    while True:
        containers = [item for item in level if isinstance(item, (list, tuple, dict))]
        if not containers:
            return deepest
        deepest += 1
        level = [v for c in containers for v in (c.values() if isinstance(c, dict) else c)]


def _no_spec_reason(run: RunInfo) -> str:
    """Why a file with an env id but no env spec cannot be replayed without an env factory."""
    notes = (run.recorder or {}).get("notes")
    said = (
        [str(n) for n in notes if str(n).startswith("env spec")] if isinstance(notes, list) else []
    )
    note = said[0] if said else ""
    if len(note) > 200:  # (at a word's end)
        note = note[:200].rsplit(" ", 1)[0] + " …"
    why = f" ({note})" if note else ""
    return (
        f"the env spec of {run.env_id!r} was not recorded{why}: its kwargs and wrappers are "
        "unknown, and the bare id may be another env; pass --env-factory MODULE:CALLABLE "
        "that builds the env as it was recorded"
    )


def _without_checks(spec: gym.envs.registration.EnvSpec) -> gym.envs.registration.EnvSpec:
    """``spec`` without the passive env checker and the order check (see docs/replay.md)."""
    return replace(spec, disable_env_checker=True, order_enforce=False)


def build_pettingzoo_env(
    layout: Mapping[str, Any],
    *,
    env_factory: str | Callable[[], Any] | None = None,
    trust_entry_points: bool = False,
) -> Any:
    """Build the PettingZoo env a file was recorded from (see docs/replay.md).

    Raises :class:`~episode_audit.errors.ReplayError` when it cannot be built in this process,
    or is not the PettingZoo API (AEC or Parallel) the file was recorded with;
    :class:`~episode_audit.errors.ConfigurationError` when ``env_factory`` cannot be loaded,
    raises or returns something other than a PettingZoo env.
    """
    from pettingzoo import AECEnv, ParallelEnv

    from ..record.pettingzoo import KIND_PARALLEL, is_registered, make_registered

    kind = str(layout.get("kind"))
    parallel = kind == KIND_PARALLEL
    want = ParallelEnv if parallel else AECEnv
    api = "ParallelEnv" if parallel else "AECEnv"
    env_id = layout.get("env_id")
    kwargs = {} if env_factory is not None else _recorded_env_kwargs(layout)
    if env_factory is not None:
        env = _called(env_factory, (AECEnv, ParallelEnv), "a PettingZoo AECEnv or ParallelEnv")
    elif isinstance(env_id, str) and is_registered(kind, env_id):
        try:
            env = make_registered(kind, env_id, kwargs)
        except Exception as exc:
            raise ReplayError(
                f"cannot make {env_id} with the recorded kwargs {kwargs!r}: "
                f"{type(exc).__name__}: {exc}"
            ) from None
    else:
        env = _from_pettingzoo_module(layout, kwargs, parallel, trust_entry_points)
    if not isinstance(env, want):
        raise ReplayError(f"the env factory returned {type(env).__name__}, not a PettingZoo {api}")
    return env


def _recorded_env_kwargs(layout: Mapping[str, Any]) -> dict[str, Any]:
    """A PettingZoo file's env kwargs, checked: their typed form when the file holds one.

    The layout's ``env_kwargs`` are JSON, each kwarg JSON would change a placeholder;
    ``env_kwargs_typed`` (``format/options.py``) holds them all exactly (a tuple, a numpy value,
    ``inf``, an int key). Raises :class:`~episode_audit.errors.ReplayError` for kwargs too large
    or deep to build from, a placeholder with no typed form, or a typed form episode-audit did
    not write.
    """
    kwargs = layout.get("env_kwargs") or {}
    typed = layout.get("env_kwargs_typed")
    if typed is None:
        _check_env_kwargs(kwargs)
        return dict(kwargs)
    try:
        if not isinstance(typed, str):
            raise ValueError("env_kwargs_typed is not text")
        if len(typed) > MAX_ENV_KWARGS_BYTES:
            raise ValueError(
                f"env_kwargs_typed is {len(typed)} bytes, more than the {MAX_ENV_KWARGS_BYTES} "
                "replay builds an env from"
            )
        exact = decode_typed(typed)
        if not isinstance(exact, dict):
            raise ValueError("env_kwargs_typed is not a dict")
    except ValueError as exc:
        raise ReplayError(f"the recorded env kwargs: {exc}; {_WAY_AROUND}") from None
    _check_depths(exact, "env kwarg")
    return exact


def _from_pettingzoo_module(
    layout: Mapping[str, Any], kwargs: dict[str, Any], parallel: bool, trust_entry_points: bool
) -> Any:
    """The env of the recorded ``env_module``, made with ``kwargs``: PettingZoo's own, or any.

    Any other module only with ``trust_entry_points``.
    """
    from ..record.pettingzoo import is_pettingzoo_module

    env_id = layout.get("env_id")
    unknown_id = (
        f"env id {env_id!r} is not registered in this process's PettingZoo "
        f"{'parallel' if parallel else 'AEC'} registry and "
        if isinstance(env_id, str)
        else ""
    )
    module_name = layout.get("env_module")
    if not isinstance(module_name, str) or not module_name:
        raise ReplayError(
            f"{unknown_id}the file names no PettingZoo env module; pass --env-factory"
        )
    if not is_pettingzoo_module(module_name) and not trust_entry_points:
        raise ReplayError(
            f"{unknown_id}env module {module_name!r} is not one of PettingZoo's own; pass "
            "--env-factory MODULE:CALLABLE, or --trust-entry-points to import it"
        )
    try:
        with warnings.catch_warnings():  # PettingZoo 1.27 deprecates importing env modules
            warnings.simplefilter("ignore", DeprecationWarning)
            module = importlib.import_module(module_name)
        make = getattr(module, "parallel_env" if parallel else "env")
        return make(**kwargs)
    except Exception as exc:
        raise ReplayError(
            f"cannot make {module_name} with the recorded kwargs {kwargs!r}: "
            f"{type(exc).__name__}: {exc}"
        ) from None


def shown_value(value: Any) -> str:
    """A value in a mismatch reason: JSON, cut to 120 characters."""
    try:
        text = json.dumps(value, sort_keys=True)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 120 else text[:117] + "..."
