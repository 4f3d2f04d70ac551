"""A job's module leaves its parameters to the runner: ``pipeline.runner`` binds and checks
every call of a job against its ``PARAMETERS`` (``bl.<job>``, the CLI and experiment files all
run through it), so no job checks them again."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WORKFLOWS = ROOT / "pipeline" / "workflows"


def parameter_checks(path: Path) -> list[tuple[str, int]]:
    """Every call of ``check_params`` in ``path`` (by its name, an alias or as an attribute),
    as (the top-level function it is in, or ``<module>``; its line)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = {"check_params"} | {alias.asname for node in ast.walk(tree)
                                if isinstance(node, ast.ImportFrom)
                                for alias in node.names
                                if alias.name == "check_params" and alias.asname}
    found = []
    for top in tree.body:
        where = top.name if isinstance(top, (ast.FunctionDef, ast.AsyncFunctionDef,
                                              ast.ClassDef)) else "<module>"
        for node in ast.walk(top):
            if not isinstance(node, ast.Call):
                continue
            func = node.func
            if ((isinstance(func, ast.Name) and func.id in names)
                    or (isinstance(func, ast.Attribute) and func.attr == "check_params")):
                found.append((where, node.lineno))
    return found


def test_parameter_checks_finds_a_call_however_it_is_named(tmp_path):
    module = tmp_path / "job.py"
    module.write_text("from pipeline.workflows import check_params as cp\n"
                      "import pipeline.workflows as w\n"
                      "def job(x):\n    cp({}, {'x': x}, 'job')\n"
                      "class R:\n    def m(self):\n        w.check_params({}, {}, 'r')\n"
                      "check_params({}, {}, 'module')\n", encoding="utf-8")
    assert parameter_checks(module) == [("job", 4), ("R", 7), ("<module>", 8)]


def test_no_job_module_calls_a_parameter_check():
    """Not even a plain function of ``bl`` that is not a job (``read``, ``validate``,
    ``write``, ``backtest``: ``pipeline.api``'s table of them): it declares its check with
    ``pipeline.workflows.checked``, as scikit-learn's ``validate_params`` does."""
    calls = sorted(f"{path.relative_to(ROOT)}:{line} ({where})"
                   for path in WORKFLOWS.rglob("*.py") if path.name != "__init__.py"
                   for where, line in parameter_checks(path))
    assert calls == []


@pytest.mark.parametrize(("function", "call", "parameter"), [
    ("read", {"path": 3}, "path"),
    ("read", {"path": "x.csv", "format": "nope"}, "format"),
    ("validate", {"frame": None, "source": 3}, "source"),
    ("write", {"readings": None, "path": 3}, "path"),
    ("backtest", {"data": "x.csv", "seed": -1}, "seed"),
])
def test_a_plain_function_refuses_a_bad_parameter_before_it_runs(function, call, parameter):
    import backlash as bl
    from features.readings.errors import InputError

    with pytest.raises(InputError) as err:
        getattr(bl, function)(**call)
    assert err.value.parameter == parameter
