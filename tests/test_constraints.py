"""The jobs' tables declare scikit-learn's constraints without importing it
(``pipeline.steps.constraints``); ``pipeline.workflows.check_params`` converts them to
scikit-learn's own objects and lets its ``validate_parameter_constraints`` decide, wording the
error from those objects: "must be A, B or C; got X", as scikit-learn lists them in its own
message."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sklearn.utils import _param_validation as sk

from features.readings.errors import InputError
from pipeline.steps import constraints as ours
from pipeline.workflows import WORKFLOWS, _converted, check_params

REPO = Path(__file__).resolve().parents[1]
VALUES = [None, True, False, 0, 0.0, -1, 1, 2, 0.5, 0.25, float("nan"), float("inf"),
          -float("inf"), "x", "", "csv", "auto", [1], {}, 3.0, 7, 2.0, -1.5, 2**32,
          Path("a.csv"), np.bool_(False), np.array([2.0, 4.0]), np.float64(3.0), np.int64(4),
          (1, 2), pd.DataFrame(), object(), print]
CONSTRAINTS = {
    "format": [ours.StrOptions(("auto", "csv", "wide"))],
    "threshold": [ours.Interval(Real, 0, None, closed="neither"), None],
    "alpha": [ours.Interval(Real, 0, 0.5, closed="neither")],
    "bins": [ours.Interval(Integral, 2, None, closed="left"), str, "array-like"],
    "model": [str, os.PathLike, ours.HasMethods(["predict"]), None],
    "estimator": [ours.HasMethods(["fit", "predict"])],
    "verify": ["boolean"],
    "data": [str, os.PathLike, "pandas.DataFrame"],
    "mode": [sk.StrOptions({"a", "b"}), ours.Options(int, (3, 1, 2))],
}
# the same, written with scikit-learn's own classes
SKLEARN = {
    "format": [sk.StrOptions({"auto", "csv", "wide"})],
    "threshold": [sk.Interval(Real, 0, None, closed="neither"), None],
    "alpha": [sk.Interval(Real, 0, 0.5, closed="neither")],
    "bins": [sk.Interval(Integral, 2, None, closed="left"), str, "array-like"],
    "model": [str, os.PathLike, sk.HasMethods(["predict"]), None],
    "estimator": [sk.HasMethods(["fit", "predict"])],
    "verify": ["boolean"],
    "data": [str, os.PathLike, pd.DataFrame],
    "mode": [sk.StrOptions({"a", "b"}), sk.Options(int, {3, 1, 2})],
}


def scikit_learns(c):
    """scikit-learn's own object for declaration ``c``, built here from its fields."""
    if isinstance(c, ours.Interval):
        return sk.Interval(c.type, c.left, c.right, closed=c.closed)
    if isinstance(c, ours.StrOptions):
        return sk.StrOptions(set(c.options), deprecated=set(c.deprecated) or None)
    if isinstance(c, ours.Options):
        return sk.Options(c.type, set(c.options), deprecated=set(c.deprecated) or None)
    if isinstance(c, ours.HasMethods):
        return sk.HasMethods(list(c.methods))
    if isinstance(c, str) and "." in c:
        module, _, name = c.rpartition(".")
        return getattr(__import__(module, fromlist=[name]), name)
    return c


def samples(accepts) -> list:
    """Values to try on a parameter: ``VALUES``, and the edges of what it declares."""
    values = list(VALUES)
    for c in accepts:
        if isinstance(c, ours.Interval):
            for bound in (c.left, c.right):
                if bound is not None:
                    values += [bound, bound - 1, bound + 1, bound - 0.5, bound + 0.5,
                               float(bound), int(bound)]
        elif isinstance(c, ours.Options):
            values += [*c.options, *(f"{o}x" for o in c.options), *map(str, c.options)]
        elif isinstance(c, ours.HasMethods):
            values += [type("Has", (), dict.fromkeys(c.methods, lambda self: None))(),
                       type("Lacks", (), dict.fromkeys(c.methods[:-1], lambda self: None))()]
    return values


