"""A parameter is described once: in its workflow function's numpydoc ``Parameters`` section.
The command line's help and the docs' parameter table take the description from there when
its ``Param`` gives no help of its own, and every job's table, signature and docstring agree."""

from __future__ import annotations

import argparse
import inspect
from dataclasses import replace

import pytest

from pipeline import runner
from pipeline.commands.parameters import add_parameters
from pipeline.steps.docstrings import parameter_descriptions, plain
from pipeline.steps.parameters import Param, helps, parameters_table, python_only
from pipeline.workflows import WORKFLOWS

# the runner's own parameters (``pipeline.runner.run``: ``out``, ``store``...): a job's table
# may declare them for the command line without its function taking them
RUNNER = {n for n, p in inspect.signature(runner.run).parameters.items()
          if p.kind is inspect.Parameter.KEYWORD_ONLY}
UNDOCUMENTED = {  # jobs whose function has no numpydoc Parameters section yet
    "compare": "compare's docstring refers to train's parameters instead of listing its own",
}


def _functions(module) -> list:
    return [f for f in vars(module).values()
            if inspect.isfunction(f) and f.__module__ == module.__name__]


@pytest.mark.parametrize("record", [
    pytest.param(r, marks=pytest.mark.xfail(reason=UNDOCUMENTED[r.name], strict=True))
    if r.name in UNDOCUMENTED else r for r in WORKFLOWS], ids=lambda r: r.name)
def test_every_parameter_is_in_the_signature_and_the_docstring(record):
    """Each name of ``PARAMETERS`` is a parameter of the workflow function, described in its
    ``Parameters`` section; or one the runner takes itself (``out``, ``store``) or hands to a
    raw log's reader, described by its ``Param``; or a Python-only parameter of another
    function of the job's module (``convert``'s ``read``, ``write``)."""
    signature = inspect.signature(record.function).parameters
    described = parameter_descriptions(record.function)
    wrong = []
    for name, param in record.parameters.items():
        if name in signature:
            if not described.get(name):
                wrong.append(f"{name}: not described in {record.function.__name__}'s docstring")
        elif name in RUNNER or name in record.reader_options:
            if param.on_cli and not param.help:
                wrong.append(f"{name}: the runner's or the reader's, yet no help of its own")
        elif param.on_cli or not any(name in inspect.signature(f).parameters
                                     for f in _functions(record.module)):
            wrong.append(f"{name}: not a parameter of {record.function.__name__}")
    assert not wrong, wrong


@pytest.mark.parametrize("record", WORKFLOWS, ids=lambda r: r.name)
def test_every_command_line_parameter_has_a_help(record):
    described = helps(record.function, record.parameters)
    assert set(described) == {n for n, p in record.parameters.items() if p.on_cli}
    assert [n for n, text in described.items() if not text.strip()] == []


def _rank_without_help(monkeypatch, name: str):
    from pipeline.workflows import rank

    monkeypatch.setitem(rank.PARAMETERS, name, replace(rank.PARAMETERS[name], help=None))
    return rank


def test_a_param_without_help_takes_the_docstrings_description(monkeypatch):
    rank = _rank_without_help(monkeypatch, "k")
    parser = argparse.ArgumentParser()
    add_parameters(parser, "rank")
    option = next(a for a in parser._actions if a.dest == "k")
    assert option.help == "Neighbours of the weighted k-NN (default 5)"
    assert "| `k` | `--k` | `5` | Neighbours of the weighted k-NN |" in parameters_table(
        rank.rank, rank.PARAMETERS)
    model = helps(rank.rank, rank.PARAMETERS)["format"]
    assert model == "input layout of a file (default: detect)"  # its own help is kept


def test_the_docstrings_markup_is_dropped_from_the_help(monkeypatch):
    _rank_without_help(monkeypatch, "format")
    parser = argparse.ArgumentParser()
    add_parameters(parser, "rank")
    option = next(a for a in parser._actions if a.dest == "format")
    assert option.help == ("Input layout of a file (see features.readings.schema.FORMATS) "
                           "(default auto)")


def test_a_python_only_parameter_says_so():
    assert not python_only(None, callable).on_cli
    assert Param((str,)).on_cli and Param((str,), "a file").on_cli
    assert not Param((str,), "a file", cli=False).on_cli


def test_the_parameters_section_is_read_as_numpydoc_writes_it():
    def f(a, b, c=1, *args, **kwargs):
        """Summary.

        Parameters
        ----------
        a : int
            The first; ``a`` wraps
            onto a second line.
        b, c : float, default 1
            Both of them.

            A second paragraph.
        *args, **kwargs
            Passed on.

        Returns
        -------
        int
            Not a parameter.
        """

    assert parameter_descriptions(f) == {
        "a": "The first; ``a`` wraps onto a second line.",
        "b": "Both of them. A second paragraph.", "c": "Both of them. A second paragraph.",
        "args": "Passed on.", "kwargs": "Passed on."}
    assert parameter_descriptions(lambda: None) == {}
    assert plain("Use :func:`read` or ``x``; `y`.") == "Use read or x; y"
