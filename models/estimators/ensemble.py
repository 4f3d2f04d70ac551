"""Bootstrap ensemble: intervals for predictors that have none of their own (networks).

Each member is a clone of ``estimator`` fitted on a bootstrap resample of the training points
(with its own seed); the prediction is the members' mean and its interval
mean +- t(n - 1, 0.975) sd sqrt(1 + 1/n), sd the members' spread: the uncertainty of the fitted
function from the data it saw (Efron and Tibshirani, An Introduction to the Bootstrap, 1993,
ch. 6), which is what a forecast of the true backlash needs; measurement noise is not in it.
Members are saved through ``models.serving.persistence`` side by side with an ``ensemble.json``.
"""

from __future__ import annotations

from numbers import Integral, Real
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy.special import stdtrit  # Student t quantile; scipy.stats costs a second to import
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context, clone
from sklearn.utils._param_validation import HasMethods, Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from features.readings.errors import InputError
from models.serving.persistence import (
    check_spec,
    checked_params,
    load_estimator,
    read_state,
    restore_inputs,
    save_estimator,
    write_state,
)

FILE_NAME = "ensemble.json"


class BootstrapEnsemble(RegressorMixin, BaseEstimator):
    """Mean of ``n_members`` bootstrap fits of ``estimator``, with ``predict_interval``.

    Parameters
    ----------
    estimator : regressor
        The model each member clones.
    n_members : int
        Bootstrap fits, at least 2 (their spread is the interval).
    random_state : int
        Seed of the resamples; member i gets ``random_state + i`` when it takes one.
    level : float
        Coverage of ``predict_interval`` (default 0.95).
    """

    _parameter_constraints: ClassVar[dict] = {
        "estimator": [HasMethods(["fit", "predict"])],
        "n_members": [Interval(Integral, 2, None, closed="left")],
        "random_state": [Interval(Integral, 0, None, closed="left")],
        "level": [Interval(Real, 0, 1, closed="neither")],
    }

    def __init__(self, estimator=None, n_members: int = 5, random_state: int = 0,
                 level: float = 0.95):
        self.estimator = estimator
        self.n_members = n_members
        self.random_state = random_state
        self.level = level

    @_fit_context(prefer_skip_nested_validation=False)
    def fit(self, X, y):
        checked, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        X = X if hasattr(X, "iloc") else checked  # members keep the column names
        rng = np.random.default_rng(self.random_state)
        n = len(y)
        self.members_ = []
        for i in range(int(self.n_members)):
            rows = rng.integers(0, n, n)
            member = clone(self.estimator)
            if "random_state" in member.get_params():
                member.set_params(random_state=int(self.random_state) + i)
            part = X.iloc[rows] if hasattr(X, "iloc") else X[rows]
            self.members_.append(member.fit(part, y[rows]))
        return self

    def _members_predict(self, X) -> np.ndarray:
        check_is_fitted(self, "members_")
        validate_data(self, X, reset=False, dtype=np.float64)
        return np.stack([np.asarray(m.predict(X), float) for m in self.members_])

    def predict(self, X) -> np.ndarray:
        return self._members_predict(X).mean(axis=0)

    def predict_interval(self, X, level: float | None = None):
        """Mean prediction [um] and its interval (low, high) from the members' spread."""
        values = self._members_predict(X)
        n = len(values)
        mean, sd = values.mean(axis=0), values.std(axis=0, ddof=1)
        half = stdtrit(n - 1, 0.5 + (level or self.level) / 2) * sd * np.sqrt(1 + 1 / n)
        return mean, mean - half, mean + half

    def save(self, directory) -> Path:
        """Each member by ``save_estimator``, their specs and the parameters in ensemble.json."""
        check_is_fitted(self, "members_")
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        parts = [save_estimator(m, directory, f"member_{i}") for i, m in enumerate(self.members_)]
        params = {k: v for k, v in self.get_params(deep=False).items() if k != "estimator"}
        return write_state(directory / FILE_NAME, self, {"params": params, "members": parts})

    @classmethod
    def load(cls, directory, template: BootstrapEnsemble):
        """Read ``save``'s folder; every member must be of the class of ``template.estimator``."""
        directory = Path(directory)
        path = directory / FILE_NAME
        state = read_state(path, ("params", "members"))
        if not isinstance(state["params"], dict) or not isinstance(state["members"], list) \
                or not state["members"]:
            raise InputError(f"broken {FILE_NAME}: expected parameters and a list of members",
                             file=path)
        for spec in state["members"]:  # members live in this directory, nowhere else
            spec = check_spec(spec, path)
            if Path(spec["path"]).name != spec["path"] or spec["path"] in ("", ".", ".."):
                raise InputError("ensemble member outside the model directory", file=path,
                                 column=str(spec["path"]))
        members = [load_estimator(directory, spec, template.estimator, where=path)
                   for spec in state["members"]]
        unknown = set(state["params"]) - set(cls._parameter_constraints)
        if unknown or "estimator" in state["params"]:
            raise InputError(f"broken {FILE_NAME}: unknown parameter "
                             f"{min(unknown or {'estimator'})!r}", file=path)
        model = checked_params(cls(estimator=clone(members[0]), **state["params"]), path)
        model.members_ = members
        return restore_inputs(model, state)
