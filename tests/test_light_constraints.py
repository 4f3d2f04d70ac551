"""``pipeline.workflows.constraints`` accepts and refuses what scikit-learn's constraints do,
in the same words, and lets a workflow that fits nothing check its parameters without
importing scikit-learn."""

from __future__ import annotations

import os
import subprocess
import sys
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pytest
from sklearn.utils import _param_validation as sk

from features.readings.errors import InputError
from pipeline.workflows import check_params
from pipeline.workflows import constraints as light

REPO = Path(__file__).resolve().parents[1]
VALUES = [None, 0, 0.0, -1, 1, 2, 0.5, 0.25, float("nan"), float("inf"), -float("inf"), True,
          "x", "csv", [1], {}, 3.0, 7, 2.0, -1.5, Path("a.csv"), np.bool_(False),
          np.array([2.0, 4.0]), np.float64(3.0), (1, 2)]


def _pairs():
    formats = {"auto", "csv", "wide"}
    return {
        "format": ([light.StrOptions(formats)], [sk.StrOptions(formats)]),
        "threshold": ([light.Interval(Real, 0, None, closed="neither"), None],
                      [sk.Interval(Real, 0, None, closed="neither"), None]),
        "alpha": ([light.Interval(Real, 0, 0.5, closed="neither")],
                  [sk.Interval(Real, 0, 0.5, closed="neither")]),
        "bounds": ([light.Interval(Real, -1.5, 2, closed="both")],
                   [sk.Interval(Real, -1.5, 2, closed="both")]),
        "bins": ([light.Interval(Integral, 2, None, closed="left")],
                 [sk.Interval(Integral, 2, None, closed="left")]),
        "model": ([str, os.PathLike, light.HasMethods(["predict"]), None],
                  [str, os.PathLike, sk.HasMethods(["predict"]), None]),
        "estimator": ([light.HasMethods(["fit", "predict"])], [sk.HasMethods(["fit", "predict"])]),
        "budget": ([str, os.PathLike, dict, None], [str, os.PathLike, dict, None]),
        "verify": (["boolean"], ["boolean"]),
        "classes": ([light.Interval(Integral, 2, None, closed="left"), str, "array-like"],
                    [sk.Interval(Integral, 2, None, closed="left"), str, "array-like"]),
    }


@pytest.mark.parametrize("name", sorted(_pairs()))
def test_the_same_values_pass_and_fail_in_the_same_words(name):
    ours, theirs = _pairs()[name]
    for value in VALUES:
        try:
            sk.validate_parameter_constraints({name: theirs}, {name: value}, "drift")
            expected = None
        except sk.InvalidParameterError as err:
            expected = str(err)
        assert light.violation(ours, value, name, "drift") == expected, value


def test_check_params_words_both_kinds_alike():
    ours, theirs = _pairs()["alpha"]
    messages = []
    for constraints in (ours, theirs):
        with pytest.raises(InputError) as err:
            check_params({"alpha": constraints}, {"alpha": 0.7}, "drift")
        assert err.value.parameter == "alpha"
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert "must be a float in the range (0.0, 0.5); got 0.7" in messages[0]


def test_drift_checks_its_parameters_without_scikit_learn():
    code = ("import sys\n"
            "from pipeline.workflows import check_params, drift\n"
            "try:\n"
            "    check_params(drift.PARAMETERS, {'alpha': 0.7}, 'drift')\n"
            "except Exception as err:\n"
            "    print(type(err).__name__)\n"
            "print('sklearn' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
    assert done.stdout.split() == ["InputError", "False"]
