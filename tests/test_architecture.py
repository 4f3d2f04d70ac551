"""Workflows are pure functions: typed parameters in, a result out. They open no tracking store
and log nothing, so no module under ``pipeline/workflows`` imports the tracking package, MLflow
or Optuna; the runner does the tracking their records declare. Nor do they open a fleet store
or record in one: no workflow calls ``open_store`` or ``open_for_records`` or imports
``pipeline.store.records``; the runner opens the store their records declare. Imports inside
functions count too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WORKFLOWS = sorted((ROOT / "pipeline" / "workflows").rglob("*.py"))
FORBIDDEN = ("pipeline.tracking", "mlflow", "optuna")


def imported_names(source: str, package: str) -> list[tuple[int, str]]:
    """(line, module) of every import in ``source``, at any depth: ``import a.b``, ``from a
    import b`` (as ``a`` and ``a.b``), relative imports resolved against ``package``, and
    ``importlib.import_module("a")`` / ``__import__("a")`` with a literal name."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, *([base] if base else [])])
            found += [(node.lineno, base)]
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
        elif (isinstance(node, ast.Call) and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
              and getattr(node.func, "attr", getattr(node.func, "id", None))
              in ("import_module", "__import__")):
            found.append((node.lineno, node.args[0].value))
    return found


def forbidden(source: str, package: str = "pipeline.workflows") -> list[str]:
    return [f"{line}: {name}" for line, name in imported_names(source, package)
            if any(name == f or name.startswith(f"{f}.") for f in FORBIDDEN)]


@pytest.mark.parametrize("path", WORKFLOWS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_workflow_imports_tracking_mlflow_or_optuna(path):
    assert forbidden(path.read_text(encoding="utf-8")) == []


@pytest.mark.parametrize("source", [
    "import mlflow",
    "import optuna.trial",
    "def f():\n    from pipeline.tracking import runs\n",
    "def f():\n    from pipeline import tracking\n",
    "class R:\n    def g(self):\n        import pipeline.tracking.model_registry as m\n",
    "from ..tracking.runs import log_child",
    "import importlib\nimportlib.import_module('mlflow.pyfunc')",
])
def test_the_check_sees_every_kind_of_import(source):
    assert forbidden(source) != []


def test_the_check_leaves_other_imports_alone():
    assert forbidden("from pipeline.results import TrackingRecord\nimport models.estimators.tuning\n"
                     "from pipeline.workflows import imported\n") == []


# ---------------------------------------------------------------------- the fleet store
# No workflow opens a fleet store or records in one: the runner opens the store a job records
# into (``Workflow.records``) or operates on (``Workflow.store_access``) and hands it over.
OPENERS = ("open_store", "open_for_records")
RECORDS = "pipeline.store.records"
# what a record says, from records already read (fleet's axes): no store opened, nothing recorded
PURE_RECORDS = {"summary"}
# the one reader of a store a job takes as its data (``readings_of``)
READS_DATA = {"__init__.py": {"readings_of"}}


def store_use(source: str, package: str = "pipeline.workflows",
              allowed: frozenset = frozenset()) -> list[str]:
    """``line: what`` of every call or import of ``open_store``/``open_for_records`` and
    every import from ``pipeline.store.records`` (but ``PURE_RECORDS``) in ``source``, at any
    depth, outside the functions named in ``allowed``."""
    found = []

    def imported(line: int, base: str, names: list[str]) -> None:
        for name in names:
            full = f"{base}.{name}" if base else name
            if (name in OPENERS or full == RECORDS
                    or (base == RECORDS and name not in PURE_RECORDS)):
                found.append(f"{line}: imports {full}")

    def visit(node, inside: bool) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name in allowed:
            inside = True
        if not inside:
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name == RECORDS or alias.name.startswith(f"{RECORDS}."):
                        found.append(f"{node.lineno}: imports {alias.name}")
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join([*parts, *([base] if base else [])])
                imported(node.lineno, base, [alias.name for alias in node.names])
            elif isinstance(node, ast.Call):
                name = getattr(node.func, "attr", getattr(node.func, "id", None))
                literal = (node.args and isinstance(node.args[0], ast.Constant)
                           and node.args[0].value)
                if name in OPENERS:
                    found.append(f"{node.lineno}: calls {name}")
                elif (name in ("import_module", "__import__") and isinstance(literal, str)
                      and (literal == RECORDS or literal.startswith(f"{RECORDS}."))):
                    found.append(f"{node.lineno}: imports {literal}")
        for child in ast.iter_child_nodes(node):
            visit(child, inside)

    visit(ast.parse(source), False)
    return found


@pytest.mark.parametrize("path", WORKFLOWS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_workflow_opens_a_store_or_records_in_one(path):
    allowed = frozenset(READS_DATA.get(path.name, ()))
    assert store_use(path.read_text(encoding="utf-8"), allowed=allowed) == []


@pytest.mark.parametrize("source", [
    "from pipeline.store import open_store\n",
    "def f(s):\n    import pipeline.store as p\n    return p.open_store(s, write=True)\n",
    "def f(s):\n    from pipeline.store.records import open_for_records\n",
    "def f(s, r):\n    from pipeline.store.records import record\n    record(s, 'trace', r)\n",
    "from pipeline.store import records\n",
    "import pipeline.store.records\n",
    "from ..store.records import record_trace\n",
    "import importlib\nimportlib.import_module('pipeline.store.records')\n",
    "class C:\n    def g(self, s):\n        return open_for_records(s)\n",
])
def test_the_store_check_sees_every_way_to_open_or_record(source):
    assert store_use(source) != []


def test_the_store_check_leaves_the_rest_alone():
    assert store_use("from pipeline.store import redact, is_store\n"
                     "from pipeline.store.records import summary\n"
                     "from pipeline.store.content import KEYS\n"
                     "def f(store):\n    return store.exists() and store.location\n") == []
    reader = "def readings_of(data):\n    from pipeline.store import open_store\n" \
             "    return open_store(data)\n"
    assert store_use(reader, allowed=frozenset({"readings_of"})) == []
    assert store_use(reader) != []
