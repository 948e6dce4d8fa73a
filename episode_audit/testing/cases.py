"""What one contract case is: the env, the reset seed, the actions and the expected ending.

- :class:`ContractCase` -- one case; :func:`contract_cases` -- the same case over many env ids,
  for ``pytest.mark.parametrize``.
- :class:`Expected` -- an expected ending, parsed from ``"success"``, ``"failure:LABEL"`` or
  ``"truncated:REASON"`` (:func:`expected_ending`).
- :func:`evidence_actions` -- the actions of one recorded episode, to step a case with.
- :func:`evidence_folder` -- the folder a case's evidence file is kept in, made if need be.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym

from ..errors import ConfigurationError
from ..format import names as fmt
from ..read import open_evidence
from ..read.arguments import name_list
from ..record.notes import short
from ..replay.recorded import replay_actions

__all__ = [
    "Actions",
    "ContractCase",
    "EnvMaker",
    "Expected",
    "Policy",
    "contract_cases",
    "evidence_actions",
    "evidence_folder",
    "expected_ending",
]

Policy = Callable[[Any], Any]
"""A policy: observation -> action."""

EnvMaker = Callable[..., gym.Env[Any, Any]]
"""A factory called with the case's ``env_kwargs`` that returns a fresh env."""

Actions = Sequence[Any] | Policy | Literal["random"] | os.PathLike[str]
"""What a case steps with: a list of actions, a policy, ``"random"`` (the action space
sampled, seeded with the case's seed) or an evidence file (the actions of its episode 0)."""


@dataclass(frozen=True)
class Expected:
    """An expected ending: ``outcome`` and, for a failure or a truncation, its ``detail``.

    ``detail`` ``None`` accepts any failure label (or truncation reason).

    >>> expected_ending("failure:collision")
    Expected(outcome='failure', detail='collision')
    >>> str(expected_ending("truncated"))
    'truncated'
    """

    outcome: Literal["success", "failure", "truncated"]
    detail: str | None = None

    def __str__(self) -> str:
        return self.outcome if self.detail is None else f"{self.outcome}:{self.detail}"

    def matches(self, outcome: str, detail: str | None) -> bool:
        """Whether an episode that ended ``outcome`` (``detail``: label or reason) is this one."""
        return outcome == self.outcome and (self.detail is None or detail == self.detail)


def expected_ending(text: str | Expected) -> Expected:
    """Parse an expected ending: ``success``, ``failure[:LABEL]`` or ``truncated[:REASON]``.

    >>> expected_ending("truncated:time_limit")
    Expected(outcome='truncated', detail='time_limit')
    >>> expected_ending("done")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: expect: expected 'success', ..., got 'done'
    """
    if isinstance(text, Expected):
        return text
    outcome, sep, detail = text.partition(":")
    if outcome == fmt.OUTCOME_SUCCESS and not sep:
        return Expected("success")
    if outcome in (fmt.OUTCOME_FAILURE, fmt.OUTCOME_TRUNCATED) and (detail or not sep):
        return Expected(outcome, detail or None)  # type: ignore[arg-type]
    raise ConfigurationError(
        f"expect: expected 'success', 'failure[:LABEL]' or 'truncated[:REASON]', got {text!r}"
    )


