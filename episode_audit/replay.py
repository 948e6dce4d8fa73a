"""Replay recorded episodes and compare them, step by step, with the evidence.

Each episode is reset from its recorded seed — or, for an unseeded reset, from the RNG state
captured just before it — and stepped with the recorded actions. The reset observation, every
observation, reward, reward terms, ``terminated``, ``truncated`` and the outcome are compared;
the first difference is reported with its step, field, expected and actual values.

How the environment is built, safely (a file may come from anyone):

1. ``env_factory`` (``"module:callable"`` or a callable), given by the user; else
2. the recorded env id, when it is registered in this process (Gymnasium's built-ins, ids
   registered by ``imports`` the user names, and episode-audit's own tasks), with the
   recorded kwargs and ``max_episode_steps``; else
3. only with ``trust_entry_points=True``: the entry point named in the file.

Nothing named inside a file is imported without that flag — including the ``module:`` prefix
Gymnasium's ``make`` would import, and wrappers recorded in the spec that are not Gymnasium's own.
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import pyarrow as pa

from . import format as fmt
from .columns import terms_column
from .errors import ConfigurationError, ReplayError
from .outcomes import EndingRules, RewardTerms, find_time_limit, time_limit_hit
from .reader import Evidence, open_evidence
from .recorder import library_versions
from .records import RunInfo
from .seeding import restore_rng_state
from .spaces import SpaceCodec

__all__ = [
    "Divergence",
    "EpisodeReplay",
    "ReplayResult",
    "build_env",
    "load_callable",
    "replay",
    "replay_evidence",
]

Status = Literal["identical", "diverged", "not_replayable"]
EnvFactory = Callable[[], gym.Env[Any, Any]]

_TRUSTED_WRAPPER_PREFIX = "gymnasium.wrappers"


@dataclass(frozen=True)
class Divergence:
    """Where a replay first differed from the evidence (``step`` is ``None`` for the reset)."""

    step: int | None
    field: str
    expected: str
    got: str
    max_abs_diff: float | None = None

    def describe(self) -> str:
        """One line: step, field, expected, got, max abs difference."""
        where = "reset" if self.step is None else f"step {self.step}"
        diff = "" if self.max_abs_diff is None else f" (max abs diff {self.max_abs_diff:.3g})"
        return f"{where}: {self.field} expected {self.expected}, got {self.got}{diff}"


@dataclass(frozen=True)
class EpisodeReplay:
    """The replay of one episode."""

    file: str
    episode: int
    status: Status
    steps: int
    divergence: Divergence | None = None
    reason: str | None = None


@dataclass
class ReplayResult:
    """Replays of many episodes, with the library versions that differ from the recording."""

    episodes: list[EpisodeReplay] = field(default_factory=list)
    version_differences: dict[str, dict[str, tuple[str, str]]] = field(default_factory=dict)

    def count(self, status: Status) -> int:
        """How many episodes ended with ``status``."""
        return sum(1 for e in self.episodes if e.status == status)

    @property
    def ok(self) -> bool:
        """True when no episode diverged (not-replayable episodes do not fail a replay)."""
        return self.count("diverged") == 0

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able form: ``{"summary": {...}, "episodes": [...], "version_differences"}``."""
        return {
            "summary": {
                "identical": self.count("identical"),
                "diverged": self.count("diverged"),
                "not_replayable": self.count("not_replayable"),
            },
            "episodes": [asdict(e) for e in self.episodes],
            "version_differences": {
                file: {lib: {"recorded": a, "current": b} for lib, (a, b) in diffs.items()}
                for file, diffs in self.version_differences.items()
            },
        }


