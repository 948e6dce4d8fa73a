"""Record a test's own rollout: :class:`RolloutRecorder`, behind the ``record_evidence`` fixture."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium as gym
from typing_extensions import Unpack

from ..errors import ConfigurationError
from ..read import Evidence, open_evidence
from ..record import RecordEvidence
from ..record.settings import RecorderOptions

__all__ = ["RolloutRecorder"]


class RolloutRecorder:
    """Wraps a test's envs in :class:`~episode_audit.RecordEvidence`, writing to ``directory``.

    Call it with an env (and recorder options) to get the recording env; :meth:`evidence`
    closes the recorder and opens the file. Recorders left open are closed by :meth:`close`.

    >>> import tempfile, gymnasium as gym
    >>> record = RolloutRecorder(tempfile.mkdtemp())
    >>> env = record(gym.make("CartPole-v1", max_episode_steps=3))
    >>> _ = env.reset(seed=0)
    >>> for _ in range(3):
    ...     _ = env.step(1)
    >>> record.evidence().episodes().column("outcome").to_pylist()
    ['truncated']
    """

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.directory = Path(directory)
        self._recorders: list[RecordEvidence[Any, Any]] = []

    def __call__(
        self,
        env: gym.Env[Any, Any],
        name: str = "rollout",
        **options: Unpack[RecorderOptions],
    ) -> RecordEvidence[Any, Any]:
        """Record ``env`` to ``directory/NAME.mcap``; return the recording env."""
        path = self.directory / f"{name}.mcap"
        if any(r.path == path for r in self._recorders):
            raise ConfigurationError(
                f"record_evidence: {path} is already recorded by this test; give another name="
            )
        recorder = RecordEvidence(env, path, **options)
        self._recorders.append(recorder)
        return recorder

    @property
    def path(self) -> Path:
        """The file of the last env recorded."""
        return Path(self._last().path)

    def evidence(self, name: str | None = None) -> Evidence:
        """Close the recorder of ``name`` (default: the last one) and open its file."""
        recorder = self._last() if name is None else self._named(name)
        recorder.close()
        return open_evidence(recorder.path)

    def close(self) -> None:
        """Close every recorder still open (safe to call twice)."""
        for recorder in self._recorders:
            recorder.close()

    def _last(self) -> RecordEvidence[Any, Any]:
        if not self._recorders:
            raise ConfigurationError("record_evidence: no env recorded yet: call it with an env")
        return self._recorders[-1]

    def _named(self, name: str) -> RecordEvidence[Any, Any]:
        path = self.directory / f"{name}.mcap"
        for recorder in self._recorders:
            if Path(recorder.path) == path:
                return recorder
        raise ConfigurationError(f"record_evidence: no env recorded as {name!r}")