@dataclass(frozen=True)
class ContractCase:
    """One environment contract case: make the env, reset it with ``seed``, step ``actions``.

    Args:
        env: A registered Gymnasium env id, or a factory called with ``env_kwargs``.
        env_kwargs: Keyword arguments of ``gym.make`` or of the factory.
        seed: The reset seed.
        actions: A list of actions, a policy (observation -> action), ``"random"`` or an
            evidence file whose episode 0's actions are stepped (see :data:`Actions`).
        make_policy: Instead of ``actions``: called once with the case's env, returns the policy.
        expect: The expected ending (``"success"``, ``"failure:LABEL"``,
            ``"truncated:REASON"``; see :func:`expected_ending`); ``None`` accepts any.
        terms_present: Reward terms the last step must have, non-zero (envs that report
            every term on every step report the inactive ones as 0).
        terms_absent: Reward terms the last step must not have, or have as 0.
        random_episodes: If > 0, also record this many random episodes (seeds ``seed``,
            ``seed + 1``, ...) and fail on any incentive warning of their report.
        max_steps: A policy that has not ended the episode after this many steps fails.
        recorder_options: Options of :class:`~episode_audit.RecordEvidence` (``reward_terms``,
            ``constant_terms``, ``ending_rules``, ...).
        atol: Absolute tolerance of the terms-sum check (``check``'s own default).
        rtol: Relative tolerance of the terms-sum check.
        require_terms: Steps without reward terms are a finding (``check --require-terms``).
        replay: Replay the recorded episode in a fresh env and require it identical.
        id: The case's name in test ids (default: env, seed and expected ending).
    """

    env: str | EnvMaker
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    actions: Actions | None = None
    make_policy: Callable[[gym.Env[Any, Any]], Policy] | None = None
    expect: str | Expected | None = None
    terms_present: Sequence[str] = ()
    terms_absent: Sequence[str] = ()
    random_episodes: int = 0
    max_steps: int = 100_000
    recorder_options: Mapping[str, Any] = field(default_factory=dict)
    atol: float = 1e-6
    rtol: float = 1e-6
    require_terms: bool = False
    replay: bool = True
    id: str | None = None

    def __post_init__(self) -> None:
        _check_fields(self)
        if (self.actions is None) == (self.make_policy is None):
            raise ConfigurationError(
                f"{self}: expected exactly one of actions= and make_policy=, got "
                f"{'both' if self.actions is not None else 'neither'}"
            )
        if isinstance(self.actions, str) and self.actions != "random":
            raise ConfigurationError(
                f"{self}: actions: expected a list, a policy, 'random' or an evidence file "
                f"as a Path, got the string {self.actions!r}"
            )
        if self.expect is not None:
            object.__setattr__(self, "expect", expected_ending(self.expect))
        for terms in ("terms_present", "terms_absent"):
            given = name_list(f"{self}: {terms}", getattr(self, terms))
            object.__setattr__(self, terms, tuple(given))

    @property
    def expected(self) -> Expected | None:
        """The expected ending, parsed."""
        return expected_ending(self.expect) if self.expect is not None else None

    @property
    def env_name(self) -> str:
        """The env id, or the factory's name."""
        if isinstance(self.env, str):
            return self.env
        return getattr(self.env, "__qualname__", None) or type(self.env).__name__

    def __str__(self) -> str:
        if self.id is not None:
            return self.id
        ending = f"-{self.expect}" if self.expect is not None else ""
        return f"{self.env_name}-seed{self.seed}{ending}"

    def make_env(self) -> gym.Env[Any, Any]:
        """A fresh env of this case."""
        if isinstance(self.env, str):
            return gym.make(self.env, **self.env_kwargs)
        env = self.env(**self.env_kwargs)
        if not isinstance(env, gym.Env):
            raise ConfigurationError(
                f"{self}: the env factory returned {type(env).__name__}, not a gymnasium.Env"
            )
        return env


_MAX_SEED = 2**63 - 1
"""The largest seed a file records (its ``seed`` column is an int64)."""


def _check_fields(case: ContractCase) -> None:
    """Each field of ``case`` of its type and in its range, else :class:`ConfigurationError`."""
    if not (isinstance(case.env, str) or callable(case.env)):
        raise ConfigurationError(
            f"ContractCase: env: expected a registered env id (a str) or a factory returning a "
            f"gymnasium.Env, got {found(case.env)}"
        )
    check_case_fields(case, (("random_episodes", 0, None),))
    _check_steppers(case)


def check_case_fields(case: Any, integers: Iterable[tuple[str, int, int | None]] = ()) -> None:
    """The fields every kind of case has (:class:`ContractCase`, ``GameCase``), checked.

    ``id``, ``env_kwargs``, ``recorder_options``, ``seed``, ``max_steps``, ``atol``, ``rtol``,
    ``require_terms``, ``replay``, and the ``integers`` (field, low, high) of the case's own.
    Each of its type and in its range, else a one-line :class:`ConfigurationError`; the
    integers are kept as ``int`` (a numpy integer is one; a ``bool`` is not). Call it after
    checking ``env`` (the case's name in a message is made from it).
    """
    if case.id is not None and not isinstance(case.id, str):
        raise ConfigurationError(
            f"{type(case).__name__}: id: expected a str or None, got {found(case.id)}"
        )
    for name in ("env_kwargs", "recorder_options"):
        value = getattr(case, name)
        if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
            raise ConfigurationError(
                f"{case}: {name}: expected a dict of keyword arguments (str keys), got "
                f"{found(value)}"
            )
    for name, low, high in (("seed", 0, _MAX_SEED), *integers, ("max_steps", 1, None)):
        object.__setattr__(case, name, _integer(case, name, low, high))
    for name in ("atol", "rtol"):
        value = getattr(case, name)
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not (number and math.isfinite(value) and value >= 0):
            raise ConfigurationError(
                f"{case}: {name}: expected a finite number >= 0, got {found(value)}"
            )
    for name in ("require_terms", "replay"):
        if not isinstance(getattr(case, name), bool):
            raise ConfigurationError(
                f"{case}: {name}: expected True or False, got {found(getattr(case, name))}"
            )


