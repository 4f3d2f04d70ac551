"""``pipeline.workflows.check_params`` checks with scikit-learn's own constraints and
``validate_parameter_constraints``, and words the error from the constraint objects:
"must be A, B or C; got X", as scikit-learn lists them in its own message."""

from __future__ import annotations

import os
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sklearn.utils import _param_validation as sk

from features.readings.errors import InputError
from pipeline.workflows import WORKFLOWS, check_params
from pipeline.workflows import constraints as ours

VALUES = [None, 0, 0.0, -1, 1, 2, 0.5, 0.25, float("nan"), float("inf"), -float("inf"),
          "x", "csv", [1], {}, 3.0, 7, 2.0, -1.5, Path("a.csv"), np.bool_(False),
          np.array([2.0, 4.0]), np.float64(3.0), (1, 2)]
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


def test_the_classes_are_scikit_learns():
    assert ours.Interval is sk.Interval and ours.HasMethods is sk.HasMethods
    assert isinstance(ours.StrOptions(("b", "a")), sk.StrOptions)
    assert isinstance(ours.Options(int, (2, 1)), sk.Options)


@pytest.mark.parametrize("name", sorted(CONSTRAINTS))
def test_scikit_learn_decides_and_its_words_are_kept(name):
    given = CONSTRAINTS[name]
    theirs = ours.resolved(given)
    for value in VALUES:
        try:
            sk.validate_parameter_constraints({name: theirs}, {name: value}, "drift")
            expected = None
        except sk.InvalidParameterError as err:
            expected = str(err)
        try:
            check_params({name: given}, {name: value}, "drift")
            message = None
        except InputError as err:
            assert err.parameter == name
            message = err.message
        if expected is None:
            assert message is None, value
        else:  # the same list of constraints, and the value as scikit-learn shows it
            listed, _, got = message.removeprefix("must be ").rpartition("; got ")
            assert expected == (f"The {name!r} parameter of drift must be {listed}. "
                                f"Got {got} instead."), value


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
    with pytest.raises(InputError, match=r"must be an int in the range \[0, 4294967295\]; "
                                         "got True"):
        check_params({"seed": seed}, {"seed": True}, "simulate")
    check_params({"seed": seed}, {"seed": 1}, "simulate")
    check_params({"flag": [ours.Options(bool, (True, False))]}, {"flag": True}, "simulate")
    check_params({"verify": ["boolean"]}, {"verify": np.bool_(True)}, "store")


def test_a_dotted_type_is_imported_when_a_value_is_checked():
    check_params({"data": CONSTRAINTS["data"]}, {"data": pd.DataFrame()}, "drift")
    with pytest.raises(InputError, match="or an instance of 'pandas.DataFrame'; got 3"):
        check_params({"data": CONSTRAINTS["data"]}, {"data": 3}, "drift")


def test_no_name_is_skipped():
    with pytest.raises(InputError, match="is not a parameter of drift; expected one of alpha"):
        check_params({"alpha": CONSTRAINTS["alpha"]}, {"alhpa": 0.1}, "drift")


@pytest.mark.parametrize("record", WORKFLOWS, ids=lambda r: r.name)
def test_every_table_speaks_scikit_learns_language(record):
    """Every constraint of every job is one scikit-learn makes (a dotted type once imported)."""
    for name, param in record.parameters.items():
        for c in ours.resolved(param.accepts):
            assert isinstance(sk.make_constraint(c), sk._Constraint), (name, c)
