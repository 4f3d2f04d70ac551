"""Physics baselines for per-point backlash, as scikit-learn regressors on the feature table.

Each uses only the inputs its physics names, so the same ``X`` feeds every model. Inputs are
found by name: a DataFrame names its columns (``feature_names_in_``); a numpy array uses the
``features`` constructor parameter when given, else its columns are unnamed and the terms that
need a named input are left out (the model then reduces to its constant part, which is what
scikit-learn's estimator checks on random unnamed arrays see — declared with the
``poor_score`` tag). ``required_inputs()`` lists the named inputs a baseline exists for; the
training step refuses a feature set without them.

- ``ConstantBacklash``: one lost-motion value, the mean of the training targets — what a CNC
  control's scalar backlash compensation assumes ([BacklashNN], section 2.2.2).
- ``LinearInTemperature``: b = b_20 + k (T_machine - 20 degC): preload change with the screw's
  temperature (``backlash_temperature``).
- ``BezierPosition`` (degree 4) and ``BSplinePosition`` (degree 2, uniform clamped knots), five
  control points each, least squares over the position normalised to [0, 1] on the training
  range — the intra-axis error models of [Mechta2022] (eqs. 18 and 20), here for the backlash profile.
- (the effect-model baseline, built from the effect records, is in ``models.estimators.effect_model``)
- ``PhysicsHybrid``: a physics baseline plus any regressor fitted on its residual.
"""

from __future__ import annotations

from numbers import Integral
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
from scipy.special import comb
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context, clone
from sklearn.utils._param_validation import HasMethods, Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from features.readings.errors import InputError
from features.statistics import bspline_basis
from models.physics.effects import REFERENCE_TEMP_C
from models.serving.persistence import (
    load_estimator,
    read_state,
    restore_inputs,
    save_estimator,
    write_state,
)

HYBRID_FILE = "hybrid.json"


def _lstsq(design: np.ndarray, y) -> np.ndarray:
    return np.linalg.lstsq(design, np.asarray(y, float), rcond=None)[0]


def input_names(estimator, n_columns: int) -> list[str | None]:
    """Name of each input column: the fitted DataFrame's, else ``estimator.features``, else
    None (unnamed)."""
    if hasattr(estimator, "feature_names_in_"):
        return [str(c) for c in estimator.feature_names_in_]
    features = getattr(estimator, "features", None)
    if features is None:
        return [None] * n_columns
    if isinstance(features, str) or len(features) != n_columns:
        raise ValueError(f"features must name each of the {n_columns} input columns; "
                         f"got {features!r}")
    return [str(f) for f in features]


def column_of(estimator, name: str, n_columns: int) -> int | None:
    """Index of the input called ``name``, or None when the inputs do not name it."""
    names = input_names(estimator, n_columns)
    return names.index(name) if name in names else None


class _BaselineTags:
    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        # on unnamed inputs (scikit-learn's checks use random unnamed arrays) a baseline is
        # its constant part, so the checks' score threshold does not apply, as for
        # DummyRegressor
        tags.regressor_tags.poor_score = True
        return tags


class ConstantBacklash(_BaselineTags, RegressorMixin, BaseEstimator):
    """Constant lost motion b [um]: the training mean."""

    _parameter_constraints: ClassVar[dict] = {}

    def required_inputs(self) -> tuple[str, ...]:
        return ()

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True)
        self.backlash_um_ = float(np.mean(y))
        return self

    def predict(self, X):
        check_is_fitted(self, "backlash_um_")
        X = validate_data(self, X, reset=False)
        return np.full(X.shape[0], self.backlash_um_)


