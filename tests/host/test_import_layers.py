"""The package's layers point one way: read from the sources' import statements (ast), not from a list.

What fails here is a new import circle, an upward import (post-flight code reaching into the live
recorder; the I/O-free core reaching for a transport or a thread) or a private name used across
packages. Imports under ``if TYPE_CHECKING:`` are for the type checker only and do not count; imports
inside functions do (they are deferred, not absent). A package's ``__init__`` importing its own modules
(a facade, often lazily) is not an edge: it would make every module that imports a sibling through the
package look circular.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "host" / "icgt"

POST_FLIGHT = {"export", "report", "mapping", "trajectories", "ingest", "geometry", "catalog", "detect"}
"""Packages that work on a finished log: they read recordings, never the live side."""
LIVE = (
    "icgt.recorder",
    "icgt.control",
    "icgt.mavlink.link",
    "icgt.device.link",
    "icgt.device.session",
    "icgt.device.port",
)
"""The live recorder and its transports."""
CORE = {"geotag", "sync", "clocks", "pose", "geodesy"}
"""The I/O-free core that the recorder and the offline recompute both feed: one thread, no transport."""
NOT_IN_CORE = ("threading", "socket", "select", "serial", "icgt.recorder", "icgt.mavlink.link", "icgt.device.link")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in ROOT.rglob("*.py")}


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _runtime_imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    out: list[ast.Import | ast.ImportFrom] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import | ast.ImportFrom):
            out.append(node)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return out


class Graph:
    """Runtime import edges between the package's modules, and the names each edge takes."""

    def __init__(self) -> None:
        self.modules = _modules()
        self.edges: dict[str, set[str]] = defaultdict(set)
        self.external: dict[str, set[str]] = defaultdict(set)
        self.names: list[tuple[str, str, str]] = []  # (importer, module imported from, name)
        for name, path in self.modules.items():
            package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
            for node in _runtime_imports(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    for alias in node.names:
                        self._add(name, alias.name)
                    continue
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([node.module] if node.module else []))
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    if sub in self.modules:
                        self._add(name, sub)
                    else:
                        self._add(name, base)
                        self.names.append((name, base, alias.name))

    def _add(self, importer: str, target: str) -> None:
        if not target.startswith("icgt"):
            self.external[importer].add(target)
            return
        if target == importer or (self.modules[importer].name == "__init__.py" and target.startswith(importer + ".")):
            return  # the package's facade over its own modules
        while target not in self.modules and "." in target:
            target = target.rsplit(".", 1)[0]
        self.edges[importer].add(target)


def _top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


GRAPH = Graph()


def test_the_graph_sees_the_package() -> None:
    """The reader works: it finds the modules and the edges everyone knows are there."""
    assert len(GRAPH.modules) > 100
    assert "icgt.pose" in GRAPH.edges["icgt.geotag.geotagger"]
    assert "icgt.sync" in GRAPH.edges["icgt.recorder.recorder"]
    assert "threading" in GRAPH.external["icgt.recorder.recorder"]


def test_no_module_imports_itself_in_a_circle() -> None:
    assert _cycles(GRAPH.edges) == []


def test_packages_form_no_circle() -> None:
    packages: dict[str, set[str]] = defaultdict(set)
    for a, targets in GRAPH.edges.items():
        for b in targets:
            if _top(a) != _top(b) and _top(a) and _top(b):
                packages[_top(a)].add(_top(b))
    assert _cycles(packages) == []


def test_post_flight_code_imports_nothing_from_the_live_recorder() -> None:
    upward = sorted(
        (a, b)
        for a, targets in GRAPH.edges.items()
        if _top(a) in POST_FLIGHT
        for b in targets
        if any(b == live or b.startswith(live + ".") for live in LIVE)
    )
    assert upward == []


def test_the_core_has_no_transport_and_no_thread() -> None:
    found = sorted(
        (a, b)
        for a in GRAPH.modules
        if _top(a) in CORE
        for b in GRAPH.edges[a] | GRAPH.external[a]
        if any(b == x or b.startswith(x + ".") for x in NOT_IN_CORE)
    )
    assert found == []


def test_no_private_name_crosses_a_package() -> None:
    crossing = sorted(
        (a, b, n)
        for a, b, n in GRAPH.names
        if n.startswith("_") and not n.startswith("__") and _top(a) != _top(b) and b.startswith("icgt")
    )
    assert crossing == []


def test_the_checks_fail_on_what_they_forbid() -> None:
    """The circle finder and the edge reader are not vacuous."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import x\nelse:\n    import y\n")
    names = [a.name for n in _runtime_imports(tree) if isinstance(n, ast.Import) for a in n.names]
    assert names == ["y"]
