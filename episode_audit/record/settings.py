"""The recorder's options, declared and checked once, and the run metadata of a recording.

- :class:`RecorderOptions` — the keyword options every recorder takes (``**options``).
- :class:`RecorderSettings` — those options checked, with their defaults (documented there).
- :func:`run_info` and :func:`library_versions` — the run metadata a recording starts with.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import os
import platform
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime, timezone
from typing import Any, TypedDict

import gymnasium as gym
import numpy as np
import pyarrow as pa
from typing_extensions import Unpack

from .._version import __version__
from ..errors import ConfigurationError
from ..format import names as fmt
from ..format.options import LAYOUT_SPEC_KWARGS_TYPED, typed_spec_kwargs
from ..format.records import MAX_JSON_TEXT, RunInfo, to_json
from ..format.unrecorded import placeholders, spec_placeholders
from ..format.wrappers import RECORDED_WRAPPERS, RUN_TRANSPARENT_WRAPPERS
from .rules import EndingRules, RewardTerms, TermsFn, check_constants

__all__ = [
    "DEFAULT_BLOCK_STEPS",
    "KNOWN_TERMS",
    "RecorderOptions",
    "RecorderSettings",
    "STEP_LIBRARIES",
    "check_options",
    "library_versions",
    "run_info",
]

DEFAULT_BLOCK_STEPS = 32_768
"""Steps per columnar block unless told otherwise. Larger blocks cost the recorder a little
memory (flushes every ``flush_every_s`` bound what a crash can lose either way) and make every
read faster: ``check`` decodes a 1 M-step CartPole file ~25 % faster than with 8 192."""


KNOWN_TERMS: Mapping[str, RewardTerms] = {
    # reward = alive bonus - distance penalty - velocity penalty; only the first key has the
    # reward_ prefix "auto" reads (the penalties are in info as negative numbers)
    "InvertedDoublePendulum-v5": RewardTerms(
        ("reward_survive", "distance_penalty", "velocity_penalty")
    ),
    # reward = uph_cost + 1 - quad_ctrl_cost - quad_impact_cost: the 1 is in no info key
    "HumanoidStandup-v5": RewardTerms("auto", {"constant_bonus": 1.0}),
    "HumanoidStandup-v4": RewardTerms("auto", {"constant_bonus": 1.0}),
}
"""The reward terms of the Gymnasium envs whose ``info["reward_*"]`` keys alone do not sum to
their reward, by env id: a recorder given no ``reward_terms`` nor ``constant_terms`` reads
these (:meth:`RecorderSettings.use_known_terms`). Every other MuJoCo v5 and v4 env's keys sum
to its reward, or it has none (``tests/record/test_known_terms.py`` checks them all)."""


class RecorderOptions(TypedDict, total=False):
    """The keyword options every recorder takes; :class:`RecorderSettings` says what each means."""

    tags: Mapping[str, str] | None
    reward_terms: RewardTerms | str | Sequence[str] | TermsFn | None
    constant_terms: Mapping[str, float] | None
    ending_rules: EndingRules | None
    info_keys: Sequence[str] | str
    digest_min_bytes: int | None
    block_steps: int
    flush_every_s: float
    fsync: bool
    overwrite: bool
    command_line: Sequence[str] | None
    transparent_wrappers: Sequence[str | type] | None


_OPTIONS = frozenset(RecorderOptions.__annotations__)


def check_options(options: Mapping[str, Any], caller: str) -> None:
    """Refuse an option no recorder takes, as Python refuses an unknown keyword of ``caller``.

    >>> check_options({"reward_term": None}, "RecordEvidence.__init__()")
    Traceback (most recent call last):
    TypeError: RecordEvidence.__init__() got an unexpected keyword argument 'reward_term'
    """
    for name in options:
        if name not in _OPTIONS:
            raise TypeError(f"{caller} got an unexpected keyword argument {name!r}")


class RecorderSettings:
    """The recorder options (:class:`RecorderOptions`), checked once, with their defaults.

    Every recorder (``RecordEvidence``, ``RecordVectorEvidence``, ``RecordParallelEvidence``,
    ``RecordAECEvidence``) takes these keyword options:

    Args:
        tags: Free-form run tags (policy name, checkpoint, git commit, ...): a mapping, kept
            as text, up to 1 MiB of JSON in all (what readers accept).
        reward_terms: Where a step's named reward terms come from: ``"auto"`` (default:
            ``info["reward_terms"]`` or ``info["reward_*"]``), a list of info keys, a callable
            ``info -> dict``, a :class:`~episode_audit.RewardTerms`, or ``None``.
        constant_terms: Terms the env adds outside its info, declared once (``check`` adds
            them to every step's sum).
        ending_rules: How success, failure labels and truncation reasons are read (default:
            :class:`~episode_audit.EndingRules`'s defaults).
        info_keys: Info keys to keep per step as JSON: a list of keys, or ``"all"``.
        digest_min_bytes: Store observation arrays of at least this many bytes as a 16-byte
            BLAKE2b digest instead of losslessly (for large images); ``None`` keeps all.
        block_steps: Steps per columnar block (default :data:`DEFAULT_BLOCK_STEPS`; fewer when
            rows are large, so that the chunk of one flush stays under 32 MiB uncompressed).
        flush_every_s: Flush at least this often (default 1 second; checked on every step and
            reset).
        fsync: ``fsync`` the file on every flush.
        overwrite: Allow replacing an existing file (never overwritten otherwise).
        command_line: The command line to store (defaults to ``sys.argv``): strings or
            paths, up to 1 MiB of JSON.
        transparent_wrappers: Your own wrappers that never change a step (a logger, a
            statistics wrapper): classes or ``"module:Class"`` entry points. Stored in the run
            metadata; replay rebuilds the env without them, saying so (a step one of them did
            change diverges). Gymnasium's and SB3's known wrappers keep their own rule.

    Raises:
        ConfigurationError: An option's value is out of its range.
        TypeError: An option no recorder takes.
    """

    __slots__ = (
        "block_steps",
        "command_line",
        "digest_min_bytes",
        "flush_every_s",
        "fsync",
        "info_keys",
        "keep_all_info",
        "overwrite",
        "rules",
        "tags",
        "terms_given",
        "terms_rule",
        "track_info",
        "transparent",
    )

    def __init__(self, **options: Unpack[RecorderOptions]) -> None:
        check_options(options, "RecorderSettings()")
        block_steps = options.get("block_steps", DEFAULT_BLOCK_STEPS)
        flush_every_s = options.get("flush_every_s", 1.0)
        info_keys = options.get("info_keys", ())
        if (isinstance(info_keys, str) and info_keys != "all") or not isinstance(
            info_keys, (str, Iterable)
        ):
            raise ConfigurationError(
                f"info_keys: expected a list of keys or 'all', actually: {info_keys!r}"
            )
        digest = options.get("digest_min_bytes")
        _check_sizes(block_steps, flush_every_s, digest)
        self.terms_given = "reward_terms" in options or "constant_terms" in options
        self.terms_rule = _terms_rule(
            options.get("reward_terms", "auto"), options.get("constant_terms")
        )
        self.rules = _ending_rules(options.get("ending_rules"))
        self.info_keys: tuple[str, ...] | None = None if info_keys == "all" else tuple(info_keys)
        self.keep_all_info = info_keys == "all"
        self.track_info = bool(self.keep_all_info or self.info_keys)
        self.digest_min_bytes = digest
        self.block_steps = int(block_steps)
        self.flush_every_s = flush_every_s
        self.tags = _tags(options.get("tags"))
        self.command_line = _command_line(options.get("command_line"))
        self.fsync = options.get("fsync", False)
        self.overwrite = options.get("overwrite", False)
        self.transparent = _entry_points(options.get("transparent_wrappers"))

    def use_known_terms(self, env_id: str | None) -> None:
        """Read the terms :data:`KNOWN_TERMS` gives ``env_id``, unless terms were given."""
        known = KNOWN_TERMS.get(env_id or "")
        if known is not None and not self.terms_given:
            self.terms_rule = known

    def recorder_metadata(self, notes: Sequence[str] = ()) -> dict[str, Any]:
        """The ``recorder`` key of the run metadata."""
        return {
            "block_steps": self.block_steps,
            "flush_every_s": self.flush_every_s,
            "digest_min_bytes": self.digest_min_bytes,
            "info_keys": "all" if self.keep_all_info else list(self.info_keys or ()),
            "notes": list(notes),
        } | ({RUN_TRANSPARENT_WRAPPERS: list(self.transparent)} if self.transparent else {})


def _check_sizes(block_steps: Any, flush_every_s: Any, digest_min_bytes: Any) -> None:
    """``block_steps=``, ``flush_every_s=`` and ``digest_min_bytes=``, checked."""
    if not (_is_int(block_steps) and block_steps >= 1):
        raise ConfigurationError(
            f"block_steps: expected an integer >= 1, actually: {block_steps!r}"
        )
    if not (_is_number(flush_every_s) and flush_every_s > 0 and math.isfinite(flush_every_s)):
        raise ConfigurationError(
            f"flush_every_s: expected a positive number of seconds, actually: {flush_every_s!r}"
        )
    if digest_min_bytes is not None and not (_is_int(digest_min_bytes) and digest_min_bytes >= 1):
        raise ConfigurationError(
            f"digest_min_bytes: expected an integer >= 1 or None, actually: {digest_min_bytes!r}"
        )


def _terms_rule(reward_terms: Any, constant_terms: Any) -> RewardTerms:
    """The rule of ``reward_terms=`` and ``constant_terms=``, checked."""
    if constant_terms is not None:
        check_constants(constant_terms)
    if isinstance(reward_terms, RewardTerms):
        if not constant_terms:
            return reward_terms
        return RewardTerms(reward_terms.source, {**reward_terms.constants, **constant_terms})
    return RewardTerms(reward_terms, dict(constant_terms or {}))


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _ending_rules(rules: EndingRules | None) -> EndingRules:
    """``ending_rules=``, checked: an :class:`EndingRules` (``None``: the defaults)."""
    if rules is None:
        return EndingRules()
    if not isinstance(rules, EndingRules):
        how = "EndingRules(**rules)" if isinstance(rules, Mapping) else "EndingRules(...)"
        raise ConfigurationError(
            f"ending_rules: expected an EndingRules, actually: {type(rules).__name__}; pass {how}"
        )
    keys = rules.success_keys
    if isinstance(keys, (str, bytes)):  # (its characters would be the keys)
        raise ConfigurationError(
            f"ending_rules: success_keys: expected a sequence of info keys, got the string "
            f"{keys!r}; pass success_keys=({keys!r},)"
        )
    return rules


def _tags(tags: Mapping[str, str] | None) -> dict[str, str] | None:
    """``tags=``, checked: a mapping, its names and values as text, as much as readers read."""
    if tags is None:
        return None
    if not isinstance(tags, Mapping):
        raise ConfigurationError(
            "tags: expected a mapping of names to values, e.g. {'policy': 'ppo'}, actually: "
            f"{type(tags).__name__}"
        )
    out = {str(name): str(value) for name, value in tags.items()}
    _fits("tags", out, f"{len(out)} tags", "keep tags short (names, commits, paths)")
    return out


def _command_line(command_line: Sequence[str] | None) -> list[str] | None:
    """``command_line=``, checked: a list of strings (or paths), as ``sys.argv``."""
    if command_line is None:
        return None
    if isinstance(command_line, (str, bytes)) or not isinstance(command_line, Sequence):
        raise ConfigurationError(
            "command_line: expected a list of strings, as sys.argv, actually: "
            f"{type(command_line).__name__}"
        )
    out = []
    for i, arg in enumerate(command_line):
        if not isinstance(arg, (str, os.PathLike)):
            raise ConfigurationError(
                f"command_line[{i}]: expected a string, as in sys.argv, actually: "
                f"{type(arg).__name__}"
            )
        out.append(os.fsdecode(arg))
    _fits("command_line", out, f"{len(out)} arguments", "record the command, not its data")
    return out


def _fits(name: str, value: Any, what: str, advice: str) -> None:
    """Raise unless ``value``'s JSON is small enough for every reader (:data:`MAX_JSON_TEXT`)."""
    size = len(to_json(value))
    if size > MAX_JSON_TEXT:
        raise ConfigurationError(
            f"{name}: expected at most {MAX_JSON_TEXT} bytes of JSON (what readers accept), "
            f"actually: {size} in {what}; {advice}, and store large data beside the file"
        )


def _entry_points(wrappers: Sequence[str | type] | None) -> tuple[str, ...]:
    """The entry points of ``transparent_wrappers=``, checked."""
    if wrappers is None:
        return ()
    if isinstance(wrappers, (str, type)):
        wrappers = [wrappers]
    out: list[str] = []
    for wrapper in wrappers:
        if isinstance(wrapper, type):
            out.append(f"{wrapper.__module__}:{wrapper.__qualname__}")
        elif isinstance(wrapper, str) and _ENTRY_POINT.fullmatch(wrapper):
            out.append(wrapper)
        else:
            raise ConfigurationError(
                "transparent_wrappers: expected wrapper classes or 'module:Class' entry points, "
                f"actually: {wrapper!r}"
            )
    if len(out) > 64:
        raise ConfigurationError(
            f"transparent_wrappers: expected at most 64 wrappers, actually: {len(out)}"
        )
    return tuple(dict.fromkeys(out))


_ENTRY_POINT = re.compile(r"[A-Za-z_][\w.]{0,200}:[A-Za-z_][\w.]{0,80}")


_LOADED_LIBRARIES = ("mujoco", "pettingzoo", "torch", "jax", "stable_baselines3", "ale_py")
"""Libraries that can change what an env does or how it is stepped (the simulator, the Atari
emulator, SB3's vector envs and wrappers the recorder may sit over), recorded when the process
has imported them: recording never imports one. Not Ray: RLlib steps the envs it is given, the
recorder inside them, and a replay's own ``--ray`` tasks import it."""

STEP_LIBRARIES = frozenset({"python", "numpy", "gymnasium", *_LOADED_LIBRARIES})
"""Of what :func:`library_versions` records, what can change an env's steps (not pyarrow and
mcap, which read and write the file; not episode-audit)."""


def library_versions() -> dict[str, str]:
    """Versions of Python and of the libraries a rollout depends on (those imported).

    >>> {"python", "numpy", "gymnasium", "episode_audit"} <= set(library_versions())
    True
    """
    import mcap

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "gymnasium": gym.__version__,
        "pyarrow": pa.__version__,
        "mcap": getattr(mcap, "__version__", "unknown"),
        "episode_audit": __version__,
    }
    for name in _LOADED_LIBRARIES:
        module = sys.modules.get(name)
        if module is not None:
            versions[name] = str(getattr(module, "__version__", "unknown"))
    return versions


def run_info(
    *,
    settings: RecorderSettings,
    spec: Any,
    observation_space: dict[str, Any],
    action_space: dict[str, Any],
    layout: dict[str, Any],
    notes: Sequence[str] = (),
    info_of: str | None = None,
) -> RunInfo:
    """The run metadata of a recording of an env with ``spec`` (an ``EnvSpec`` or ``None``).

    ``info_of``: the entry point of the object whose ``info`` the recorder reads (the env or
    wrapper it wraps; a sub-env's for a vector recorder), kept in ``reward_terms`` as
    ``info_of`` when the terms are found automatically, so a reader knows whose keys they are.
    A known env's terms (:data:`KNOWN_TERMS`) become ``settings``' first, unless terms were
    given: call this before the streams are made.
    """
    settings.use_known_terms(spec.id if spec is not None else None)
    spec_json: dict[str, Any] | None = None
    notes = list(notes)
    if spec is not None:
        try:
            spec_json, unheld = _spec_json(spec)
        except Exception as exc:
            notes.append(f"env spec is not JSON-serializable ({type(exc).__name__}: {exc})")
        else:
            if unheld:
                notes.append(
                    "env spec recorded with placeholders for what JSON cannot hold: "
                    f"{', '.join(unheld)} (replay needs an env factory to build what takes it)"
                )
            size = len(to_json(spec_json))
            if size > MAX_JSON_TEXT:  # (a reader refuses it: the whole file would be unreadable)
                spec_json = None
                notes.append(
                    f"env spec not recorded: {size} bytes of JSON, over the {MAX_JSON_TEXT} "
                    "readers accept (large make() arguments); not replayable"
                )
            else:  # the kwargs its JSON changes (a tuple), exactly: replay makes the env with them
                typed = typed_spec_kwargs(spec.kwargs or {}, spec_json.get("kwargs") or {})
                if typed is not None:
                    layout = {**layout, LAYOUT_SPEC_KWARGS_TYPED: typed}
    command_line = settings.command_line
    return RunInfo(
        format_version=fmt.FORMAT_VERSION,
        writer=f"episode-audit {__version__}",
        env_id=spec.id if spec is not None else None,
        env_spec=spec_json,
        observation_space=observation_space,
        action_space=action_space,
        reward_terms=_terms(settings, info_of),
        ending_rules=settings.rules.describe(),
        versions=library_versions(),
        platform=platform.platform(),
        command_line=list(sys.argv) if command_line is None else command_line,
        start_time=datetime.now(timezone.utc).isoformat(),
        tags=dict(settings.tags or {}),
        recorder=settings.recorder_metadata(notes),
        layout=layout,
    )


def _spec_json(spec: Any) -> tuple[dict[str, Any], list[str]]:
    """``spec`` as JSON, and the arguments in it that JSON cannot hold (named for a note).

    An entry point given as a class or function is named ``module:name``:
    ``gym.register(id, entry_point=MyEnv)`` registers the class itself, which ``to_json``
    refuses; its name, when it leads back to that object, is what the spec holds instead
    (replay builds a registered id from this process's registry, never from that name
    unless trusted: docs/replay.md). An argument of the env or of a wrapper that JSON cannot
    hold (``TransformReward(env, lambda r: ...)``) becomes a placeholder
    (:mod:`~episode_audit.format.unrecorded`). Raises what ``to_json`` raises for anything else.
    """
    entry = spec.entry_point
    if callable(entry):
        module, name = getattr(entry, "__module__", None), getattr(entry, "__qualname__", "")
        found: Any = sys.modules.get(module or "")
        for part in name.split("."):
            found = getattr(found, part, None)
        if found is entry:
            spec = dataclasses.replace(spec, entry_point=f"{module}:{name}")
    try:
        return json.loads(spec.to_json()), []
    except (TypeError, ValueError):
        pass
    wrappers = tuple(
        dataclasses.replace(
            w, kwargs=placeholders(w.kwargs, dtype_names=w.entry_point in RECORDED_WRAPPERS)[0]
        )
        if w.kwargs is not None  # (None: the wrapper records no arguments, and stays so)
        else w
        for w in spec.additional_wrappers or ()
    )
    kwargs = placeholders(spec.kwargs or {})[0]
    spec = dataclasses.replace(spec, kwargs=kwargs, additional_wrappers=wrappers)
    loaded: dict[str, Any] = json.loads(spec.to_json())
    return loaded, spec_placeholders(loaded)


def _terms(settings: RecorderSettings, info_of: str | None) -> dict[str, Any]:
    """The ``reward_terms`` key of the run metadata."""
    described = settings.terms_rule.describe()
    if info_of is not None and described.get("source") == "auto":
        described["info_of"] = info_of
    return described
