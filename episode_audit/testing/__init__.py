"""Environment contract tests: one success, one failure, one truncation -- checked from evidence.

- :class:`ContractCase` (an env, a seed, actions, the expected ending, terms at the last step),
  :func:`contract_cases` (one case per env id, for ``pytest.mark.parametrize``),
  :func:`evidence_actions` (a recorded episode's actions).
- :func:`check_contract` records a case and checks it with the library's own ``check``,
  ``replay`` and ``report``; a broken contract raises
  :class:`~episode_audit.errors.ContractViolation` (an ``AssertionError``).
- :class:`GameCase` and :func:`check_game_contract`: the same for a PettingZoo ``ParallelEnv``,
  each agent's ending.
- :class:`RolloutRecorder` records a test's own rollout.

The pytest plugin (module ``episode_audit_pytest``, loaded when the package is installed) gives
the fixtures ``env_contract`` and ``record_evidence`` over these; see docs/testing.md.
"""

from ..errors import ContractViolation
from .cases import (
    Actions,
    ContractCase,
    EnvMaker,
    Expected,
    Policy,
    contract_cases,
    evidence_actions,
    expected_ending,
)
from .contract import ContractResult, check_contract
from .games import GameCase, check_game_contract
from .rollouts import RolloutRecorder

__all__ = [
    "Actions",
    "ContractCase",
    "ContractResult",
    "ContractViolation",
    "EnvMaker",
    "Expected",
    "GameCase",
    "Policy",
    "RolloutRecorder",
    "check_contract",
    "check_game_contract",
    "contract_cases",
    "evidence_actions",
    "expected_ending",
]
