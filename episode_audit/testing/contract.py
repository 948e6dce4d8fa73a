"""Check one :class:`~.cases.ContractCase` through a real recording.

:func:`check_contract` records the case with :class:`~episode_audit.RecordEvidence`, then
holds the file to the contract with the library's own functions: the ending (the episodes
table), the reward terms and flags (:func:`~episode_audit.check`), reproducibility
(:func:`~episode_audit.replay` in a fresh env) and, optionally, incentives over random
episodes (:func:`~episode_audit.report`). A broken contract raises
:class:`~episode_audit.errors.ContractViolation`, one line per broken clause, naming the step
and term, and the ``episode-audit replay`` command for the evidence file it keeps.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym

from ..check import Finding, check
from ..errors import ConfigurationError, ContractViolation
from ..format import names as fmt
from ..format.columns import error_text
from ..read import open_evidence
from ..record import RecordEvidence
from ..replay import EpisodeReplay, replay
from ..report import report
from .cases import ContractCase, Expected, Policy, evidence_actions, evidence_folder
from .command import replay_command

__all__ = [
    "CaseLike",
    "ContractResult",
    "check_contract",
    "check_file",
    "ending_problem",
    "evidence_path",
    "file_stem",
    "replay_file",
    "violation",
    "violation_message",
]


class CaseLike(Protocol):
    """What the shared clauses read of a case (:class:`ContractCase`, ``GameCase``)."""

    @property
    def env(self) -> Any:
        """An env id or a factory."""

    @property
    def env_kwargs(self) -> Mapping[str, Any]:
        """The factory's or ``gym.make``'s keyword arguments."""

    @property
    def seed(self) -> int:
        """The reset seed."""

    @property
    def atol(self) -> float:
        """Absolute tolerance of the terms-sum check."""

    @property
    def rtol(self) -> float:
        """Relative tolerance of the terms-sum check."""

    @property
    def require_terms(self) -> bool:
        """Whether steps without terms are a finding."""

    def make_env(self) -> Any:
        """A fresh env of the case."""


@dataclass
class ContractResult:
    """What a case's recording showed (also on :class:`ContractViolation`: ``.result``)."""

    case: CaseLike
    path: Path
    outcome: str
    detail: str | None
    steps: int
    last_terms: dict[str, float]
    findings: list[Finding] = field(default_factory=list)
    replayed: EpisodeReplay | None = None
    incentive_path: Path | None = None
    incentive_warnings: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Whether the case kept its contract."""
        return not self.problems


def check_contract(case: ContractCase, directory: str | os.PathLike[str]) -> ContractResult:
    """Record ``case`` into ``directory`` and check its contract; return what it showed.

    Raises :class:`~episode_audit.errors.ContractViolation` (an ``AssertionError``) naming
    every broken clause; :class:`~episode_audit.errors.ConfigurationError` for a case that
    cannot run (an env that cannot be made, a bad option).

    >>> import tempfile
    >>> case = ContractCase("CartPole-v1", {"max_episode_steps": 5}, actions=[0] * 5,
    ...                     expect="truncated:time_limit")
    >>> result = check_contract(case, tempfile.mkdtemp())
    >>> result.outcome, result.detail, result.steps, result.replayed.status
    ('truncated', 'time_limit', 5, 'identical')
    >>> wrong = ContractCase("CartPole-v1", {"max_episode_steps": 5}, actions=[0] * 5,
    ...                      expect="success")
    >>> check_contract(wrong, tempfile.mkdtemp())  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    episode_audit.errors.ContractViolation: CartPole-v1-seed0-success: 1 broken clause
      ending: expected success, got truncated (time_limit) at step 4: ...
    """
    path = evidence_path(directory, case)
    steps = _record(case, path)
    episode = open_evidence(path).episodes().to_pylist()[0]
    outcome = str(episode["outcome"])
    detail = episode["failure_label"] if outcome == fmt.OUTCOME_FAILURE else None
    if outcome == fmt.OUTCOME_TRUNCATED:
        detail = episode["truncation_reason"]
    last = _last_terms(path)
    result = ContractResult(case, path, outcome, detail, steps, last)
    if outcome == fmt.OUTCOME_ERROR:
        where = f"at step {steps - 1}" if steps else "in reset"
        result.problems.append(
            f"ending: the env raised {where}: {episode['error_type']}: {episode['error_message']}"
        )
    elif not episode["ended"] or outcome == fmt.OUTCOME_INCOMPLETE:
        why = "the actions ran out" if steps < case.max_steps else "max_steps was reached"
        result.problems.append(
            f"ending: expected {case.expected or 'an ending'}, got none: {why} after {steps} "
            f"step(s) with terminated and truncated both False"
        )
    elif case.expected is not None and not case.expected.matches(outcome, detail):
        result.problems.append(ending_problem(case.expected, episode, steps - 1))
    result.problems += _term_problems(case, last, steps)
    result.findings = check_file(case, path, result)
    if case.replay and outcome != fmt.OUTCOME_ERROR:
        result.replayed = replay_file(case, path, result)
    if case.random_episodes:
        _incentives(case, path.with_name(f"{path.stem}-random.mcap"), result)
    if result.problems:
        raise violation(result)
    return result


_KEPT: set[Path] = set()
"""Evidence files a violation in this process said it kept: no later case writes over them."""


def evidence_path(directory: str | os.PathLike[str], case: CaseLike) -> Path:
    """The file ``case``'s evidence goes to in ``directory`` (made if missing).

    ``<case>.mcap``, written over by a later run of the same case, unless a violation in this
    process kept it (:func:`violation`): then ``<case>-2.mcap``, ``-3``... A ``directory``
    that is a file is a :class:`~episode_audit.errors.ConfigurationError`
    (:func:`~.cases.evidence_folder`).
    """
    out = evidence_folder(directory)
    stem, n = file_stem(case), 1
    path = out / f"{stem}.mcap"
    while path.resolve() in _KEPT or path.with_name(f"{path.stem}-random.mcap").resolve() in _KEPT:
        n += 1
        path = out / f"{stem}-{n}.mcap"
    return path


def violation(result: ContractResult) -> ContractViolation:
    """The :class:`~episode_audit.errors.ContractViolation` of ``result``; its files kept.

    The evidence it names is never written over by a later case of this process.
    """
    for kept in (result.path, result.incentive_path):
        if kept is not None:
            _KEPT.add(Path(kept).resolve())
    return ContractViolation(violation_message(result), result)


def file_stem(case: CaseLike) -> str:
    """The case's name as a file name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in str(case))[:120]


