"""The recorder and replay leave the loop's context variables as they found them.

pyarrow's first conversion imports pandas, whose import sets ``decimal``'s context variable;
in the loop's context, that one variable makes numpy read its own context variables (at each
array made and each ufunc called) more slowly for the rest of the process.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

_RECORD = """
import gymnasium as gym
from episode_audit import RecordEvidence
env = RecordEvidence(gym.make("CartPole-v1"), sys.argv[1])
env.reset(seed=0)
for _ in range(30):
    env.step(env.action_space.sample())
env.close()
"""

_REPLAY = """
from episode_audit import replay
assert replay(sys.argv[1]).ok
"""

_SHOWN = """
import contextvars
print(sorted(v.name for v in contextvars.copy_context()), "pandas" in sys.modules)
"""


def _run(code: str, path: Path) -> str:
    """What ``code`` (then :data:`_SHOWN`) prints, run in a fresh interpreter."""
    return subprocess.run(
        [sys.executable, "-c", f"import sys\n{code}{_SHOWN}", str(path)],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    ).stdout.strip()


def test_recording_and_replay_leave_the_context_variables_as_they_were(tmp_path: Path) -> None:
    pytest.importorskip("pandas", reason="the variable is pandas' import's (pandas not installed)")
    path = tmp_path / "run.mcap"
    # (pandas imported in each: the case this is about happened)
    assert _run(_RECORD, path) == "[] True"
    assert _run(_REPLAY, path) == "[] True"
