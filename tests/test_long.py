"""Long harnesses, run by `make test-long` (marked slow; not part of `make test`)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests import kill_harness


@pytest.mark.slow
def test_kill_harness_never_loses_flushed_steps(tmp_path: Path) -> None:
    """SIGKILL recordings at random steps, inside flushes and inside close(): see kill_harness."""
    kills = int(os.environ.get("EPISODE_AUDIT_KILLS", "120"))
    verdicts = kill_harness.run(
        kills, tmp_path, seed=int(os.environ.get("EPISODE_AUDIT_SEED", "2026"))
    )
    print(kill_harness.summary(verdicts))
    assert len(verdicts) == kills
    assert [(v.plan.index, v.problems) for v in verdicts if v.problems] == []
