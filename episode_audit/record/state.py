"""State adapters: the state of an env or wrapper beyond its seed, snapshot at each reset.

A :class:`StateAdapter` reads an object's state as data (numpy arrays, bytes, JSON values)
and sets it back. The recorder walks the env's wrapper chain once, finds the objects an
adapter is registered for (:func:`register_state_adapter`, by class or ``"module:Class"``),
and snapshots them before every ``reset()`` (:class:`StateTargets`); replay builds the env,
then :func:`restore_snapshot` sets each state before the episode's ``reset(seed)``. Snapshots
are data (:mod:`episode_audit.format.state`): never pickled. Shipped adapters:
:mod:`.adapters`; how to write one: docs/recording.md, "State snapshots".
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator, Mapping
from typing import Any, Literal, Protocol, runtime_checkable

from ..errors import ConfigurationError
from ..format.state import MAX_STATE_TEXT, StateValue, decode_snapshot, encode_snapshot
from .notes import note

__all__ = [
    "StateAdapter",
    "StateTargets",
    "adapter_for",
    "adapter_for_entry_point",
    "chain",
    "register_state_adapter",
    "restore_snapshot",
]

_MAX_CHAIN = 256  # wrappers walked at most (a chain that loops stops there)


@runtime_checkable
class StateAdapter(Protocol):
    """Reads and sets the state of one kind of env or wrapper, as data.

    ``name`` is stored in the file with each snapshot (stable, e.g.
    ``"gymnasium.NormalizeObservation"``); ``needed`` says which episodes cannot replay
    without a snapshot: ``"always"`` (state that carries across episodes, such as running
    statistics) or ``"unseeded"`` (state a seeded ``reset()`` sets anew, such as an emulator's
    RNG). ``get_state`` returns a mapping of string keys to numpy arrays (numeric or bool),
    ``bytes`` or JSON values (finite numbers); ``set_state`` puts such a mapping back.
    """

    @property
    def name(self) -> str:
        """The adapter's name, stored with each snapshot."""
        ...

    @property
    def needed(self) -> Literal["always", "unseeded"]:
        """Which episodes cannot replay without a snapshot."""
        ...

    def get_state(self, obj: Any) -> Mapping[str, StateValue]:
        """The state of ``obj`` now."""
        ...

    def set_state(self, obj: Any, state: Mapping[str, StateValue]) -> None:
        """Give ``obj`` exactly ``state`` (as :meth:`get_state` returned it)."""
        ...


_ADAPTERS: dict[str, StateAdapter] = {}
_BY_TYPE: dict[type, StateAdapter | None] = {}


def register_state_adapter(
    target: type | str, adapter: StateAdapter, *, replace: bool = False
) -> None:
    """Snapshot every ``target`` (a class, or ``"module:QualName"``) with ``adapter``.

    Subclasses are covered too (the nearest registered class wins). A string target does not
    import its module: adapters for optional libraries cost nothing until such an env is used.
    Raises :class:`~episode_audit.errors.ConfigurationError` when ``adapter`` lacks the protocol,
    or the target has an adapter already (unless ``replace``).

    >>> class Counter:
    ...     name, needed = "demo.Counter", "always"
    ...     def get_state(self, obj): return {"n": obj.n}
    ...     def set_state(self, obj, state): obj.n = state["n"]
    >>> register_state_adapter("my_package.envs:CountingEnv", Counter(), replace=True)
    """
    if isinstance(target, type):
        key = _key(target)
    elif isinstance(target, str) and _TARGET.fullmatch(target):
        key = target
    else:
        raise ConfigurationError(
            f"register_state_adapter: expected a class or a 'module:QualName' string as the "
            f"target, got {target!r}; pass e.g. MyEnv or 'my_package.envs:MyEnv'"
        )
    if not isinstance(adapter, StateAdapter) or getattr(adapter, "needed", None) not in (
        "always",
        "unseeded",
    ):
        raise ConfigurationError(
            f"register_state_adapter({key!r}): expected an adapter with name, needed "
            f"('always' or 'unseeded'), get_state and set_state, got {type(adapter).__name__}"
        )
    if key in _ADAPTERS and not replace and _ADAPTERS[key] is not adapter:
        raise ConfigurationError(
            f"register_state_adapter({key!r}): it has the adapter {_ADAPTERS[key].name!r} "
            "already; pass replace=True to replace it"
        )
    _ADAPTERS[key] = adapter
    _BY_TYPE.clear()


_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")
"""A string target: ``module:QualName``, as :func:`_key` names a class."""