def load_callable(spec: str) -> Callable[..., Any]:
    """Import ``"module:attribute"`` (given by the user, never by a file) and return it.

    >>> load_callable("gymnasium:make") is gym.make
    True
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigurationError(f"expected MODULE:CALLABLE, actually: {spec!r}")
    try:
        target: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            target = getattr(target, part)
    except (ImportError, AttributeError) as exc:
        raise ConfigurationError(f"cannot load {spec!r}: {exc}") from None
    if not callable(target):
        raise ConfigurationError(f"{spec!r} is not callable")
    return target  # type: ignore[no-any-return]


def build_env(
    run: RunInfo,
    *,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
) -> gym.Env[Any, Any]:
    """Build the environment to replay a file's episodes in (see the module docstring)."""
    if env_factory is not None:
        factory = load_callable(env_factory) if isinstance(env_factory, str) else env_factory
        env = factory()
        if not isinstance(env, gym.Env):
            raise ReplayError(f"the env factory returned {type(env).__name__}, not a gymnasium.Env")
        return env
    spec = run.env_spec or {}
    env_id = run.env_id
    if not env_id:
        raise ReplayError("the file names no env id; pass --env-factory MODULE:CALLABLE")
    wrappers = [w for w in spec.get("additional_wrappers") or [] if isinstance(w, Mapping)]
    foreign = [
        str(w.get("entry_point"))
        for w in wrappers
        if not str(w.get("entry_point", "")).startswith(_TRUSTED_WRAPPER_PREFIX)
    ]
    if ":" not in env_id and env_id in gym.registry and (not foreign or trust_entry_points):
        kwargs = dict(spec.get("kwargs") or {})
        if "max_episode_steps" in spec:
            kwargs["max_episode_steps"] = spec["max_episode_steps"]
        try:
            env = gym.make(env_id, **kwargs)
            for wrapper in wrappers:
                cls = load_callable(str(wrapper["entry_point"]))
                env = cls(env, **(wrapper.get("kwargs") or {}))
        except (TypeError, ValueError, gym.error.Error) as exc:
            raise ReplayError(f"cannot make {env_id!r} with the recorded kwargs: {exc}") from None
        return env
    entry = spec.get("entry_point")
    if trust_entry_points and spec:
        try:
            return gym.make(gym.envs.registration.EnvSpec.from_json(json.dumps(spec)))
        except Exception as exc:
            raise ReplayError(f"cannot make the env from the recorded spec: {exc}") from None
    if foreign and env_id in gym.registry:
        raise ReplayError(
            f"the recorded env had wrappers from outside Gymnasium ({', '.join(foreign)}); "
            "pass --env-factory MODULE:CALLABLE, or --trust-entry-points to import them"
        )
    raise ReplayError(
        f"env id {env_id!r} is not registered in this process; pass --import MODULE that "
        "registers it, --env-factory MODULE:CALLABLE, or --trust-entry-points to import "
        f"{entry!r} named in the file"
    )


def _short(value: Any) -> str:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _rules_of(run: RunInfo) -> tuple[EndingRules | None, RewardTerms | None]:
    ending = run.ending_rules or {}
    rules: EndingRules | None = None
    if not ending.get("success_fn") and not ending.get("failure_fn"):
        rules = EndingRules(
            success_keys=tuple(ending.get("success_keys") or ("success", "is_success")),
            failure_key=str(ending.get("failure_key") or "failure"),
            truncation_reason_key=str(ending.get("truncation_reason_key") or "truncation_reason"),
        )
    source = (run.reward_terms or {}).get("source", "auto")
    terms: RewardTerms | None
    if source == "auto" or source is None:
        terms = RewardTerms(source)
    elif isinstance(source, list):
        terms = RewardTerms(tuple(str(k) for k in source))
    else:  # a callable the file can only name: terms are not compared
        terms = None
    return rules, terms


