"""Workflows are pure functions: typed parameters in, a result out. They open no tracking store
and log nothing, so no module under ``pipeline/workflows`` imports the tracking package, MLflow
or Optuna; the runner does the tracking their records declare. Imports inside functions
count too."""

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
    assert forbidden("from pipeline.results import TrackingRecord\nimport models.tuning\n"
                     "from pipeline.workflows import imported\n") == []