def test_the_declarations_take_scikit_learns_arguments():
    def arguments(parameters) -> list:
        return [(p.name, p.kind, p.default) for p in parameters]

    for name in ("Interval", "Options", "StrOptions", "HasMethods"):
        theirs = list(inspect.signature(getattr(sk, name).__init__).parameters.values())[1:]
        assert arguments(inspect.signature(getattr(ours, name)).parameters.values()) == \
            arguments(theirs), name


def test_a_declaration_builds_scikit_learns_own_object():
    made = {ours.Interval(Integral, 1, None, closed="left"): sk.Interval,
            ours.Options(int, (2, 1)): sk.Options, ours.StrOptions(("b", "a")): sk.StrOptions,
            ours.HasMethods("predict"): sk.HasMethods}
    for declared, cls in made.items():
        assert not isinstance(declared, sk._Constraint)
        assert type(declared.sklearn()) is cls
        assert sk.make_constraint(declared.sklearn()) is not None
        assert str(declared) == str(declared.sklearn())  # scikit-learn's words
    assert ours.StrOptions(("b", "a")).sklearn().options == ("b", "a")  # the order kept
    assert ours.StrOptions({"b", "c", "a"}).options == ("a", "b", "c")  # a set's sorted
    assert ours.HasMethods("predict").sklearn().methods == ["predict"]


@pytest.mark.parametrize("name", sorted(CONSTRAINTS))
def test_scikit_learn_decides_and_its_words_are_kept(name):
    given, theirs = CONSTRAINTS[name], SKLEARN[name]
    converted = ours.resolved(given)
    for value in VALUES:
        try:
            sk.validate_parameter_constraints({name: theirs}, {name: value}, "drift")
            passes = not (isinstance(value, bool) and not ours.takes_bool(theirs))
        except sk.InvalidParameterError:
            passes = False
        try:  # scikit-learn's message with the converted objects (a tuple keeps its order)
            sk.validate_parameter_constraints({name: converted}, {name: value}, "drift")
            expected = None
        except sk.InvalidParameterError as err:
            expected = str(err)
        try:
            check_params({name: given}, {name: value}, "drift")
            message = None
        except InputError as err:
            assert err.parameter == name
            message = err.message
        assert (message is None) == passes, value
        if expected is not None:  # the same list of constraints, and the value as it shows it
            listed, _, got = message.removeprefix("must be ").rpartition("; got ")
            assert expected == (f"The {name!r} parameter of drift must be {listed}. "
                                f"Got {got} instead."), value


@pytest.mark.parametrize("record", WORKFLOWS, ids=lambda r: r.name)
def test_every_table_converts_to_what_scikit_learn_decides_alike(record):
    """Every constraint of every job converts to one scikit-learn accepts, taking and refusing
    the same values as scikit-learn's own object; and the runner's check of each parameter
    agrees with scikit-learn's on the table written with its own objects (True refused where
    no boolean is taken)."""
    table = record.parameters
    for name, param in table.items():
        converted = ours.resolved(param.accepts)
        theirs = [scikit_learns(c) for c in param.accepts]
        values = samples(param.accepts)
        for c, made, own in zip(param.accepts, converted, theirs, strict=True):
            assert not type(c).__module__.startswith(("sklearn", "numpy", "pandas")), (name, c)
            constraint = sk.make_constraint(made)
            assert isinstance(constraint, sk._Constraint), (name, c)
            if isinstance(c, ours.Declaration):
                assert type(made) is type(own) and str(c) == str(made), (name, c)
                assert [constraint.is_satisfied_by(v) for v in values] == \
                    [own.is_satisfied_by(v) for v in values], (name, c)
        for value in values:
            try:
                sk.validate_parameter_constraints({name: theirs}, {name: value}, record.name)
                passes = not (isinstance(value, bool) and not ours.takes_bool(theirs))
            except sk.InvalidParameterError:
                passes = False
            try:
                check_params(table, {name: value}, record.name)
                refused = False
            except InputError as err:
                assert err.parameter == name and err.message.startswith("must be ")
                refused = True
            assert refused != passes, (name, value)


