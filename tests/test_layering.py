"""The package's layering: no import cycles, and no wing imports a wing above it.

Every import counts, at module level or inside a function (a lazy import is still a dependency),
``TYPE_CHECKING`` blocks included. The wings, lowest first (docs/architecture.md):

    0  errors, _version
    1  format, tasks, _jobs
    2  _usercode, record, read
    3  check, replay, report, recover, export, rollout
    4  compare, testing
    5  cli
    6  demo, __main__, the package's __init__

A module may import its own wing and the wings of lower rank, never a wing of its own rank or
above (``record`` and ``read`` are siblings: neither imports the other).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "episode_audit"
NAME = "episode_audit"

RANK = {
    "errors": 0,
    "_version": 0,
    "format": 1,
    "tasks": 1,
    "_jobs": 1,
    "_usercode": 2,
    "record": 2,
    "read": 2,
    "check": 3,
    "replay": 3,
    "report": 3,
    "recover": 3,
    "export": 3,
    "rollout": 3,
    "testing": 4,
    "compare": 4,
    "cli": 5,
    "demo": 6,
    "__main__": 6,
    "": 6,  # episode_audit/__init__.py
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([NAME, *parts])


def known_modules() -> dict[str, Path]:
    return {module_name(p): p for p in PACKAGE.rglob("*.py")}


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``path`` imports (``from x import y``: ``x.y`` if a module)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            targets = [source] + [f"{source}.{alias.name}" for alias in node.names]
        for target in targets:
            if target in modules and target != name:
                found.add(target)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = known_modules()
    return {name: imports_of(path, modules) for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` (as the list of its modules, first repeated), or None.

    An import of a package's own ``__init__`` by its submodules is not followed: importing a
    submodule runs its package's ``__init__`` first, but the ``__init__`` re-exporting the
    submodule's names is not a dependency of the submodule on it.
    """
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if node.startswith(nxt + "."):
                continue  # a submodule importing from its own package
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt]
            if state.get(nxt) is None:
                found = visit(nxt)
                if found is not None:
                    return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if state.get(node) is None:
            found = visit(node)
            if found is not None:
                return found
    return None


def wing(module: str) -> str:
    return module.removeprefix(NAME).lstrip(".").split(".")[0]


def layering_violations(graph: dict[str, set[str]]) -> list[str]:
    problems = []
    for module, targets in sorted(graph.items()):
        own = wing(module)
        for target in sorted(targets):
            other = wing(target)
            if other == own or module.startswith(target + "."):
                continue
            if RANK[other] >= RANK[own]:
                problems.append(f"{module} (wing {own!r}) imports {target} (wing {other!r})")
    return problems


def test_every_module_belongs_to_a_known_wing() -> None:
    assert sorted({wing(m) for m in known_modules()} - RANK.keys()) == []


def test_the_package_has_no_import_cycle() -> None:
    assert find_cycle(import_graph()) is None


def test_no_wing_imports_a_wing_at_or_above_its_rank() -> None:
    assert layering_violations(import_graph()) == []


def test_the_lower_wings_never_import_the_higher_ones() -> None:
    graph = import_graph()
    lower = [m for m in graph if wing(m) in ("format", "read", "record", "errors")]
    higher = ("check", "replay", "report", "cli", "recover", "export", "rollout", "testing")
    assert [(m, t) for m in lower for t in graph[m] if wing(t) in higher] == []


@pytest.mark.parametrize(
    ("graph", "cycle"),
    [
        ({"a": {"b"}, "b": {"a"}}, ["a", "b", "a"]),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a", "b", "c", "a"]),
        ({"p.x": {"p.y"}, "p.y": {"p.x"}, "p": {"p.x"}}, ["p.x", "p.y", "p.x"]),
        ({"a": {"b"}, "b": set()}, None),
        ({"p": {"p.x"}, "p.x": {"p"}}, None),  # a submodule importing its own package
    ],
)
def test_the_cycle_finder_finds_cycles(graph: dict[str, set[str]], cycle: list[str] | None) -> None:
    assert find_cycle(graph) == cycle


def test_the_layering_check_sees_an_upward_import() -> None:
    graph = {f"{NAME}.read.reader": {f"{NAME}.check.core"}, f"{NAME}.check.core": set()}
    assert layering_violations(graph) == [
        f"{NAME}.read.reader (wing 'read') imports {NAME}.check.core (wing 'check')"
    ]
