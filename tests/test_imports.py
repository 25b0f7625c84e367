"""The import graph of pipeline/ and vision/: no cycles, no private names across modules.

Every ``import`` and ``from ... import`` of the two packages is read with :mod:`ast`, those inside
functions included (an import hidden in a function still makes a cycle, only a later one).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "vision")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).glob("*.py")):
            out[pkg if path.stem == "__init__" else f"{pkg}.{path.stem}"] = path
    return out


def _imports(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str | None, int]]:
    """``(imported module, imported name or None, line)`` of every import of a project module."""
    package = module.split(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names if a.name in modules]
        elif isinstance(node, ast.ImportFrom):
            target = (package + ("." + node.module if node.module else "")) if node.level else node.module
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in modules:
                    out.append((sub, None, node.lineno))
                elif target in modules:
                    out.append((target, a.name, node.lineno))
    return [(m, name, line) for m, name, line in out if m != module]


def _graph() -> tuple[dict[str, set[str]], list[str]]:
    modules = _modules()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    private = []
    for module, path in modules.items():
        for target, name, line in _imports(module, path, modules):
            graph[module].add(target)
            if name is not None and name.startswith("_") and not name.startswith("__"):
                private.append(f"{module}:{line} imports {name} from {target}")
    return graph, private


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_import_graph_has_no_cycle():
    graph, _ = _graph()
    assert _cycles(graph) == []


def test_no_module_imports_a_private_name_of_another():
    _, private = _graph()
    assert private == []


def test_the_checks_see_a_cycle_and_an_import_inside_a_function(tmp_path):
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    src = tmp_path / "x.py"
    src.write_text("import numpy\n\n\ndef f():\n    from .identify import _hidden, read_synced\n", encoding="utf-8")
    modules = {"pipeline.identify": ROOT / "pipeline" / "identify.py", "pipeline.x": src}
    assert _imports("pipeline.x", src, modules) == [("pipeline.identify", "_hidden", 5),
                                                     ("pipeline.identify", "read_synced", 5)]
