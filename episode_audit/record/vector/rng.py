"""The sub-envs' RNG states, so that episodes a vector env resets by itself replay on their own.

- :class:`ResetRngInfo` — a sub-env wrapper that puts the RNG state from just before an unseeded
  reset into the reset's info (for ``SAME_STEP`` autoresets, which run inside ``step()``), and
  the state snapshot of the wrappers below it (:mod:`..state`) before every reset.
- :class:`SubEnvRng` — where the recorder reads the states: from the sub-envs (in this process:
  ``SyncVectorEnv``, SB3's ``DummyVecEnv``; in workers, ``AsyncVectorEnv``, SB3's
  ``SubprocVecEnv``, through their :class:`ResetRngInfo`, whose answer cannot end a worker, else
  through ``get_attr("np_random")`` when it is known to be safe: :mod:`.workers`) or from the
  reset infos.

Which mode reads them when, and why: ``docs/format.md``, "Vector files".
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from ..._jobs import unpicklable
from ...format import names as fmt
from ...format.wrappers import LAYOUT_UNSAVED_STATE
from .. import native
from ..gym import reward_wrappers
from ..notes import note
from ..rules import find_wrapper
from ..seeding import capture_rng_state
from ..state import StateTargets, adapter_for_entry_point
from .workers import RngUnsendable, unsendable

__all__ = [
    "REWARD_WRAPPERS",
    "RNG_STATE_IF_READABLE",
    "SPEC_IF_SENDABLE",
    "LocalSubEnvs",
    "RemoteSubEnvs",
    "ResetRngInfo",
    "SubEnvRng",
]

RngState = dict[str, Any]

SPEC_IF_SENDABLE = "episode_audit_spec"
"""The method of :class:`ResetRngInfo` giving the sub-env's spec when a worker can send it."""

REWARD_WRAPPERS = "episode_audit_reward_wrappers"
"""The method of :class:`ResetRngInfo` naming the reward-changing wrappers below it, in order."""

RNG_STATE_IF_READABLE = "episode_audit_rng_state"
"""The method of :class:`ResetRngInfo` giving the sub-env's RNG state as JSON text, or why not."""


class LocalSubEnvs(Protocol):
    """A vector env whose sub-envs live in this process (``SyncVectorEnv``, SB3 ``DummyVecEnv``)."""

    envs: Any  # the list of sub-envs (replaced in place to install ResetRngInfo)


class RemoteSubEnvs(Protocol):
    """A vector env whose sub-envs are asked by name (``AsyncVectorEnv``, SB3 ``SubprocVecEnv``)."""

    def get_attr(self, name: str, /) -> Any:
        """Each sub-env's attribute ``name``, in a sequence."""