def _step_actions(case: ContractCase, env: gym.Env[Any, Any]) -> Iterator[Any] | Policy:
    """The case's actions as an iterator, or its policy."""
    if case.make_policy is not None:
        return case.make_policy(env)
    actions = case.actions
    if isinstance(actions, str):  # "random" (the case refuses any other string)
        space = env.action_space
        space.seed(case.seed)
        return lambda obs: space.sample()
    if isinstance(actions, os.PathLike):
        return iter(evidence_actions(actions))
    if callable(actions):
        return actions
    return iter(actions)  # type: ignore[arg-type]


def _record(case: ContractCase, path: Path) -> int:
    """Record one episode of ``case`` to ``path``; return its number of steps."""
    env = _make(case)
    steps = 0
    with RecordEvidence(env, path, overwrite=True, **case.recorder_options) as recorder:
        source = _step_actions(case, env)
        try:
            obs, _ = recorder.reset(seed=case.seed)
        except Exception:  # the env's fault: the file keeps it as an error episode
            return 0
        while steps < case.max_steps:
            action = source(obs) if callable(source) else next(source, _END)
            if action is _END:
                break
            steps += 1
            try:
                obs, _, terminated, truncated, _ = recorder.step(action)
            except Exception:  # the env's fault: the file keeps it as an error episode
                break
            if terminated or truncated:
                break
    return steps


_END = object()


def _make(case: ContractCase) -> gym.Env[Any, Any]:
    try:
        return case.make_env()
    except ConfigurationError:
        raise
    except Exception as exc:
        raise ConfigurationError(f"{case}: cannot make the env: {error_text(exc)}") from None


def _last_terms(path: Path) -> dict[str, float]:
    steps = open_evidence(path).steps(columns=[fmt.COL_TERMS])
    if steps.num_rows == 0:
        return {}
    return dict(steps.column(fmt.COL_TERMS)[-1].as_py() or [])


def ending_problem(expected: Expected, episode: dict[str, Any], step: int, who: str = "") -> str:
    """The line saying how an episode's ending (its record) differs from ``expected``.

    ``step`` is its last step; ``who`` names the agent of a game (`` of agent 'a'``).
    """
    outcome = episode["outcome"]
    got = outcome
    if outcome == fmt.OUTCOME_FAILURE:
        got = f"failure ({episode['failure_label']})"
    elif outcome == fmt.OUTCOME_TRUNCATED:
        got = f"truncated ({episode['truncation_reason']})"
    head = f"ending{who}: expected {expected}, got {got} at step {step}"
    if expected.outcome == fmt.OUTCOME_TRUNCATED and outcome != fmt.OUTCOME_TRUNCATED:
        return (
            f"{head}: terminated=True, truncated={episode['truncated']}, so the task ended it; "
            f"if a cutoff such as a time limit did, the env reports a truncation as "
            f"termination (it must set truncated=True, terminated=False)"
        )
    if expected.outcome != fmt.OUTCOME_TRUNCATED and outcome == fmt.OUTCOME_TRUNCATED:
        return (
            f"{head}: terminated=False, truncated=True, so a cutoff ended it; if the task "
            f"ended it, the env reports a task ending as truncation (it must set "
            f"terminated=True), else the actions do not reach the ending in time"
        )
    return f"{head} (terminated={episode['terminated']}, truncated={episode['truncated']})"