def _check_steppers(case: ContractCase) -> None:
    """``actions``, ``make_policy`` and ``expect`` of the types they may be, else raise."""
    actions = case.actions
    if not (
        actions is None
        or isinstance(actions, (str, os.PathLike))
        or callable(actions)
        or (isinstance(actions, Iterable) and not isinstance(actions, (bytes, Mapping)))
    ):
        raise ConfigurationError(
            f"{case}: actions: expected a list, a policy, 'random' or an evidence file as a "
            f"Path, got {found(actions)}"
        )
    if case.make_policy is not None and not callable(case.make_policy):
        raise ConfigurationError(
            f"{case}: make_policy: expected a callable (env -> policy) or None, got "
            f"{found(case.make_policy)}"
        )
    if case.expect is not None and not isinstance(case.expect, (str, Expected)):
        raise ConfigurationError(
            f"{case}: expect: expected 'success', 'failure[:LABEL]', 'truncated[:REASON]' or "
            f"None, got {found(case.expect)}"
        )


def _integer(case: Any, name: str, low: int, high: int | None) -> int:
    """``case``'s field ``name`` as an ``int`` in ``low .. high``, else raise."""
    value = getattr(case, name)
    span = f">= {low}" if high is None else f"in {low} .. {high}"
    integer = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if integer and low <= int(value) and (high is None or int(value) <= high):
        return int(value)
    raise ConfigurationError(f"{case}: {name}: expected an int {span}, got {found(value)}")


def found(value: Any) -> str:
    """What a field held, for a message: its value (cut) and type, e.g. ``'0' (str)``."""
    return f"{short(value)} ({type(value).__name__})"


def contract_cases(env_ids: Iterable[str | EnvMaker], **case: Any) -> list[ContractCase]:
    """One :class:`ContractCase` per env id (or factory), the other fields ``case``'s.

    The cases print as their ids, so they read well as parametrize ids:

    >>> cases = contract_cases(["CartPole-v1", "Acrobot-v1"], actions="random", seed=3)
    >>> [str(c) for c in cases]
    ['CartPole-v1-seed3', 'Acrobot-v1-seed3']
    """
    base = ContractCase(env="", **case)
    return [replace(base, env=env) for env in env_ids]


def evidence_actions(path: str | os.PathLike[str], episode: int = 0) -> list[Any]:
    """The actions recorded for ``episode`` of the evidence file ``path``, in step order.

    Raises :class:`~episode_audit.errors.EvidenceError` for an unreadable file and
    :class:`~episode_audit.errors.ConfigurationError` when the file has no such episode or
    cannot decode its actions.
    """
    ev = open_evidence(path)
    steps = ev.steps(columns=[fmt.COL_ACTION], episodes=[episode])
    if steps.num_rows == 0:
        raise ConfigurationError(f"{path}: no steps of episode {episode} to take actions from")
    codec = ev.action_codec
    if codec is None:
        raise ConfigurationError(f"{path}: its action space cannot be decoded to take actions from")
    actions, missing = replay_actions(steps.column(fmt.COL_ACTION), codec)
    if missing is not None:
        raise ConfigurationError(
            f"{path}: episode {episode} has {len(missing)} step(s) without a recorded action "
            f"(first at step {int(missing[0])})"
        )
    return list(actions)


def evidence_folder(directory: str | os.PathLike[str]) -> Path:
    """``directory`` as a folder to keep a case's evidence file in, made (with its parents).

    A path that is a file, or under one, or that cannot be made is a
    :class:`~episode_audit.errors.ConfigurationError` saying so (not ``FileExistsError``).
    """
    out = Path(directory)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ConfigurationError(
            f"{out}: expected a folder to keep the evidence files in, got a file; give a "
            "folder, e.g. pytest's tmp_path"
        ) from None
    except OSError as exc:
        raise ConfigurationError(
            f"{out}: cannot make the folder for the evidence files ({exc.strerror or exc}); "
            "give a folder you can write to, e.g. pytest's tmp_path"
        ) from None
    return out