class _EpisodeRunner:
    """Replays the episodes of one file in one environment."""

    def __init__(
        self,
        ev: Evidence,
        env: gym.Env[Any, Any],
        *,
        atol: float,
        progress: Callable[[int], None] | None,
    ) -> None:
        self.ev = ev
        self.env = env
        self.atol = atol
        self.progress = progress
        self.obs_codec = ev.observation_codec
        self.act_codec = ev.action_codec
        self.rules, self.terms_rule = _rules_of(ev.run)
        self.time_limit = find_time_limit(env)

    def not_replayable(self, index: int, steps: int, reason: str) -> EpisodeReplay:
        return EpisodeReplay(str(self.ev.path), index, "not_replayable", steps, reason=reason)

    def run(self, record: dict[str, Any]) -> EpisodeReplay:
        index = int(record["episode"])
        if self.obs_codec is None or self.act_codec is None:
            return self.not_replayable(index, 0, "the file's spaces cannot be rebuilt")
        seed = record.get("seed")
        rng_state = record.get("rng_state")
        if seed is None and rng_state is None:
            return self.not_replayable(index, 0, "no seed or RNG state recorded for its reset")
        episode = self.ev.episode(index)
        steps = episode.steps
        n = steps.num_rows
        if episode.reset is None:
            return self.not_replayable(index, n, "its reset row is missing (torn file)")
        options = json.loads(record["options"]) if record.get("options") else None
        try:
            if seed is not None:
                obs, _ = self.env.reset(seed=int(seed), options=options)
            else:
                restore_rng_state(self.env, json.loads(str(rng_state)))
                obs, _ = self.env.reset(options=options)
        except Exception as exc:
            return self._diverged(
                index, 0, Divergence(None, "reset", "a reset", f"{type(exc).__name__}: {exc}")
            )
        expected_reset = pa.array([episode.reset[fmt.COL_OBSERVATION]], self.obs_codec.arrow_type)
        got_reset = self._encode(self.obs_codec, [obs])
        found = _compare_values(self.obs_codec, expected_reset, got_reset, self.atol)
        if found is not None:
            _, diff = found
            return self._diverged(
                index,
                0,
                Divergence(
                    None,
                    "reset_observation",
                    _short(self.obs_codec.decode(expected_reset)[0]),
                    _short(obs),
                    diff,
                ),
            )
        return self._step_through(index, record, steps)

    @staticmethod
    def _encode(codec: SpaceCodec, values: Sequence[Any]) -> pa.Array:
        buffer = codec.new_buffer()
        for value in values:
            try:
                buffer.append(value)
            except (TypeError, ValueError):
                buffer.append_null()
        return buffer.finish()

    def _diverged(self, index: int, steps: int, divergence: Divergence) -> EpisodeReplay:
        return EpisodeReplay(str(self.ev.path), index, "diverged", steps, divergence)

    def _step_through(self, index: int, record: dict[str, Any], steps: pa.Table) -> EpisodeReplay:
        assert self.obs_codec is not None
        assert self.act_codec is not None
        n = steps.num_rows
        actions = self.act_codec.decode(steps.column(fmt.COL_ACTION).combine_chunks())
        obs_buffer = self.obs_codec.new_buffer()
        rewards: list[float] = []
        terms: list[dict[str, Any] | None] = []
        terminated: list[bool] = []
        truncated: list[bool] = []
        extract = self.terms_rule.extract if self.terms_rule is not None else None
        env_step = self.env.step
        progress = self.progress
        last_info: Any = {}
        crash: Divergence | None = None
        for i, action in enumerate(actions):
            if action is None:
                crash = Divergence(i, "action", "a recorded action", "null (not recordable)")
                break
            try:
                obs, reward, term, trunc, info = env_step(action)
            except Exception as exc:
                crash = Divergence(i, "step", "a step", f"{type(exc).__name__}: {exc}")
                break
            try:
                obs_buffer.append(obs)
            except (TypeError, ValueError):
                obs_buffer.append_null()
            rewards.append(float(reward))
            terms.append(extract(info) if extract is not None and info else None)
            terminated.append(bool(term))
            truncated.append(bool(trunc))
            last_info = info
            if progress is not None and i % 1024 == 1023:
                progress(1024)
            if (term or trunc) and i < n - 1:
                break
        if progress is not None:
            progress(len(rewards) % 1024)
        done = len(rewards)
        expected = steps.slice(0, done)
        first = self._first_difference(
            expected, obs_buffer.finish(), rewards, terms, terminated, truncated
        )
        if first is not None:
            return self._diverged(index, first.step or 0, first)
        if crash is not None:
            return self._diverged(index, done, crash)
        if done < n:
            return self._diverged(
                index,
                done,
                Divergence(done, "length", f"{n} steps", f"the episode ended after {done}"),
            )
        outcome = self._outcome_difference(record, terminated, truncated, last_info)
        if outcome is not None:
            return self._diverged(index, done, outcome)
        return EpisodeReplay(str(self.ev.path), index, "identical", done)

    def _first_difference(
        self,
        expected: pa.Table,
        got_obs: pa.Array,
        rewards: list[float],
        terms: list[dict[str, Any] | None],
        terminated: list[bool],
        truncated: list[bool],
    ) -> Divergence | None:
        assert self.obs_codec is not None
        if not rewards:
            return None
        candidates: list[Divergence] = []
        exp_obs = expected.column(fmt.COL_OBSERVATION).combine_chunks()
        equal, diffs = self.obs_codec.compare(exp_obs, got_obs, atol=self.atol)
        bad = np.flatnonzero(~equal)
        if bad.size:
            i = int(bad[0])
            candidates.append(
                Divergence(
                    i,
                    "observation",
                    _short(self.obs_codec.decode(exp_obs.slice(i, 1))[0]),
                    _short(self.obs_codec.decode(got_obs.slice(i, 1))[0]),
                    float(diffs[i]),
                )
            )
        exp_r = expected.column(fmt.COL_REWARD).to_numpy()
        got_r = np.asarray(rewards, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            diff_r = np.abs(exp_r - got_r)
            same_r = (exp_r == got_r) | (np.isnan(exp_r) & np.isnan(got_r)) | (diff_r <= self.atol)
        bad = np.flatnonzero(~same_r)
        if bad.size:
            i = int(bad[0])
            candidates.append(
                Divergence(i, "reward", repr(exp_r[i]), repr(got_r[i]), float(diff_r[i]))
            )
        if self.terms_rule is not None:
            got_terms = terms_column(
                len(terms), {i: t for i, t in enumerate(terms) if t is not None}
            ).to_pylist()
            exp_terms = expected.column(fmt.COL_TERMS).to_pylist()
            for i, (a, b) in enumerate(zip(exp_terms, got_terms, strict=True)):
                if not _terms_equal(a, b, self.atol):
                    candidates.append(
                        Divergence(i, "terms", _short(dict(a or [])), _short(dict(b or [])))
                    )
                    break
        for name, got in ((fmt.COL_TERMINATED, terminated), (fmt.COL_TRUNCATED, truncated)):
            exp = expected.column(name).to_numpy(zero_copy_only=False)
            bad = np.flatnonzero(exp != np.asarray(got, dtype=np.bool_))
            if bad.size:
                i = int(bad[0])
                candidates.append(Divergence(i, name, str(bool(exp[i])), str(got[i])))
        if not candidates:
            return None
        return min(candidates, key=lambda d: d.step if d.step is not None else -1)

    def _outcome_difference(
        self, record: dict[str, Any], terminated: list[bool], truncated: list[bool], info: Any
    ) -> Divergence | None:
        if (
            self.rules is None
            or not terminated
            or record["outcome"]
            in (
                fmt.OUTCOME_INCOMPLETE,
                fmt.OUTCOME_ERROR,
            )
        ):
            return None
        term, trunc = terminated[-1], truncated[-1]
        if not (term or trunc):
            return None
        ending = self.rules.classify(
            term,
            trunc,
            info if isinstance(info, Mapping) else {},
            time_limit_hit=time_limit_hit(self.time_limit),
        )
        want = (record["outcome"], record.get("failure_label"), record.get("truncation_reason"))
        got = (ending.outcome, ending.failure_label, ending.truncation_reason)
        if want != got:
            return Divergence(
                len(terminated) - 1, "outcome", _fmt_outcome(*want), _fmt_outcome(*got)
            )
        return None


def _fmt_outcome(outcome: str, label: str | None, reason: str | None) -> str:
    parts = [outcome] + [p for p in (label, reason) if p]
    return "/".join(parts)


def _terms_equal(a: Any, b: Any, atol: float) -> bool:
    if a is None or b is None:
        return a is None and b is None
    if [k for k, _ in a] != [k for k, _ in b]:
        return False
    for (_, x), (_, y) in zip(a, b, strict=True):
        if x == y or (x != x and y != y):
            continue
        if atol > 0 and abs(x - y) <= atol:
            continue
        return False
    return True


def _compare_values(
    codec: SpaceCodec, expected: pa.Array, got: pa.Array, atol: float
) -> tuple[int, float] | None:
    equal, diffs = codec.compare(expected, got, atol=atol)
    bad = np.flatnonzero(~equal)
    if bad.size == 0:
        return None
    return int(bad[0]), float(diffs[int(bad[0])])


def replay_evidence(
    ev: Evidence,
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[EpisodeReplay]:
    """Replay the episodes of one open evidence file (see :func:`replay`)."""
    table = ev.episodes()
    records = table.to_pylist()
    if episodes is not None:
        wanted = set(episodes)
        records = [r for r in records if r["episode"] in wanted]
    if ev.run.layout.get("kind", "single") != "single":
        return [
            EpisodeReplay(
                str(ev.path),
                int(r["episode"]),
                "not_replayable",
                0,
                reason=f"layout {ev.run.layout.get('kind')!r} is not replayable yet",
            )
            for r in records
        ]
    try:
        env = build_env(ev.run, env_factory=env_factory, trust_entry_points=trust_entry_points)
    except ReplayError as exc:
        return [
            EpisodeReplay(str(ev.path), int(r["episode"]), "not_replayable", 0, reason=str(exc))
            for r in records
        ]
    try:
        runner = _EpisodeRunner(ev, env, atol=atol, progress=progress)
        return [runner.run(r) for r in records]
    finally:
        env.close()


def replay(
    paths: Iterable[str | os.PathLike[str]],
    *,
    episodes: Iterable[int] | None = None,
    atol: float = 0.0,
    env_factory: str | EnvFactory | None = None,
    imports: Sequence[str] = (),
    trust_entry_points: bool = False,
    progress: Callable[[int], None] | None = None,
) -> ReplayResult:
    """Replay every (or the selected) episode of each file and compare it with the evidence.

    Raises :class:`~episode_audit.errors.EvidenceError` for an unreadable file and
    :class:`~episode_audit.errors.ConfigurationError` for a module in ``imports`` that cannot
    be imported.
    """
    if atol < 0:
        raise ConfigurationError(f"atol: expected a number >= 0, actually: {atol!r}")
    for module in imports:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise ConfigurationError(f"--import {module}: {exc}") from None
    selected = None if episodes is None else list(episodes)
    result = ReplayResult()
    for path in paths:
        ev = open_evidence(path)
        result.episodes.extend(
            replay_evidence(
                ev,
                episodes=selected,
                atol=atol,
                env_factory=env_factory,
                trust_entry_points=trust_entry_points,
                progress=progress,
            )
        )
        current = library_versions()
        diffs = {
            lib: (str(recorded), current.get(lib, "not installed"))
            for lib, recorded in ev.run.versions.items()
            if current.get(lib) != recorded and lib != "episode_audit"
        }
        if diffs:
            result.version_differences[str(ev.path)] = diffs
    return result
