"""The import graph of the tympani package: no cycles, no private names across modules, and
nothing imported under the checkout's folder names.

Every ``import`` and ``from ... import`` of the package is read with :mod:`ast`, those inside
functions included (an import hidden in a function still makes a cycle, only a later one).
Installed, ``vision/`` is ``tympani.vision``, ``pipeline/`` is ``tympani.pipeline`` and
``pipeline/api/`` is ``tympani`` itself.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: installed package name -> folder of the checkout
PACKAGES = {"tympani": ROOT / "pipeline" / "api", "tympani.vision": ROOT / "vision", "tympani.pipeline": ROOT / "pipeline"}


def _modules() -> dict[str, Path]:
    """Installed module name -> source file, for every module of the package."""
    out = {}
    for pkg, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if pkg == "tympani.pipeline" and parts[0] == "api":
                continue
            name = ".".join((pkg, *parts))
            out[name.removesuffix(".__init__")] = path
    return out


def _imports(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str | None, int]]:
    """``(imported module, imported name or None, line)`` of every import of a project module."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names if a.name in modules]
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            target = (base + ("." + node.module if node.module else "")) if node.level else node.module
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


def test_nothing_is_imported_under_a_folder_name():
    """``import vision`` works from the checkout (the current folder is on the path) but not once
    installed: every import names ``tympani``."""
    bad = []
    for path in [*_modules().values(), *sorted((ROOT / "tests").glob("*.py"))]:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            bad += [f"{path.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names
                    if n.split(".")[0] in ("vision", "pipeline")]
    assert bad == []


def test_the_checks_see_a_cycle_and_an_import_inside_a_function(tmp_path):
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    src = tmp_path / "x.py"
    src.write_text("import numpy\n\n\ndef f():\n    from .identify import _hidden, read_synced\n", encoding="utf-8")
    modules = {"tympani.pipeline.model.identify": ROOT / "pipeline" / "model" / "identify.py",
               "tympani.pipeline.model.x": src}
    assert _imports("tympani.pipeline.model.x", src, modules) == [("tympani.pipeline.model.identify", "_hidden", 5),
                                                     ("tympani.pipeline.model.identify", "read_synced", 5)]
