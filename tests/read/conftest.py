"""The read wing's fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.read.helpers import record_cartpole


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_cartpole(tmp_path_factory.mktemp("rec") / "run.mcap")