class ResetRngInfo(gym.Wrapper[Any, Any, Any, Any]):
    """Put the env's RNG state from just before an unseeded ``reset()`` into its info.

    The state (``env.unwrapped.np_random.bit_generator.state``) goes to
    ``info["episode_audit.rng_state"]`` as JSON text. :class:`RecordVectorEvidence` reads it to make
    episodes that a vector env resets by itself replayable on their own. Before every reset it
    also snapshots the wrappers below it that have a state adapter (e.g. ``NormalizeObservation``)
    into ``info["episode_audit.state"]`` (a snapshot that fails: the note saying why into
    ``info["episode_audit.state_note"]``): wrap it outermost. The wrapper changes nothing else,
    and it is invisible in the env's spec (replay does not need it).

    It also remembers its last step since a reset, and a reset that raised (with that step and
    the RNG state it started from), so that the recorder of a ``SyncVectorEnv`` can record an
    autoreset that raised inside ``step()`` where it belongs: after the step that ended the
    episode, as an episode of its own that ended ``error`` during ``reset``. And it keeps the
    RNG state it last wrote until a recorder in this process takes it: the recorder need not
    parse its own text back.

    >>> import gymnasium as gym
    >>> env = ResetRngInfo(gym.make("CartPole-v1"))
    >>> _, info = env.reset(seed=1)
    >>> "episode_audit.rng_state" in info
    False
    >>> _, info = env.reset()
    >>> sorted(json.loads(info["episode_audit.rng_state"]))
    ['bit_generator', 'has_uint32', 'state', 'uinteger']
    """

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self._state = StateTargets(env)
        self.episode_audit_snapshots = bool(self._state)
        """Whether it snapshots state (an adapted wrapper or env is below it)."""
        self._last_step: tuple[Any, Any] | None = None  # (action, result) since the last reset
        self._rng_json = native.rng_json_function()
        # the RNG text the last reset's info got, and the state it was written from
        self._issued: tuple[str, RngState] | None = None
        # a reset that raised: (the exception, the RNG state before it, the step before it)
        self._failed_reset: tuple[BaseException, Any, tuple[Any, Any] | None] | None = None

    def step(self, action: Any) -> Any:
        """Step the env (remembering the step until the next reset)."""
        result = self.env.step(action)
        self._last_step = (action, result)
        return result

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the env; an unseeded reset's info gains the RNG state it started from.

        Every reset's info gains the state snapshot taken before it, if there is state to take
        (or the note saying why it could not be taken).
        """
        noted: list[str] = []
        snapshot = self._state.capture(noted) if self._state else None
        state = capture_rng_state(self.env) if seed is None else None
        last, self._last_step = self._last_step, None
        self._issued = None
        try:
            result = self.env.reset(seed=seed, options=options)
        except Exception as exc:
            self._failed_reset = (exc, state, last)
            raise
        self._failed_reset = None
        obs, info = result
        if state is not None:
            text = self._rng_json(state).decode()
            self._issued = (text, state)
            info = {**info, fmt.INFO_RNG_STATE: text}
        if snapshot is not None:
            info = {**info, fmt.INFO_STATE: snapshot}
        elif noted:
            info = {**info, fmt.INFO_STATE_NOTE: noted[0]}
        return obs, info

    @property
    def spec(self) -> Any:  # type: ignore[override]
        """The wrapped env's spec: this wrapper only observes."""
        return self.env.spec

    def episode_audit_spec(self) -> tuple[bool, Any]:
        """``(True, spec)`` when a worker's pipe can send :attr:`spec`, else ``(False, None)``.

        ``spec`` is ``None`` when the env has none. A ``SubprocVecEnv`` or ``AsyncVectorEnv``
        worker that fails to pickle its answer ends (a lambda in a wrapper's kwargs), so a
        recorder asks this (:data:`SPEC_IF_SENDABLE`) rather than for ``spec``; it never raises.
        """
        try:
            spec = self.env.spec
        except Exception:
            return False, None
        if unpicklable(spec) is not None:  # (as a worker's pipe sends it)
            return False, None
        return True, spec

    def episode_audit_reward_wrappers(self) -> list[str]:
        """The entry points of the wrappers below it that change the reward, innermost first.

        What a recorder asks a worker's sub-env (:data:`REWARD_WRAPPERS`) whose spec does not
        name them: walked in the worker, in their order (``record.gym.reward_wrappers``, as a
        sub-env in the recorder's process is). Never raises; strings always pickle.
        """
        return reward_wrappers(self.env)

    def episode_audit_rng_state(self) -> tuple[str | None, str | None]:
        """``(state, None)``: the env's RNG state now as JSON text; else ``(None, why)``.

        What a recorder asks a worker's sub-env (:data:`RNG_STATE_IF_READABLE`) rather than
        ``np_random``, whose answer may raise or not pickle, either of which ends the worker.
        Never raises; the answer is two strings or ``None``s, which always pickle.
        """
        try:
            state = self.env.unwrapped.np_random.bit_generator.state
            if not isinstance(state, dict):
                return None, "its np_random's bit_generator.state is not a dict"
            return self._rng_json(state).decode(), None
        except Exception as exc:
            return None, f"reading its np_random raised {type(exc).__name__}"

    def _issued_state(self, text: str) -> RngState | None:
        """The state this wrapper wrote as ``text`` into its last reset's info (taken once).

        ``None`` unless ``text`` is that very string: the recorder then parses the text.
        """
        issued = self._issued
        if issued is None or issued[0] is not text:
            return None
        self._issued = None
        return issued[1]

    def _take_failed_reset(self, exc: BaseException) -> tuple[Any, Any] | None:
        """``(RNG state, (action, result) of the step before)`` if its reset raised ``exc``.

        Forgotten once taken.
        """
        failed = self._failed_reset
        if failed is None or failed[0] is not exc:
            return None
        self._failed_reset = None
        return failed[1], failed[2]


def _all_have(remote: Any, name: str) -> bool:
    """Whether every worker's sub-env has the attribute ``name`` (asked safely).

    SB3's ``VecEnv.has_attr``; Gymnasium's ``AsyncVectorEnv.call("has_wrapper_attr", name)``.
    """
    has_attr = getattr(remote, "has_attr", None)
    if has_attr is not None:
        return bool(has_attr(name))
    call = getattr(remote, "call", None)
    return call is not None and all(call("has_wrapper_attr", name))


