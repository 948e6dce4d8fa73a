"""The pytest plugin of episode-audit: environment contract fixtures (docs/testing.md).

Registered as the ``pytest11`` entry point ``episode_audit_pytest``, so an installed
episode-audit is active in every pytest run; it does nothing unless a test asks for one of its
fixtures. It lives outside the ``episode_audit`` package and imports it only inside the
fixtures, so loading it costs next to nothing (importing the package pulls in Gymnasium,
pyarrow and mcap).

- ``env_contract``: ``env_contract(case)`` checks a
  :class:`~episode_audit.testing.ContractCase` (or a ``GameCase``) with the evidence in the
  test's ``tmp_path``.
- ``record_evidence``: a :class:`~episode_audit.testing.RolloutRecorder` writing to
  ``tmp_path``; recorders left open are closed after the test.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from episode_audit.testing import ContractCase, ContractResult, GameCase, RolloutRecorder

__all__ = ["env_contract", "record_evidence"]


@pytest.fixture
def env_contract(tmp_path: Path) -> Callable[[ContractCase | GameCase], ContractResult]:
    """Check an environment contract case (or a game's), keeping its evidence in ``tmp_path``."""
    from episode_audit.testing import (
        ContractViolation,
        GameCase,
        check_contract,
        check_game_contract,
    )

    def run(case: ContractCase | GameCase) -> ContractResult:
        __tracebackhide__ = True
        try:
            if isinstance(case, GameCase):
                return check_game_contract(case, tmp_path)
            return check_contract(case, tmp_path)
        except ContractViolation as exc:
            broken = str(exc)
        pytest.fail(broken, pytrace=False)  # the message says it all: no traceback

    return run


@pytest.fixture
def record_evidence(tmp_path: Path) -> Iterator[RolloutRecorder]:
    """Record the test's own rollout to ``tmp_path``: call it with an env, then ``.evidence()``."""
    from episode_audit.testing import RolloutRecorder

    recorder = RolloutRecorder(tmp_path)
    yield recorder
    recorder.close()