def test_a_table_is_converted_once():
    table = {"bins": list(CONSTRAINTS["bins"])}
    check_params(table, {"bins": 3}, "rank")
    first = _converted(table, "bins")[0]
    check_params(table, {"bins": 4}, "rank")
    assert _converted(table, "bins")[0] is first and isinstance(first[0], sk.Interval)
    table["bins"] = [ours.Interval(Integral, 5, None, closed="left")]  # replaced: again
    with pytest.raises(InputError, match=r"must be an int in the range \[5, inf\); got 4"):
        check_params(table, {"bins": 4}, "rank")


def test_the_message_is_one_line_naming_the_parameter():
    with pytest.raises(InputError) as err:
        check_params({"alpha": CONSTRAINTS["alpha"]}, {"alpha": 0.7}, "drift")
    assert err.value.parameter == "alpha"
    assert err.value.message == "must be a float in the range (0.0, 0.5); got 0.7"
    assert err.value.line(lambda p: f"--{p}") == \
        "--alpha: must be a float in the range (0.0, 0.5); got 0.7"


def test_a_tuple_of_options_keeps_its_order():
    with pytest.raises(InputError, match=r"must be a str among \{'auto', 'csv', 'wide'\}; "
                                         r"got 'xml'"):
        check_params({"format": CONSTRAINTS["format"]}, {"format": "xml"}, "convert")


def test_true_is_no_number():
    seed = [ours.Interval(Integral, 0, 2**32 - 1, closed="both")]
    assert seed[0].sklearn().is_satisfied_by(True)  # scikit-learn takes it: bool is an int
    with pytest.raises(InputError, match=r"must be an int in the range \[0, 4294967295\]; "
                                         "got True"):
        check_params({"seed": seed}, {"seed": True}, "simulate")
    check_params({"seed": seed}, {"seed": 1}, "simulate")
    check_params({"flag": [ours.Options(bool, (True, False))]}, {"flag": True}, "simulate")
    check_params({"flag": [sk.Options(bool, {True, False})]}, {"flag": True}, "simulate")
    check_params({"verify": ["boolean"]}, {"verify": np.bool_(True)}, "store")


def test_a_dotted_type_is_imported_when_a_value_is_checked():
    check_params({"data": CONSTRAINTS["data"]}, {"data": pd.DataFrame()}, "drift")
    with pytest.raises(InputError, match="or an instance of 'pandas.DataFrame'; got 3"):
        check_params({"data": CONSTRAINTS["data"]}, {"data": 3}, "drift")


def test_no_name_is_skipped():
    with pytest.raises(InputError, match="is not a parameter of drift; expected one of alpha"):
        check_params({"alpha": CONSTRAINTS["alpha"]}, {"alhpa": 0.1}, "drift")


def test_the_command_line_reads_the_declarations():
    from pipeline.commands.parameters import _options, _parser
    from pipeline.steps.parameters import Param

    assert _options(CONSTRAINTS["format"]) == ("auto", "csv", "wide")
    assert _options([ours.StrOptions({"b", "a"})]) == ("a", "b")
    bins = _parser("bins", Param(tuple(CONSTRAINTS["bins"])))
    assert bins("3") == 3 and bins.__name__ == "int"
    with pytest.raises(Exception, match=r"'1': expected an int in the range \[2, inf\)"):
        bins("1")


def test_the_tables_import_no_numeric_library():
    """Every job's module and table, as ``backlash CMD --help`` imports them: no scikit-learn,
    numpy, scipy or pandas (``tests/test_startup.py`` runs the commands themselves)."""
    code = ("import sys\nfrom pipeline.workflows import WORKFLOWS\n"
            "tables = [len(w.parameters) for w in WORKFLOWS]\n"
            "print(','.join(m for m in ('sklearn', 'numpy', 'scipy', 'pandas') "
            "if m in sys.modules) or '-')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.stdout.split() == ["-"]