def _remote_reads(remote: Any) -> bool:
    """Whether every worker's sub-env of ``remote`` has :data:`RNG_STATE_IF_READABLE`."""
    try:
        return remote is not None and _all_have(remote, RNG_STATE_IF_READABLE)
    except Exception:
        return False


def _ask_remote(remote: Any, indices: Sequence[int]) -> dict[int, tuple[Any, Any]]:
    """Each of sub-envs ``indices``' answer to :data:`RNG_STATE_IF_READABLE`.

    SB3's ``env_method`` asks those only; Gymnasium's ``AsyncVectorEnv.call`` asks every one.
    """
    env_method = getattr(remote, "env_method", None)
    if env_method is not None:
        return dict(
            zip(indices, env_method(RNG_STATE_IF_READABLE, indices=list(indices)), strict=True)
        )
    return dict(enumerate(remote.call(RNG_STATE_IF_READABLE)))


def _np_randoms(
    remote: Any, indices: Sequence[int], whys: dict[int, str | None], *, sb3: bool
) -> dict[int, RngState | None]:
    """The RNG states of sub-envs ``indices`` from each worker's ``np_random``.

    Only those whose ``whys`` is ``None`` (known safe to ask) are asked: an ``sb3`` VecEnv's
    ``get_attr`` asks those only, Gymnasium's asks every one (each is then safe to ask).
    """
    ask = [i for i in indices if whys.get(i) is None]
    out: dict[int, RngState | None] = dict.fromkeys(indices)
    if not ask:
        return out
    try:
        if sb3:
            generators = dict(zip(ask, remote.get_attr("np_random", indices=ask), strict=True))
        else:
            generators = dict(enumerate(remote.get_attr("np_random")))
    except Exception:
        return out
    for i in ask:
        try:
            state = generators[i].bit_generator.state
            out[i] = state if isinstance(state, dict) else None
        except Exception:
            out[i] = None
    return out