def _term_problems(case: ContractCase, last: dict[str, float], steps: int) -> list[str]:
    shown = ", ".join(f"{k}={v:.6g}" for k, v in last.items()) or "none"
    where = f"step {steps - 1} (the last)"
    return [
        f"terms: {where}: expected term {name!r} present (non-zero), got terms {shown}"
        for name in case.terms_present
        if not last.get(name)
    ] + [
        f"terms: {where}: expected term {name!r} absent (or zero), got {name}={last[name]:.6g}"
        for name in case.terms_absent
        if last.get(name)
    ]


def check_file(case: CaseLike, path: Path, result: ContractResult) -> list[Finding]:
    """``check`` the file; every error or warning is a broken clause."""
    # a factory's env has no spec to record: the contract replays it with the factory
    ignore = () if isinstance(case.env, str) else ("missing_env_spec",)
    checked = check(
        [path], atol=case.atol, rtol=case.rtol, require_terms=case.require_terms, ignore=ignore
    )
    for finding in checked.findings:
        if finding.severity == "note":
            continue
        where = "" if finding.step is None else f" at step {finding.step}"
        line = f"check: {finding.code}{where}: {finding.message}"
        if finding.code == "terms_sum_mismatch" and finding.step is not None:
            line += f"; {_terms_at(path, finding.episode or 0, finding.step)}"
        result.problems.append(line)
    return checked.findings


def _terms_at(path: Path, episode: int, step: int) -> str:
    """The terms and the reward of one step, for a message."""
    table = open_evidence(path).steps(
        columns=[fmt.COL_STEP, fmt.COL_REWARD, fmt.COL_TERMS], episodes=[episode]
    )
    for row in table.to_pylist():
        if row[fmt.COL_STEP] == step:
            terms = dict(row[fmt.COL_TERMS] or [])
            listed = ", ".join(f"{k}={v:.6g}" for k, v in terms.items())
            return (
                f"terms at step {step}: {listed} (sum {sum(terms.values()):.6g}), "
                f"reward {row[fmt.COL_REWARD]:.6g}"
            )
    return f"no step {step} in the file"


def replay_file(case: CaseLike, path: Path, result: ContractResult) -> EpisodeReplay:
    """Replay the file's first episode (or game) in a fresh env; a difference is a clause."""
    factory = None if isinstance(case.env, str) else case.make_env
    episodes = replay([path], env_factory=factory).episodes
    replayed = next((e for e in episodes if e.status != "identical"), episodes[0])
    # (the factory is the recording's: a difference its match could not verify is the env's)
    differed = replayed.status == "diverged" or replayed.unverified is not None
    if differed and replayed.divergence is not None:
        result.problems.append(
            f"replay: not reproducible in a fresh env with seed {case.seed}: "
            f"{replayed.divergence.describe()}"
        )
    elif replayed.status != "identical":
        result.problems.append(f"replay: not replayable: {replayed.reason}")
    return replayed


def _incentives(case: ContractCase, path: Path, result: ContractResult) -> None:
    """Record ``case.random_episodes`` random episodes; each incentive warning is a clause."""
    env = _make(case)
    space = env.action_space
    space.seed(case.seed)
    with RecordEvidence(env, path, overwrite=True, **case.recorder_options) as recorder:
        for i in range(case.random_episodes):
            recorder.reset(seed=case.seed + i)
            for _ in range(case.max_steps):
                _, _, terminated, truncated, _ = recorder.step(space.sample())
                if terminated or truncated:
                    break
    result.incentive_path = path
    (group,) = report([path], by="all").groups
    result.incentive_warnings = [f"{w.code}: {w.message}" for w in group.warnings]
    result.problems += [
        f"incentives over {case.random_episodes} random episodes (seeds {case.seed}.."
        f"{case.seed + case.random_episodes - 1}): {line}"
        for line in result.incentive_warnings
    ]


def violation_message(result: ContractResult) -> str:
    """The violation's text: the case, one line per broken clause, the replay command."""
    n = len(result.problems)
    lines = [f"{result.case}: {n} broken clause{'s' if n != 1 else ''}"]
    lines += [f"  {p}" for p in result.problems]
    lines.append(f"  evidence kept: {result.path}")
    command = replay_command(result.case.env, result.case.env_kwargs, result.path)
    lines.append(f"  replay it: {command}")
    if result.incentive_path is not None and result.incentive_warnings:
        lines.append(f"  random episodes: episode-audit report {result.incentive_path}")
    return "\n".join(lines)
