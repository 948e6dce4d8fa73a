"""Collection: an optional extra's modules are doctested only where the extra is installed.

``--doctest-modules`` imports every module of ``episode_audit``; those of the SB3 and PettingZoo
recorders import their library at the top, so without it (a Python the ``dev`` extra's torch
has no wheel for, say) they are not collected, and their tests skip.
"""

from __future__ import annotations

from importlib.util import find_spec
from pathlib import Path

import episode_audit

_PACKAGE = Path(episode_audit.__file__).resolve().parent
_NEEDS = {
    _PACKAGE.joinpath(*module.split(".")): package
    for module, (package, _) in episode_audit._EXTRAS.items()
}
"""A recorder's folder: the library it needs (the package's own map of its optional recorders)."""


def pytest_ignore_collect(collection_path: Path) -> bool | None:
    """Skip the folder of a recorder whose optional library is not installed."""
    package = _NEEDS.get(collection_path)
    return True if package is not None and find_spec(package) is None else None