class SubEnvRng:
    """Where a vector recorder reads its sub-envs' RNG states (``None`` where unknown).

    Read from outside (:meth:`capture`) until the sub-envs report them in their reset infos
    (:meth:`from_info`, :class:`ResetRngInfo`); from then on only from the infos (``in_info``).
    """

    def __init__(
        self,
        sync: LocalSubEnvs | None,
        async_env: RemoteSubEnvs | None,
        unaskable: str | None = None,
    ) -> None:
        self.sync = sync
        self._async = async_env
        # the sub-envs' unwrapped envs, whose np_random resets draw from (Sync only)
        self._sync_unwrapped = [] if sync is None else [e.unwrapped for e in sync.envs]
        self.in_info = False
        # why the states last read from workers are unknown, by sub-env
        self.unread: dict[int, str] = {}
        # whether the workers' sub-envs answer RNG_STATE_IF_READABLE (a ResetRngInfo)
        self._remote_reads = _remote_reads(async_env)
        # why an AsyncVectorEnv's workers may not be asked for np_random, from a sub-env built
        # here (:func:`~.workers.rng_unaskable`; SB3's are asked first: ``unsendable``)
        self._unaskable = unaskable
        # each sub-env's ResetRngInfo (Sync only, once installed): its states need no parsing
        self._issuers: list[ResetRngInfo | None] = []
        self.installed = [False] * (0 if sync is None else len(sync.envs))
        """Per sub-env, whether :meth:`install_wrappers` put its :class:`ResetRngInfo` there
        (whose info keys the training loop must not see: :func:`without_installed`)."""

    def snapshots(self, *, installing: bool) -> bool:
        """Whether a sub-env's resets are snapshot (:mod:`..state`), by a :class:`ResetRngInfo`.

        A sub-env's are when it has state to snapshot and a :class:`ResetRngInfo` puts it into
        each reset's info. Sub-envs in this process are looked at directly (they are snapshot
        when the recorder is ``installing`` a :class:`ResetRngInfo` on each); those in workers
        (an ``AsyncVectorEnv``'s, an SB3 ``SubprocVecEnv``'s) are asked whether they are wrapped
        in a :class:`ResetRngInfo` that snapshots, after they all say they have the attribute
        (a worker asked for an attribute its env lacks raises, and ends).
        """
        if self.sync is not None:
            return installing and any(StateTargets(sub) for sub in self.sync.envs)
        remote = self._async
        name = "episode_audit_snapshots"
        try:
            return remote is not None and _all_have(remote, name) and any(remote.get_attr(name))
        except Exception:
            return False

    def unsaved_state(self, spec: Any, snapshots: bool) -> dict[str, Any]:
        """The layout entry naming the sub-envs' own state nothing snapshots; ``{}`` if none.

        ``snapshots``: as :meth:`snapshots` said. A sub-env in this process is looked at, one
        in a worker known by its ``spec``'s entry point: the state adapter of its unwrapped env
        (ALE's ``AtariEnv``; :func:`~..state.adapter_for_entry_point`). Read by
        :func:`~episode_audit.format.wrappers.unsaved_state`.
        """
        if snapshots:
            return {}
        env: Any = None
        try:
            if self.sync is not None and self.sync.envs:
                env = type(self.sync.envs[0].unwrapped)
            elif self._async is not None:
                env = getattr(spec, "entry_point", None)
        except Exception:  # an env's own attribute access: unknown
            return {}
        adapter = adapter_for_entry_point(env)
        if adapter is None:
            return {}
        name = env.rpartition(":")[2] if isinstance(env, str) else env.__name__
        entry = {"env": name[:80], "adapter": str(adapter.name)[:80], "needed": adapter.needed}
        return {LAYOUT_UNSAVED_STATE: entry}

    def state_from_info(self, info: Any) -> tuple[str | None, str | None]:
        """``(snapshot, note)`` :class:`ResetRngInfo` put in a reset info, each if any.

        The snapshot is JSON text; the note (``state_unavailable``) says why it took none.
        """
        if not isinstance(info, Mapping):
            return None, None
        text = info.get(fmt.INFO_STATE)
        if isinstance(text, str):
            return text, None
        why = info.get(fmt.INFO_STATE_NOTE)
        if not isinstance(why, str):
            return None, None
        return None, note("state_unavailable", why.removeprefix("state_unavailable: "))

    def install_wrappers(self) -> None:
        """Wrap every sub-env of the ``SyncVectorEnv`` in :class:`ResetRngInfo` (in place)."""
        if self.sync is None:
            return
        envs = self.sync.envs
        for i, sub in enumerate(envs):
            if find_wrapper(sub, ResetRngInfo) is None:
                envs[i] = ResetRngInfo(sub)
                self.installed[i] = True
        self._issuers = [find_wrapper(sub, ResetRngInfo) for sub in envs]
        self.in_info = True

    def capture(self, indices: Sequence[int]) -> dict[int, RngState | None]:
        """The RNG states of sub-envs ``indices`` now (``None`` where unknown)."""
        if not indices:
            return {}
        if self.sync is not None:
            envs = self._sync_unwrapped
            return {i: capture_rng_state(envs[i]) for i in indices}
        if self._async is not None:
            return self._remote_capture(indices)
        return dict.fromkeys(indices)

    def _remote_capture(self, indices: Sequence[int]) -> dict[int, RngState | None]:
        """The RNG states of workers' sub-envs ``indices``, asked of their :class:`ResetRngInfo`.

        It answers JSON text or why not, never raising, where ``np_random`` may raise or not
        pickle, either of which ends the worker. Why a state is unknown goes to :attr:`unread`.
        """
        self.unread = {}
        if not self._remote_reads:
            return self._unwrapped_capture(indices)
        out: dict[int, RngState | None] = dict.fromkeys(indices)
        try:
            answers = _ask_remote(self._async, indices)
        except Exception as exc:
            self.unread = dict.fromkeys(indices, f"asking its worker raised {type(exc).__name__}")
            return out
        for i in indices:
            text, why = answers[i]
            try:
                state = json.loads(text) if isinstance(text, str) else None
            except ValueError:
                state = None
            if isinstance(state, dict):
                out[i] = state
            else:
                self.unread[i] = f"its ResetRngInfo could not read it: {why}"
        return out

    def _unwrapped_capture(self, indices: Sequence[int]) -> dict[int, RngState | None]:
        """The RNG states of workers' sub-envs ``indices`` without a :class:`ResetRngInfo`.

        A worker is asked for ``np_random`` only when the answer is known to be safe: an SB3
        VecEnv's workers are asked first (:func:`~.workers.unsendable`), an ``AsyncVectorEnv``'s
        are known by a sub-env built here (:func:`~.workers.rng_unaskable`). Why a state is not
        asked for goes to :attr:`unread`.
        """
        remote = self._async
        sb3 = hasattr(remote, "env_is_wrapped")  # (an SB3 VecEnv)
        if sb3:
            whys = unsendable(remote, RngUnsendable, indices)
        else:
            whys = dict.fromkeys(indices, self._unaskable)
        self.unread = {
            i: f"its worker was not asked for its np_random, which could end it: {why}; wrap "
            "each sub-env in episode_audit.ResetRngInfo"
            for i, why in whys.items()
            if why is not None
        }
        return _np_randoms(remote, indices, whys, sb3=sb3)

    def from_info(self, info: Any, i: int | None = None) -> RngState | None:
        """The state :class:`ResetRngInfo` put in a reset info (then it is always used).

        ``i``: the sub-env whose info it is; when its wrapper here wrote the text, the state it
        wrote it from (the text is not parsed back).
        """
        if not isinstance(info, Mapping):
            return None
        text = info.get(fmt.INFO_RNG_STATE)
        if not isinstance(text, str):
            return None
        issuers = self._issuers
        issuer = issuers[i] if i is not None and i < len(issuers) else None
        state = None if issuer is None else issuer._issued_state(text)
        if state is None:
            try:
                state = json.loads(text)
            except ValueError:
                return None
            if not isinstance(state, dict):
                return None
        self.in_info = True  # the sub-envs report it: no need to read it from outside
        return state

    def failed_resets(self, exc: BaseException) -> dict[int, tuple[Any, Any]]:
        """The sub-envs whose :class:`ResetRngInfo` saw its reset raise ``exc`` (Sync only).

        ``{i: (RNG state before the reset, (action, result) of the step before it)}``.
        """
        out: dict[int, tuple[Any, Any]] = {}
        if self.sync is None:
            return out
        for i, sub in enumerate(self.sync.envs):
            wrapper = find_wrapper(sub, ResetRngInfo)
            failed = None if wrapper is None else wrapper._take_failed_reset(exc)
            if failed is not None:
                out[i] = failed
        return out


