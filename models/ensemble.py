"""Bootstrap ensemble: intervals for predictors that have none of their own (networks).

Each member is a clone of ``estimator`` fitted on a bootstrap resample of the training points
(with its own seed); the prediction is the members' mean and its interval
mean +- t(n - 1, 0.975) sd sqrt(1 + 1/n), sd the members' spread: the uncertainty of the fitted
function from the data it saw (Efron and Tibshirani, An Introduction to the Bootstrap, 1993,
ch. 6), which is what a forecast of the true backlash needs; measurement noise is not in it.
Members are saved through ``models.persistence`` side by side with an ``ensemble.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.special import stdtrit  # Student t quantile; scipy.stats costs a second to import
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.utils.validation import check_is_fitted, validate_data

from features.readings.errors import InputError
from models.persistence import load_estimator, save_estimator

FILE_NAME = "ensemble.json"


class BootstrapEnsemble(RegressorMixin, BaseEstimator):
    """Mean of ``n_members`` bootstrap fits of ``estimator``, with ``predict_interval``."""

    def __init__(self, estimator=None, n_members: int = 5, random_state: int = 0,
                 level: float = 0.95):
        self.estimator = estimator
        self.n_members = n_members
        self.random_state = random_state
        self.level = level

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

    def save(self, directory) -> None:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        parts = [save_estimator(m, directory, f"member_{i}") for i, m in enumerate(self.members_)]
        params = {k: v for k, v in self.get_params(deep=False).items() if k != "estimator"}
        (directory / FILE_NAME).write_text(json.dumps({
            "params": params, "members": parts, "n_features_in": int(self.n_features_in_),
            "feature_names_in": [str(c) for c in getattr(self, "feature_names_in_", [])]},
            indent=2))

    @classmethod
    def load(cls, directory, template: BootstrapEnsemble):
        """Read ``save``'s folder; every member must be of the class of ``template.estimator``."""
        directory = Path(directory)
        state = json.loads((directory / FILE_NAME).read_text())
        for spec in state["members"]:  # members live in this directory, nowhere else
            if Path(spec["path"]).name != spec["path"] or spec["path"] in ("", ".", ".."):
                raise InputError("ensemble member outside the model directory",
                                 file=directory / FILE_NAME, column=str(spec["path"]))
        members = [load_estimator(directory, spec, template.estimator, where=directory / FILE_NAME)
                   for spec in state["members"]]
        model = cls(estimator=clone(members[0]), **state["params"])
        model.members_ = members
        model.n_features_in_ = int(state["n_features_in"])
        if state["feature_names_in"]:
            model.feature_names_in_ = np.asarray(state["feature_names_in"], dtype=object)
        return model