class LinearInTemperature(_BaselineTags, RegressorMixin, BaseEstimator):
    """b = b_20 + k_T (T - 20 degC) with b_20 [um], k_T [um/K] by least squares.

    Parameters
    ----------
    temperature : str
        Name of the machine temperature input [degC].
    features : tuple of str, optional
        Names of a numpy input's columns.

    Attributes
    ----------
    temperature_column_ : int or None
        Column of the temperature input; None when the inputs do not name it (slope 0).
    """

    _parameter_constraints: ClassVar[dict] = {"temperature": [str], "features": [None, "array-like"]}

    def __init__(self, temperature: str = "machine_temp_c", features=None):
        self.temperature = temperature
        self.features = features

    def required_inputs(self) -> tuple[str, ...]:
        return (self.temperature,)

    def _design(self, X: np.ndarray) -> np.ndarray:
        if self.temperature_column_ is None:
            return np.column_stack([np.ones(len(X)), np.zeros(len(X))])
        return np.column_stack([np.ones(len(X)),
                                X[:, self.temperature_column_] - REFERENCE_TEMP_C])

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        self.temperature_column_ = column_of(self, self.temperature, X.shape[1])
        self.backlash_20_um_, self.slope_um_per_k_ = (float(c) for c in
                                                      _lstsq(self._design(X), y))
        return self

    def predict(self, X):
        check_is_fitted(self, "slope_um_per_k_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self._design(X) @ np.array([self.backlash_20_um_, self.slope_um_per_k_])


class _PositionCurve(_BaselineTags, RegressorMixin, BaseEstimator):
    """A parametric curve over position with control points fitted by least squares.

    Without a named ``target`` input every point sits at t = 0 and the curve is a constant.
    """

    position = "target"

    def required_inputs(self) -> tuple[str, ...]:
        return (self.position,)

    def _x(self, X: np.ndarray) -> np.ndarray:
        if self.position_column_ is None:
            return np.zeros(len(X))
        return X[:, self.position_column_]

    def _t(self, X) -> np.ndarray:
        x = self._x(X)
        return np.clip((x - self.range_[0]) / (self.range_[1] - self.range_[0]), 0.0, 1.0)

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        self.position_column_ = column_of(self, self.position, X.shape[1])
        x = self._x(X)
        span = np.ptp(x)
        self.range_ = (float(x.min()), float(x.min() + (span if span > 0 else 1.0)))
        self.control_points_um_ = _lstsq(self.basis(self._t(X)), y)
        return self

    def predict(self, X):
        check_is_fitted(self, "control_points_um_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.basis(self._t(X)) @ self.control_points_um_


class BezierPosition(_PositionCurve):
    """Bezier curve of degree n over position ([Mechta2022], eq. 3): B(t) = sum_i C(n,i) t^i
    (1-t)^(n-i) P_i with n + 1 control points P_i [um]; default degree 4 (five points).
    ``features`` names a numpy input's columns."""

    _parameter_constraints: ClassVar[dict] = {"degree": [Interval(Integral, 1, None, closed="left")],
                                    "features": [None, "array-like"]}

    def __init__(self, degree: int = 4, features=None):
        self.degree = degree
        self.features = features

    def basis(self, t: np.ndarray) -> np.ndarray:
        i = np.arange(self.degree + 1)
        return comb(self.degree, i) * t[:, None] ** i * (1 - t[:, None]) ** (self.degree - i)


class BSplinePosition(_PositionCurve):
    """B-spline of degree k over position ([Mechta2022], eq. 4) on a uniform clamped knot vector
    with ``n_control`` control points [um]; default degree 2, five points (the degree is at
    most ``n_control - 1``). ``features`` names
    a numpy input's columns."""

    _parameter_constraints: ClassVar[dict] = {"degree": [Interval(Integral, 0, None, closed="left")],
                                    "n_control": [Interval(Integral, 1, None, closed="left")],
                                    "features": [None, "array-like"]}

    def __init__(self, degree: int = 2, n_control: int = 5, features=None):
        self.degree = degree
        self.n_control = n_control
        self.features = features

    def basis(self, t: np.ndarray) -> np.ndarray:
        return bspline_basis(t, self.n_control, self.degree)


class PhysicsHybrid(RegressorMixin, BaseEstimator):
    """``physics`` fitted first, then ``residual`` fitted on what the physics leaves.

    Both parts see the inputs with their names (a DataFrame's columns, or ``features`` for a
    numpy input), so a physics part finds its named inputs either way. Saved as
    ``hybrid.json`` plus one file or folder per part (``models.serving.persistence``).
    """

    _parameter_constraints: ClassVar[dict] = {"physics": [HasMethods(["fit", "predict"])],
                                    "residual": [HasMethods(["fit", "predict"])],
                                    "features": [None, "array-like"]}

    def __init__(self, physics=None, residual=None, features=None):
        self.physics = physics
        self.residual = residual
        self.features = features

    def required_inputs(self) -> tuple[str, ...]:
        needed = []
        for part in (self.physics, self.residual):
            needed += [n for n in getattr(part, "required_inputs", tuple)() if n not in needed]
        return tuple(needed)

    def _named(self, X: np.ndarray):
        names = input_names(self, X.shape[1])
        return X if None in names else pd.DataFrame(X, columns=names)

    @_fit_context(prefer_skip_nested_validation=False)
    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        X = self._named(X)
        self.physics_ = clone(self.physics).fit(X, y)
        self.residual_ = clone(self.residual).fit(X, y - self.physics_.predict(X))
        return self

    def predict(self, X):
        check_is_fitted(self, "residual_")
        X = self._named(validate_data(self, X, reset=False, dtype=np.float64))
        return self.physics_.predict(X) + self.residual_.predict(X)

    def save(self, directory) -> Path:
        """Each part by ``save_estimator``, their specs and the input names in hybrid.json."""
        check_is_fitted(self, "residual_")
        directory = Path(directory)
        parts = {"physics": save_estimator(self.physics_, directory, "physics"),
                 "residual": save_estimator(self.residual_, directory, "residual")}
        return write_state(directory / HYBRID_FILE, self, {
            **parts, "features": None if self.features is None else list(self.features)})

    @classmethod
    def load(cls, directory, template: PhysicsHybrid) -> PhysicsHybrid:
        """Read ``save``'s folder; each part must be of the class ``template`` has there."""
        path = Path(directory) / HYBRID_FILE
        saved = read_state(path, ("physics", "residual", "features"))
        features = saved["features"]
        if features is not None and (not isinstance(features, list)
                                     or not all(isinstance(f, str) for f in features)):
            raise InputError(f"broken {HYBRID_FILE}: features must list the input names",
                             file=path)
        fitted = {k: load_estimator(directory, saved[k], getattr(template, k), where=path)
                  for k in ("physics", "residual")}
        model = cls(physics=clone(fitted["physics"]), residual=clone(fitted["residual"]),
                    features=None if features is None else tuple(features))
        model.physics_, model.residual_ = fitted["physics"], fitted["residual"]
        return restore_inputs(model, saved)