def _key(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def adapter_for(obj: Any) -> StateAdapter | None:
    """The adapter registered for ``obj``'s class or its nearest base class, if any."""
    cls = type(obj)
    try:
        return _BY_TYPE[cls]
    except KeyError:
        pass
    found = next((_ADAPTERS[k] for k in map(_key, cls.__mro__) if k in _ADAPTERS), None)
    _BY_TYPE[cls] = found
    return found


def adapter_for_entry_point(entry_point: Any) -> StateAdapter | None:
    """The adapter of the env a spec's ``entry_point`` builds, if known, without importing it.

    A ``"module:Class"`` string: the adapter registered for it, else (its module imported
    already) for its class or nearest base class; a class: that class's. ``None`` otherwise.

    >>> adapter_for_entry_point("ale_py.env:AtariEnv").name
    'ale_py.AtariEnv'
    """
    cls: Any = entry_point
    if isinstance(entry_point, str):
        if entry_point in _ADAPTERS:
            return _ADAPTERS[entry_point]
        module, _, name = entry_point.partition(":")
        cls = sys.modules.get(module)
        try:
            for part in name.split(".") if cls is not None and name else ():
                cls = getattr(cls, part, None)
        except Exception:  # a module's own __getattr__: unknown
            return None
    if not isinstance(cls, type):
        return None
    return next((_ADAPTERS[k] for k in map(_key, cls.__mro__) if k in _ADAPTERS), None)


def chain(env: Any) -> Iterator[Any]:
    """``env`` and what it wraps, outermost first (``.env`` of wrappers, ``.venv`` of SB3's)."""
    seen: set[int] = set()
    while env is not None and id(env) not in seen and len(seen) < _MAX_CHAIN:
        seen.add(id(env))
        yield env
        inner = _inner(env, "env")
        env = inner if inner is not None else _inner(env, "venv")


def _inner(env: Any, name: str) -> Any:
    """``env``'s own attribute ``name``, or ``None``.

    Read with ``object.__getattribute__``: no ``__getattr__`` forwarding (SB3's wrappers pass
    unknown names to what they wrap), and never through ``__dict__``, whose first access gives
    the object a real dict for good, and every later attribute read on it (each step's) the
    interpreter's slow path.
    """
    try:
        return object.__getattribute__(env, name)
    except Exception:  # no such attribute, or a property that raised: the chain ends here
        return None


class StateTargets:
    """The adapted objects of an env's wrapper chain, found once, snapshot at each reset."""

    def __init__(self, env: Any) -> None:
        self.targets = [(obj, a) for obj in chain(env) if (a := adapter_for(obj)) is not None]

    def __bool__(self) -> bool:
        return bool(self.targets)

    def capture(self, notes: list[str]) -> str | None:
        """The snapshot's JSON text (``None`` if there is nothing to snapshot, or it failed).

        Never raises: an adapter that raises, or a state too large, is noted
        (``state_unavailable``) and that episode is recorded without a snapshot.
        """
        if not self.targets:
            return None
        try:
            text = encode_snapshot([(a.name, a.get_state(obj)) for obj, a in self.targets])
        except Exception as exc:
            notes.append(note("state_unavailable", f"{type(exc).__name__}: {exc}"[:300]))
            return None
        if len(text) > MAX_STATE_TEXT:
            notes.append(
                note(
                    "state_unavailable",
                    f"the state snapshot is {len(text)} bytes, more than {MAX_STATE_TEXT}",
                )
            )
            return None
        return text


def restore_snapshot(env: Any, text: str | None, *, seeded: bool) -> list[str]:
    """Set the state of ``env``'s adapted objects from a snapshot; say what was restored.

    Returns the class name of each object restored, e.g. ``["NormalizeObservation"]``. Raises
    ``ValueError`` (the reason the episode is not replayable) when the snapshot is not one
    episode-audit wrote, when an object whose state the episode needs (``seeded``: its reset
    had a seed) has no snapshot, or when the rebuilt env has no object for a recorded one.
    """
    entries = decode_snapshot(text) if text else []
    targets = StateTargets(env).targets
    pending: dict[str, list[Mapping[str, StateValue]]] = {}
    for name, state in entries:
        pending.setdefault(name, []).append(state)
    restored: list[str] = []
    for obj, adapter in targets:
        states = pending.get(adapter.name)
        if not states:
            if adapter.needed == "always" or not seeded:
                raise ValueError(
                    f"the env's {type(obj).__name__} keeps state a seed does not set, and the "
                    f"file holds no {adapter.name} snapshot for this episode's reset"
                )
            continue
        try:
            adapter.set_state(obj, states.pop(0))
        except Exception as exc:
            raise ValueError(
                f"the recorded {adapter.name} snapshot does not fit the rebuilt env's "
                f"{type(obj).__name__}: {type(exc).__name__}: {exc}"[:400]
            ) from None
        restored.append(type(obj).__name__)
    left = [name for name, states in pending.items() if states]
    if left:
        raise ValueError(
            f"the file holds a {left[0]} snapshot, and the rebuilt env has nothing it restores "
            "into (build the env as it was recorded)"
        )
    return restored
