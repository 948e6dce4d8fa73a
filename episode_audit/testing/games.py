"""Contract cases of PettingZoo Parallel games: each agent's ending, through a real recording.

:class:`GameCase` (a ``ParallelEnv`` factory, a seed, joint actions, each agent's expected
ending) and :func:`check_game_contract`, which records the game with
``RecordParallelEvidence`` and checks it as :func:`~.contract.check_contract` checks an episode:
the agents' endings, ``check`` and ``replay`` of the file. Imports ``pettingzoo`` only when run.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigurationError
from ..format import names as fmt
from ..read import open_evidence
from .cases import Expected, check_case_fields, expected_ending, found
from .contract import (
    ContractResult,
    check_file,
    ending_problem,
    evidence_path,
    replay_file,
    violation,
)

__all__ = ["GameCase", "check_game_contract"]

JointPolicy = Callable[[str, Any], Any]
"""A policy of a game: (agent, its observation) -> its action."""


@dataclass(frozen=True)
class GameCase:
    """One contract case of a PettingZoo ``ParallelEnv``: every agent's expected ending.

    Args:
        env: A factory called with ``env_kwargs`` that returns a fresh ``ParallelEnv``.
        env_kwargs: Keyword arguments of the factory.
        seed: The reset seed.
        actions: A list of joint actions (``{agent: action}`` per step), a policy
            ``(agent, observation) -> action``, or ``"random"`` (each agent's action space,
            seeded with ``seed``).
        expect: Each agent's expected ending (``"success"``, ``"failure:LABEL"``,
            ``"truncated:REASON"``); agents not named may end any way.
        max_steps: A game still running after this many steps fails.
        recorder_options: Options of ``RecordParallelEvidence``.
        atol: Absolute tolerance of the terms-sum check.
        rtol: Relative tolerance of the terms-sum check.
        require_terms: Steps without reward terms are a finding.
        replay: Replay the game with the factory and require it identical.
        id: The case's name in test ids.
    """

    env: Callable[..., Any]
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    actions: Sequence[Mapping[str, Any]] | JointPolicy | str = "random"
    expect: Mapping[str, str | Expected] = field(default_factory=dict)
    max_steps: int = 100_000
    recorder_options: Mapping[str, Any] = field(default_factory=dict)
    atol: float = 1e-6
    rtol: float = 1e-6
    require_terms: bool = False
    replay: bool = True
    id: str | None = None

    def __post_init__(self) -> None:
        if not callable(self.env):
            raise ConfigurationError(
                f"GameCase: env: expected a factory returning a pettingzoo ParallelEnv, got "
                f"{found(self.env)}"
            )
        check_case_fields(self)
        _check_actions(self)
        if not isinstance(self.expect, Mapping):
            raise ConfigurationError(
                f"{self}: expect: expected a dict of each agent's ending ({{agent: 'success'}}), "
                f"got {found(self.expect)}"
            )
        for agent, ending in self.expect.items():
            if not isinstance(agent, str) or not isinstance(ending, (str, Expected)):
                raise ConfigurationError(
                    f"{self}: expect: expected agent names (str) and endings ('success', "
                    f"'failure[:LABEL]', 'truncated[:REASON]'), got {found(agent)}: "
                    f"{found(ending)}"
                )
            try:
                expected_ending(ending)
            except ConfigurationError as exc:
                raise ConfigurationError(f"{self}: agent {agent!r}: {exc}") from None

    def __str__(self) -> str:
        if self.id is not None:
            return self.id
        name = getattr(self.env, "__qualname__", None) or type(self.env).__name__
        return f"{name}-seed{self.seed}"

    def make_env(self) -> Any:
        """A fresh ``ParallelEnv`` of this case."""
        from pettingzoo import ParallelEnv

        env = self.env(**self.env_kwargs)
        if not isinstance(env, ParallelEnv):
            raise ConfigurationError(
                f"{self}: the env factory returned {type(env).__name__}, not a ParallelEnv"
            )
        return env


def _check_actions(case: GameCase) -> None:
    """``actions``: joint actions (a list of dicts), a policy or ``"random"``, else raise."""
    actions = case.actions
    if (isinstance(actions, str) and actions == "random") or callable(actions):
        return
    if isinstance(actions, Sequence) and not isinstance(actions, (str, bytes)):
        for step, joint in enumerate(actions):
            if not isinstance(joint, Mapping):
                raise ConfigurationError(
                    f"{case}: actions: expected a dict of each agent's action at every step, "
                    f"got {found(joint)} at step {step}"
                )
        return
    raise ConfigurationError(
        f"{case}: actions: expected joint actions, a policy or 'random', got {found(actions)}"
    )


def check_game_contract(case: GameCase, directory: str | os.PathLike[str]) -> ContractResult:
    """Record ``case``'s game into ``directory`` and check its contract.

    ``outcome`` of the result is the game's outcome when every agent ended the same way,
    else ``"mixed"``. Raises :class:`~episode_audit.errors.ContractViolation` naming every
    broken clause (an agent's ending, a ``check`` finding, a replay divergence).
    """
    path = evidence_path(directory, case)
    steps = _record(case, path)
    rows = open_evidence(path).episodes().to_pylist()
    outcomes = {r["agent"]: r for r in rows}
    kinds = {r["outcome"] for r in rows}
    result = ContractResult(
        case, path, kinds.pop() if len(kinds) == 1 else "mixed", None, steps, {}
    )
    running = sorted(
        str(r["agent"]) for r in rows if not r["ended"] or r["outcome"] == fmt.OUTCOME_INCOMPLETE
    )
    if running:
        why = "the actions ran out" if steps < case.max_steps else "max_steps was reached"
        result.problems.append(
            f"ending: the game did not end: {why} after {steps} step(s), agents "
            f"{', '.join(running)} still playing"
        )
    for agent, ending in case.expect.items():
        if agent not in running:
            result.problems += _agent_problem(agent, expected_ending(ending), outcomes.get(agent))
    result.findings = check_file(case, path, result)
    if case.replay:
        result.replayed = replay_file(case, path, result)
    if result.problems:
        raise violation(result)
    return result


def _record(case: GameCase, path: Path) -> int:
    from ..record.pettingzoo import RecordParallelEvidence

    env = case.make_env()
    policy = _policy(case, env)
    steps = 0
    with RecordParallelEvidence(env, path, overwrite=True, **case.recorder_options) as game:
        observations, _ = game.reset(seed=case.seed)
        while game.agents and steps < case.max_steps:
            if isinstance(case.actions, Sequence) and not isinstance(case.actions, str):
                if steps >= len(case.actions):
                    break
                joint = {a: v for a, v in case.actions[steps].items() if a in game.agents}
            else:
                joint = {agent: policy(agent, observations[agent]) for agent in game.agents}
            steps += 1
            try:
                observations, *_ = game.step(joint)
            except Exception:  # the env's fault: the file keeps it as an error episode
                break
    return steps


def _policy(case: GameCase, env: Any) -> JointPolicy:
    if callable(case.actions):
        return case.actions
    spaces: dict[str, Any] = {}

    def sample(agent: str, obs: Any) -> Any:
        if agent not in spaces:
            spaces[agent] = env.action_space(agent)
            spaces[agent].seed(case.seed + len(spaces))
        return spaces[agent].sample()

    return sample


def _agent_problem(agent: str, expected: Expected, row: dict[str, Any] | None) -> list[str]:
    if row is None:
        return [f"ending of agent {agent!r}: expected {expected}, got no episode of it"]
    outcome = row["outcome"]
    detail = row["failure_label"] if outcome == fmt.OUTCOME_FAILURE else None
    if outcome == fmt.OUTCOME_TRUNCATED:
        detail = row["truncation_reason"]
    if expected.matches(outcome, detail):
        return []
    return [ending_problem(expected, row, row["length"] - 1, f" of agent {agent!r}")]
