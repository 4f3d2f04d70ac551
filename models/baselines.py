"""Physics baselines for per-point backlash, as scikit-learn regressors on the feature table.

Each takes the feature table ``X`` (a DataFrame with the ``features.table`` column names) and
uses only the columns its physics names, so the same ``X`` feeds every model:

- ``ConstantBacklash``: one lost-motion value, the mean of the training targets — what a CNC
  control's scalar backlash compensation assumes (seed 004, section 2.2.2).
- ``LinearInTemperature``: b = b_20 + k (T_machine - 20 degC): preload change with the screw's
  temperature (``backlash_temperature``).
- ``BezierPosition`` (degree 4) and ``BSplinePosition`` (degree 2, uniform clamped knots), five
  control points each, least squares over the position normalised to [0, 1] on the training
  range — the intra-axis error models of seed 000 (eqs. 18 and 20), here for the backlash profile.
- (the effect-model baseline, built from the effect records, is in ``models.effect_model``)
- ``PhysicsHybrid``: a physics baseline plus any regressor fitted on its residual.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.interpolate import BSpline
from scipy.special import comb
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.utils.validation import check_is_fitted

from models.persistence import load_estimator, save_estimator
from models.physics.effects import REFERENCE_TEMP_C


def _column(X, name: str) -> np.ndarray:
    if not isinstance(X, pd.DataFrame) or name not in X:
        raise ValueError(f"this baseline needs the input column {name!r}")
    return X[name].to_numpy(float)


def _lstsq(design: np.ndarray, y) -> np.ndarray:
    return np.linalg.lstsq(design, np.asarray(y, float), rcond=None)[0]


class ConstantBacklash(RegressorMixin, BaseEstimator):
    """Constant lost motion b [um]: the training mean."""

    def fit(self, X, y):
        self.backlash_um_ = float(np.mean(y))
        self.n_features_in_ = np.shape(X)[1]
        return self

    def predict(self, X):
        check_is_fitted(self, "backlash_um_")
        return np.full(len(X), self.backlash_um_)


class LinearInTemperature(RegressorMixin, BaseEstimator):
    """b = b_20 + k_T (T - 20 degC) with b_20 [um], k_T [um/K] by least squares."""

    def __init__(self, temperature: str = "machine_temp_c"):
        self.temperature = temperature

    def _design(self, X):
        return np.column_stack([np.ones(len(X)), _column(X, self.temperature) - REFERENCE_TEMP_C])

    def fit(self, X, y):
        self.backlash_20_um_, self.slope_um_per_k_ = _lstsq(self._design(X), y)
        self.n_features_in_ = np.shape(X)[1]
        return self

    def predict(self, X):
        check_is_fitted(self, "slope_um_per_k_")
        return self._design(X) @ np.array([self.backlash_20_um_, self.slope_um_per_k_])


class _PositionCurve(RegressorMixin, BaseEstimator):
    """A parametric curve over position with control points fitted by least squares."""

    position = "target"

    def _t(self, X) -> np.ndarray:
        x = _column(X, self.position)
        return np.clip((x - self.range_[0]) / (self.range_[1] - self.range_[0]), 0.0, 1.0)

    def fit(self, X, y):
        x = _column(X, self.position)
        span = np.ptp(x)
        self.range_ = (float(x.min()), float(x.min() + (span if span > 0 else 1.0)))
        self.control_points_um_ = _lstsq(self.basis(self._t(X)), y)
        self.n_features_in_ = np.shape(X)[1]
        return self

    def predict(self, X):
        check_is_fitted(self, "control_points_um_")
        return self.basis(self._t(X)) @ self.control_points_um_


class BezierPosition(_PositionCurve):
    """Bezier curve of degree n over position (seed 000, eq. 3): B(t) = sum_i C(n,i) t^i
    (1-t)^(n-i) P_i with n + 1 control points P_i [um]; default degree 4 (five points)."""

    def __init__(self, degree: int = 4):
        self.degree = degree

    def basis(self, t: np.ndarray) -> np.ndarray:
        i = np.arange(self.degree + 1)
        return comb(self.degree, i) * t[:, None] ** i * (1 - t[:, None]) ** (self.degree - i)


class BSplinePosition(_PositionCurve):
    """B-spline of degree k over position (seed 000, eq. 4) on a uniform clamped knot vector
    with ``n_control`` control points [um]; default degree 2, five points."""

    def __init__(self, degree: int = 2, n_control: int = 5):
        self.degree = degree
        self.n_control = n_control

    def basis(self, t: np.ndarray) -> np.ndarray:
        inner = np.linspace(0, 1, self.n_control - self.degree + 1)
        knots = np.r_[[0.0] * self.degree, inner, [1.0] * self.degree]
        return BSpline.design_matrix(t, knots, self.degree).toarray()


class PhysicsHybrid(RegressorMixin, BaseEstimator):
    """``physics`` fitted first, then ``residual`` fitted on what the physics leaves."""

    def __init__(self, physics=None, residual=None):
        self.physics = physics
        self.residual = residual

    def fit(self, X, y):
        y = np.asarray(y, float)
        self.physics_ = clone(self.physics).fit(X, y)
        self.residual_ = clone(self.residual).fit(X, y - self.physics_.predict(X))
        self.n_features_in_ = np.shape(X)[1]
        return self

    def predict(self, X):
        check_is_fitted(self, "residual_")
        return self.physics_.predict(X) + self.residual_.predict(X)

    def save(self, directory) -> None:
        _hybrid_save(self, directory)

    @classmethod
    def load(cls, directory):
        return _hybrid_load(cls, directory)


def _hybrid_save(self, directory) -> None:
    """Physics part (skops) and residual part (its own format) side by side."""
    import json
    from pathlib import Path

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    parts = {"physics": save_estimator(self.physics_, directory, "physics"),
             "residual": save_estimator(self.residual_, directory, "residual")}
    (directory / "hybrid.json").write_text(json.dumps(parts, indent=2))


def _hybrid_load(cls, directory):
    import json
    from pathlib import Path

    directory = Path(directory)
    parts = json.loads((directory / "hybrid.json").read_text())
    physics, residual = (load_estimator(directory, parts[k]) for k in ("physics", "residual"))
    model = cls(physics=clone(physics), residual=clone(residual))
    model.physics_, model.residual_ = physics, residual
    model.n_features_in_ = getattr(physics, "n_features_in_", None)
    return model

