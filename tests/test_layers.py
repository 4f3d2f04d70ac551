"""The layers import one way only, ground floor up, and no modules import each other.

readings contract (``features.readings``) -> ``features`` -> ``models`` -> ``pipeline``.
Imports inside functions count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("features", "models", "pipeline")


def layer(module: str) -> int:
    if module == "features.readings" or module.startswith("features.readings."):
        return 0
    return {"features": 1, "models": 2, "pipeline": 3}[module.split(".")[0]]


def modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def imports(path: Path, known: dict[str, Path]) -> set[str]:
    """Project modules that ``path`` imports (``from pkg import sub`` counts as ``pkg.sub``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in known
                     else node.module for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name:
                found.add(name)
    return found


GRAPH = {name: imports(path, modules()) - {name} for name, path in modules().items()}


def test_no_module_imports_a_higher_layer():
    upward = sorted(f"{a} -> {b}" for a, deps in GRAPH.items() for b in deps
                    if layer(b) > layer(a))
    assert upward == []


def test_no_import_cycles():
    """Tarjan's strongly connected components: any component of two or more is a cycle
    (a package importing its own submodules through ``__init__`` is not one)."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert cycles == []


@pytest.mark.parametrize("package", ["features", "models"])
def test_lower_layers_never_import_pipeline(package):
    offenders = [str(p.relative_to(ROOT)) for p in (ROOT / package).rglob("*.py")
                 if any(line.lstrip().startswith(("from pipeline", "import pipeline"))
                        for line in p.read_text(encoding="utf-8").splitlines())]
    assert offenders == []


def test_jobs_do_not_import_jobs():
    """A workflow imports shared steps (``pipeline.steps``, ``features``, ``models``), never
    another workflow: the package's records and helpers are not jobs."""
    jobs = {name for name in GRAPH if name.startswith("pipeline.workflows.")}
    crossed = sorted(f"{a} -> {b}" for a in jobs for b in GRAPH[a] & jobs)
    assert crossed == []
