"""Collection: an optional extra's modules are doctested only where the extra is installed.

``--doctest-modules`` imports every module of ``episode_audit``; those of the SB3 and PettingZoo
recorders import their library at the top, so without it (a Python the ``dev`` extra's torch
has no wheel for, say) they are not collected, and their tests skip.
"""

from __future__ import annotations

from importlib.util import find_spec
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent / "episode_audit"
_NEEDS = {
    _PACKAGE / "record" / "sb3": "stable_baselines3",
    _PACKAGE / "record" / "pettingzoo": "pettingzoo",
}


def pytest_ignore_collect(collection_path: Path) -> bool | None:
    """Skip the folder of a recorder whose optional library is not installed."""
    package = _NEEDS.get(collection_path)
    return True if package is not None and find_spec(package) is None else None
