"""The workflow contract holds for every job: one record per job, the CLI and the API built on
it, a library that never prints, thin command modules."""

from __future__ import annotations

import ast
import warnings
from pathlib import Path

import pytest

from features.readings.errors import BacklashWarning, InputError
from pipeline import api
from pipeline.commands import NAMES as COMMANDS
from pipeline.workflows import NAMES as JOBS
from pipeline.workflows import Workflow, check_params, workflow

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = [p for package in ("features", "models") for p in (ROOT / package).rglob("*.py")]
LIBRARY += [p for p in (ROOT / "pipeline").rglob("*.py")
            if "commands" not in p.parts and p.name not in ("cli.py",)]


@pytest.mark.parametrize("name", JOBS)
def test_every_job_has_one_record_the_cli_uses(name):
    record = workflow(name)
    assert isinstance(record, Workflow) and record.name == name and callable(record.function)
    from pipeline.cli import build_parser

    command = build_parser().commands[name]
    assert command.description == record.summary


def test_the_command_registry_is_the_jobs_plus_the_runner():
    from pipeline.cli import build_parser

    assert COMMANDS == (*JOBS, "run")
    assert tuple(build_parser().commands) == COMMANDS


def test_every_public_api_name_resolves_to_a_documented_function():
    jobs = ["check_store" if job == "store" else job.replace("-", "_") for job in JOBS]
    assert sorted(api.__all__) == sorted([*api._WHERE, *jobs, "InputError", "BacklashWarning"])
    for name in api.__all__:
        value = getattr(api, name)
        assert value.__doc__, f"bl.{name} has no docstring"
    with pytest.raises(AttributeError):
        api.no_such_job  # noqa: B018


def test_the_library_never_prints():
    printing = []
    for path in LIBRARY:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id == "print"):
                printing.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not printing, printing


@pytest.mark.parametrize("path", sorted((ROOT / "pipeline" / "commands").glob("*.py")),
                         ids=lambda p: p.name)
def test_command_modules_are_thin(path):
    assert len(path.read_text(encoding="utf-8").splitlines()) <= 120


def test_check_params_names_the_parameter_and_what_it_expected():
    from numbers import Integral

    from sklearn.utils._param_validation import Interval, StrOptions

    constraints = {"bins": [Interval(Integral, 2, None, closed="left")],
                   "split": [StrOptions({"random", "forward"})]}
    check_params(constraints, {"bins": 5, "split": "forward"}, "rank")
    with pytest.raises(InputError, match=r"must be an int in the range \[2, inf\); got 1") as err:
        check_params(constraints, {"bins": 1}, "rank")
    assert err.value.parameter == "bins"
    assert err.value.line(lambda p: f"--{p}").startswith("--bins: must be")


def test_a_note_reaches_a_python_user_as_a_backlash_warning():
    from features.readings.errors import note

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        note("two readings left out")
    assert [w.category for w in caught] == [BacklashWarning]
    assert str(caught[0].message) == "two readings left out"


def test_the_docs_list_every_command_with_a_page_of_its_own():
    """The index's table of commands is made from the job records as the site is built."""
    import importlib.util

    from pipeline.commands import commands_table

    spec = importlib.util.spec_from_file_location("hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    page = hooks.render(index, "index.md")
    assert commands_table() in page and not hooks.MARKER.search(page)
    listed = [line.split("`backlash ")[1].split()[0].rstrip("`") for line in page.splitlines()
              if line.startswith("| `backlash ")]
    assert listed == list(JOBS) and "`backlash run FILE" in page
    assert "| `backlash store check STORE [options]` |" in page  # a command's own synopsis
    assert all((ROOT / "docs" / f"{name}.md").is_file() for name in COMMANDS)


def test_a_job_without_a_command_module_gets_the_default_command(capsys, monkeypatch):
    """A new job needs a command module only to print more than its result's short form:
    the default command gives its table's options and its JSON, as the job's own does."""
    import json

    from pipeline import commands
    from pipeline.cli import main
    from pipeline.commands.default import command

    budget = str(ROOT / "experiments" / "data" / "paper_uncertainty.toml")
    assert main(["uncertainty", budget, "--json", "--no-track"]) == 0
    own = json.loads(capsys.readouterr().out)
    assert commands.command_of("no-such-job").run is not None  # no module: the default
    monkeypatch.setattr(commands, "command_of", command)
    monkeypatch.setattr("pipeline.cli.command_of", command)
    assert main(["uncertainty", budget, "--json", "--no-track"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out) == own and out.err.startswith("UncertaintyResult")
