"""Workflows are pure functions: typed parameters in, a result out. They open no tracking store
and log nothing, so no module under ``pipeline/workflows`` imports the tracking package, MLflow
or Optuna; the runner does the tracking their records declare. Nor do they open a fleet store
or record in one: no workflow calls ``open_store`` or ``open_for_records`` or imports
``pipeline.store.records``; the runner opens the store their records declare. The shared steps
(``pipeline/steps``) sit below the workflows: no step imports ``pipeline.workflows``, neither a
job nor the package's records and helpers. Imports inside functions count too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WORKFLOWS = sorted((ROOT / "pipeline" / "workflows").rglob("*.py"))
STEPS = sorted((ROOT / "pipeline" / "steps").rglob("*.py"))
FORBIDDEN = ("pipeline.tracking", "mlflow", "optuna")


def imported_names(source: str, package: str) -> list[tuple[int, str]]:
    """(line, module) of every import in ``source``, at any depth: ``import a.b``, ``from a
    import b`` (as ``a.b``), relative imports resolved against ``package``, and
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
            found += [(node.lineno, f"{base}.{alias.name}" if base else alias.name)
                      for alias in node.names]
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


def store_use(source: str, package: str = "pipeline.workflows") -> list[str]:
    """``line: what`` of every call or import of ``open_store``/``open_for_records`` and
    every import from ``pipeline.store.records`` (but ``PURE_RECORDS``) in ``source``, at any
    depth (``imported_names``)."""
    def recording(name: str) -> bool:
        return (name.rsplit(".", 1)[-1] in OPENERS or name == RECORDS
                or (name.startswith(f"{RECORDS}.")
                    and name.removeprefix(f"{RECORDS}.") not in PURE_RECORDS))

    found = [f"{line}: imports {name}" for line, name in imported_names(source, package)
             if recording(name)]
    for node in ast.walk(ast.parse(source)):
        name = isinstance(node, ast.Call) and getattr(node.func, "attr",
                                                      getattr(node.func, "id", None))
        if name in OPENERS:
            found.append(f"{node.lineno}: calls {name}")
    return found


@pytest.mark.parametrize("path", WORKFLOWS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_workflow_opens_a_store_or_records_in_one(path):
    assert store_use(path.read_text(encoding="utf-8")) == []


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


# ---------------------------------------------------------------------- the steps
# The shared steps sit below the jobs: a step imports ``features``, ``models`` and the rest of
# ``pipeline``, never ``pipeline.workflows`` (a job, its records or its helpers), not even
# inside a function; no step is exempt. What a step needs of a job's record its caller passes.
WORKFLOWS_PACKAGE = "pipeline.workflows"


def imports_workflows(source: str, package: str = "pipeline.steps") -> list[str]:
    """``line: module`` of every import of ``pipeline.workflows`` or a module under it in
    ``source``, at any depth (``imported_names``)."""
    return [f"{line}: {name}" for line, name in imported_names(source, package)
            if name == WORKFLOWS_PACKAGE or name.startswith(f"{WORKFLOWS_PACKAGE}.")]


def test_the_steps_are_checked():
    assert {p.name for p in STEPS} >= {"__init__.py", "parameters.py", "source.py"}


@pytest.mark.parametrize("path", STEPS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_step_imports_the_workflows(path):
    assert imports_workflows(path.read_text(encoding="utf-8")) == []


@pytest.mark.parametrize("source", [
    "from pipeline.workflows import workflow\n",
    "from pipeline import workflows\n",
    "import pipeline.workflows\n",
    "from pipeline.workflows.iso import IsoResult\n",
    "def f():\n    from pipeline.workflows import readings_of\n",
    "class S:\n    def g(self):\n        import pipeline.workflows.fleet as f\n",
    "from ..workflows import check_params\n",
    "from .. import workflows\n",
    "import importlib\nimportlib.import_module('pipeline.workflows.drift')\n",
    "__import__('pipeline.workflows')\n",
])
def test_the_steps_check_sees_every_kind_of_import(source):
    assert imports_workflows(source) != []


def test_the_steps_check_leaves_other_imports_alone():
    assert imports_workflows("from pipeline.steps.constraints import Interval\n"
                             "from pipeline.results import Result\n"
                             "from . import source\nfrom .source import readings_of\n"
                             "import pipeline.workflows_notes\n"
                             "def f():\n    from pipeline.store import redact\n") == []
