"""A switch for the vector recorder's batched reading of step infos, for tests that compare
the batched path's files with the sub-env by sub-env path's."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from episode_audit.record.vector import steps as steps_module
from episode_audit.record.vector import terms as terms_module


class InfoReading:
    """Counts the steps whose info ``terms.<name>`` read for the batched path; with
    ``declining`` set, it reads none (they go sub-env by sub-env). The clocks are fixed, so
    both paths write the same times (the batched path reads one a vector step)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, name: str) -> None:
        monkeypatch.setattr(time, "monotonic_ns", lambda: 1_000_000_000)
        monkeypatch.setattr(time, "time_ns", lambda: 1_700_000_000_000_000_000)
        self.taken: list[bool] = []
        self.declining = False
        real = getattr(terms_module, name)

        def counted(*args: Any) -> Any:
            terms = None if self.declining else real(*args)
            self.taken.append(terms is not None)
            return terms

        for module in (terms_module, steps_module):  # (where the vector recorder calls it)
            if hasattr(module, name):
                monkeypatch.setattr(module, name, counted)

    def run(self, declining: bool) -> None:
        """Start a run (the counts from zero), batching or not."""
        self.taken.clear()
        self.declining = declining


def messages(path: Path) -> list[Any]:
    """Every message of a file: its topic, log time and bytes, in file order."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        return [
            (channel.topic, message.log_time, message.data)
            for _, channel, message in reader.iter_messages(log_time_order=False)
        ]
