"""`episode_audit.__all__` is exactly the public surface, sorted; every export is documented."""

from __future__ import annotations

import inspect

import episode_audit


def test_all_is_sorted_and_complete() -> None:
    names = episode_audit.__all__
    assert list(names) == sorted(names)
    public = {
        name
        for name, value in vars(episode_audit).items()
        if not name.startswith("_") and not inspect.ismodule(value)
    }
    # the PettingZoo recorders are loaded on first access (pettingzoo is optional)
    assert public | {"__version__"} | set(episode_audit._LAZY) == set(names)


def test_every_export_is_documented() -> None:
    for name in episode_audit.__all__:
        value = getattr(episode_audit, name)
        if inspect.isclass(value) or inspect.isfunction(value):
            assert value.__doc__ and value.__doc__.strip(), name