OWN_INFO_KEYS = (fmt.INFO_RNG_STATE, fmt.INFO_STATE, fmt.INFO_STATE_NOTE)
"""The info keys :class:`ResetRngInfo` adds to a reset's info."""


def has_own_keys(infos: Any) -> bool:
    """Whether a vector env's ``infos`` hold a key of :data:`OWN_INFO_KEYS`.

    ``infos``: a dict (three looks), or ``DictInfoToList``'s list of a dict per sub-env.
    """
    if type(infos) is list:
        return any(_has_own(info) for info in infos)
    return _has_own(infos)


def _has_own(info: Any) -> bool:
    """Whether ``info`` is a dict holding a key of :data:`OWN_INFO_KEYS` (three looks)."""
    return type(info) is dict and (
        fmt.INFO_RNG_STATE in info or fmt.INFO_STATE in info or fmt.INFO_STATE_NOTE in info
    )


def without_own_keys(info: Any) -> Any:
    """``info`` without the keys of :data:`OWN_INFO_KEYS` (a copy), or itself when it has none.

    >>> without_own_keys({"episode_audit.rng_state": "{}", "x": 1}), without_own_keys(None)
    ({'x': 1}, None)
    """
    if not _has_own(info):
        return info
    return {k: v for k, v in info.items() if k not in OWN_INFO_KEYS}


def without_installed(infos: Any, installed: Sequence[bool]) -> Any:
    """A copy of a vector env's ``infos`` without what the recorder's own wrappers put there.

    ``installed``: per sub-env, whether its :class:`ResetRngInfo` is the recorder's
    (:attr:`SubEnvRng.installed`). A list (``DictInfoToList``'s) loses those keys from the
    dicts of those sub-envs. Of a dict, a key (and its ``_`` mask) goes when only those
    sub-envs have it; one that a user's own :class:`ResetRngInfo` also wrote stays, for those
    sub-envs only.
    """
    if type(infos) is list:
        return [
            without_own_keys(info) if i < len(installed) and installed[i] else info
            for i, info in enumerate(infos)
        ]
    out = dict(infos)
    mine = np.asarray(installed, dtype=bool)
    for key in OWN_INFO_KEYS:
        if key not in out:
            continue
        mask = out.get(f"_{key}")
        known = isinstance(mask, np.ndarray) and mask.shape == mine.shape
        theirs = (np.asarray(mask, dtype=bool) if known else np.ones_like(mine)) & ~mine
        if not theirs.any():
            del out[key]
            out.pop(f"_{key}", None)
            continue
        values = np.array(out[key], dtype=object)
        values[mine] = None
        out[key], out[f"_{key}"] = values, theirs
    return out
