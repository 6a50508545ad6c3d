"""The import direction of the architecture, enforced.

The packages form layers, lowest first (docs/ARCHITECTURE.md):

    core  ->  companion  ->  twin  ->  analysis  ->  learn  ->  server

Every layer lives under the one namespace ``fpv_station`` (``fpv_station.core``, ...), the
only name an install puts into site-packages. A module may import from its own layer or
any layer below it, never above, and modules may not import each other in a cycle.
Imports under ``if TYPE_CHECKING:`` count too: a type that lives above you is a
dependency on the layer above, even if only the type checker follows it. ``web/`` is the browser's and imports no Python.

The walk is over the source (ast), not the import system, so a test run imports nothing
it checks and a lazy import inside a function is caught like any other.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NS = "fpv_station"
LAYERS = ("core", "companion", "twin", "analysis", "learn", "server")
RANK = {name: i for i, name in enumerate(LAYERS)}


@dataclass(frozen=True)
class Edge:
    source: str  # importing module, dotted
    target: str  # imported module (or package), dotted
    line: int


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([NS, *parts])


def layer(name: str) -> str | None:
    """The layer a dotted module name lies in (`fpv_station.core.x` -> `core`), or None."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == NS and parts[1] in RANK else None


def resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module an ``from ... import`` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    # For a package's __init__, "." is the package itself; for a module, its parent.
    base = base if is_package else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def project_modules() -> dict[str, Path]:
    return {
        module_name(path): path
        for layer in LAYERS
        for path in sorted((ROOT / layer).rglob("*.py"))
        if ".venv" not in path.parts
    }


def imported_names(module: str, path: Path, modules: dict[str, Path]):
    """(absolute module name, line) of every import in the file at `path`."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = resolve(module, is_package, node)
            # "from pkg import name" may import the submodule pkg.name.
            targets = [
                f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                for alias in node.names
            ]
        else:
            continue
        for target in targets:
            yield target, node.lineno


def import_edges(modules: dict[str, Path]) -> list[Edge]:
    return [
        Edge(module, target, line)
        for module, path in modules.items()
        for target, line in imported_names(module, path, modules)
        if layer(target)
    ]


def known_target(target: str, modules: dict[str, Path]) -> str | None:
    """The longest project module that ``target`` names or lies in."""
    parts = target.split(".")
    for n in range(len(parts), 0, -1):
        name = ".".join(parts[:n])
        if name in modules:
            return name
    return None


def import_cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of ``graph`` with more than one module
    (Tarjan): each is a set of modules that import each other in a cycle."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


# Known upward imports still to remove. Each entry must still exist (a fixed one fails the
# test until it is struck from here), and nothing may be added.
KNOWN_UPWARD: set[tuple[str, str]] = set()
KNOWN_CYCLES: list[set[str]] = []


MODULES = project_modules()
EDGES = import_edges(MODULES)


def test_the_walk_sees_the_layers():
    # Guards the test itself: an empty walk would pass everything.
    assert {layer(m) for m in MODULES} == set(LAYERS)
    assert len(EDGES) > 50


def test_every_import_points_down_the_layers():
    upward = [e for e in EDGES if RANK[layer(e.target)] > RANK[layer(e.source)]]
    new = [
        f"{MODULES[e.source].relative_to(ROOT)}:{e.line}: {e.source} imports {e.target}"
        for e in upward
        if (e.source, e.target) not in KNOWN_UPWARD
    ]
    assert not new, "imports that point up the layers:\n" + "\n".join(new)
    fixed = KNOWN_UPWARD - {(e.source, e.target) for e in upward}
    assert not fixed, f"fixed, strike from KNOWN_UPWARD: {sorted(fixed)}"


def test_no_import_cycles_between_modules():
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for e in EDGES:
        target = known_target(e.target, MODULES)
        # A package's __init__ importing its own submodules is how packages re-export.
        if target and target != e.source and not target.startswith(e.source + "."):
            graph[e.source].add(target)
    cycles = import_cycles(graph)
    new = [sorted(c) for c in cycles if c not in KNOWN_CYCLES]
    assert not new, f"modules that import each other in a cycle: {new}"
    fixed = [sorted(c) for c in KNOWN_CYCLES if c not in cycles]
    assert not fixed, f"fixed, strike from KNOWN_CYCLES: {fixed}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from . import x", "fpv_station.server.routes"),
        ("from .. import settings", "fpv_station.server"),
        ("from ..station import Station", "fpv_station.server.station"),
    ],
)
def test_relative_imports_resolve(source, expected):
    node = ast.parse(source).body[0]
    assert isinstance(node, ast.ImportFrom)
    assert resolve("fpv_station.server.routes.control", False, node) == expected


def test_a_cycle_is_found():
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


def test_every_import_of_ours_goes_through_the_namespace():
    """`import core` in a checkout finds the folder too, but it is a second copy of every
    module (other classes, other state) and, installed, someone else's `core` or nothing.
    Checked in every Python file of the tree: packages, tests, benchmarks."""
    ours = {*LAYERS, "web"}
    others = {
        ".".join(path.relative_to(ROOT).with_suffix("").parts): path
        for path in sorted(ROOT.rglob("*.py"))
        if not {*ours, NS, ".venv", "build", ".git"} & set(path.relative_to(ROOT).parts)
    }
    bare = [
        f"{path.relative_to(ROOT)}:{line}: {target}"
        for module, path in {**MODULES, **others}.items()
        for target, line in imported_names(module, path, MODULES)
        if target.split(".")[0] in ours
    ]
    assert len(others) > 50  # the walk sees the tests
    assert not bare, "imports outside the fpv_station namespace:\n" + "\n".join(bare)


def test_no_file_imports_a_test_module():
    """A test module holds tests: what several share (helpers, fixtures, flights with
    known answers) lives in the test kit (tests/*.py without `test_`, conftest.py), so
    running or changing one test module never runs or breaks another's imports."""
    importers = [
        path
        for folder in ("tests", "benchmarks")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if ".venv" not in path.parts
    ]
    found = []
    for path in importers:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            found += [
                f"{path.relative_to(ROOT)}:{node.lineno}: {name}"
                for name in names
                if name.split(".")[:2][-1].startswith("test_") and name.startswith("tests.")
            ]
    assert len(importers) > 50  # the walk sees the tests
    assert not found, "imports of test modules (move what they share to the kit):\n" + "\n".join(
        found
    )
