"""The effect-model baseline: least squares of the twin's lost-motion effects, built from the
effect records (``models.physics.effects.EFFECTS``).

Its terms are the lost-motion records whose ``inputs`` the feature table supplies, each
evaluated with unit amplitude so the fit is linear, plus wear growing with operating hours:

    b = b0 + A * backlash_position(x; c, w) + k_f * backlash_feed(f) + k_T * backlash_temperature(T)
        + k_h * operating_hours / 1000

The wear location c is searched over the training positions (w a quarter of the travel).
Terms whose input the table lacks, or that do not vary in training, are left out. Inputs follow
the estimator convention of the package: a DataFrame names its columns; a numpy array uses the
``features`` constructor parameter when given, else its columns are unnamed and only the
constant term is fitted.
"""

from __future__ import annotations

from numbers import Integral
from typing import ClassVar

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context
from sklearn.utils._param_validation import Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from models.physics import effects

WEAR_INPUT = "operating_hours"


class EffectModelBaseline(RegressorMixin, BaseEstimator):
    """Least squares of the lost-motion effect records (see the module docstring).

    Parameters
    ----------
    n_centers : int
        Candidate wear locations tried between the smallest and largest training position.
    features : tuple of str or None
        Names of the columns of a numpy input (ignored for a DataFrame, which names its own).
    """

    _parameter_constraints: ClassVar[dict] = {"n_centers": [Interval(Integral, 1, None, closed="left")],
                                    "features": [None, "array-like"]}

    def __init__(self, n_centers: int = 9, features: tuple[str, ...] | None = None):
        self.n_centers = n_centers
        self.features = features

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        # unnamed inputs leave only the constant clearance: a mean, like DummyRegressor
        tags.regressor_tags.poor_score = True
        return tags

    # -------------------------------------------------------------- columns and terms
    def _names(self, n_columns: int) -> list[str | None]:
        names = getattr(self, "feature_names_in_", None)
        if names is not None:
            return list(names)
        if self.features is not None:
            if len(self.features) != n_columns:
                raise ValueError(f"features names {len(self.features)} columns, X has "
                                 f"{n_columns}")
            return list(self.features)
        return [None] * n_columns

    def _terms(self, available: set) -> list[str]:
        terms = [name for name, record in effects.EFFECTS.items()
                 if record.kind == "lost_motion" and set(record.inputs) <= available]
        return terms + ([WEAR_INPUT] if WEAR_INPUT in available else [])

    def _design(self, columns: dict, n: int, terms: list[str], center_mm: float,
                width_mm: float) -> np.ndarray:
        x = columns.get("target", np.zeros(n))
        cols = []
        for term in terms:
            if term == WEAR_INPUT:
                cols.append(columns[WEAR_INPUT] / 1000.0)
                continue
            record = effects.EFFECTS[term]
            params = {record.amplitude: 1.0}
            if term == "backlash_position":
                params.update(center_mm=center_mm, width_mm=width_mm)
            cols.append(np.broadcast_to(
                effects.contribution(term, x, 0, columns, **params), (n,)))
        return np.column_stack(cols)

    def _columns(self, X: np.ndarray) -> dict:
        return {name: X[:, i] for i, name in enumerate(self._names(X.shape[1])) if name}

    # -------------------------------------------------------------- estimator API
    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True)
        columns = self._columns(X)
        self.terms_ = self._terms(set(columns))
        x = columns.get("target", np.zeros(len(X)))
        width = max(float(np.ptp(x)) / 4, 1e-9)
        best = None
        for center in np.linspace(x.min(), x.max(), self.n_centers):
            design = self._design(columns, len(X), self.terms_, float(center), width)
            keep = np.r_[True, np.ptp(design[:, 1:], axis=0) > 1e-12]
            coef = np.zeros(design.shape[1])
            coef[keep] = np.linalg.lstsq(design[:, keep], y, rcond=None)[0]
            sse = float(np.sum((design @ coef - y) ** 2))
            if best is None or sse < best[0]:
                best = (sse, float(center), coef)
        _, self.center_mm_, self.coef_ = best
        self.width_mm_ = width
        return self

    def predict(self, X):
        check_is_fitted(self, "coef_")
        X = validate_data(self, X, reset=False)
        design = self._design(self._columns(X), len(X), self.terms_, self.center_mm_,
                              self.width_mm_)
        return design @ self.coef_
