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
- ``EffectModelBaseline``: least squares of the twin's lost-motion effects (``backlash``,
  ``backlash_position``, ``backlash_feed``, ``backlash_temperature``, and wear growing with
  operating hours) on whichever inputs the table supplies.
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

REFERENCE_TEMP_C = 20.0


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


class EffectModelBaseline(RegressorMixin, BaseEstimator):
    """Least squares of the twin's lost-motion effects (``models.physics.effects``):

    b = b0 + A * backlash_position(x; c, w) + k_f * backlash_feed + k_T * backlash_temperature
        + k_h * operating_hours / 1000

    each effect evaluated with unit amplitude, so the fit is linear; the wear location c is
    searched over the training positions (w a quarter of the travel). Terms whose input the
    table lacks, or that do not vary in training, are left out.
    """

    def __init__(self, n_centers: int = 9):
        self.n_centers = n_centers

    def _design(self, X, center_mm: float, width_mm: float) -> tuple[np.ndarray, list[str]]:
        from models.physics import effects

        n = len(X)
        cols, names = [np.ones(n)], ["backlash"]
        conditions = {c: X[c].to_numpy(float) for c in ("feed_mm_min", "machine_temp_c")
                      if c in X}
        if "target" in X:
            cols.append(effects.contribution("backlash_position", X["target"].to_numpy(float), 0,
                                             conditions, amplitude_um=1.0, center_mm=center_mm,
                                             width_mm=width_mm))
            names.append("backlash_position")
        if "feed_mm_min" in X:
            cols.append(effects.contribution("backlash_feed", np.zeros(n), 0, conditions,
                                             k_um_per_m_min=1.0))
            names.append("backlash_feed")
        if "machine_temp_c" in X:
            cols.append(effects.contribution("backlash_temperature", np.zeros(n), 0, conditions,
                                             k_um_per_k=1.0))
            names.append("backlash_temperature")
        if "operating_hours" in X:
            cols.append(X["operating_hours"].to_numpy(float) / 1000.0)
            names.append("wear_um_per_1000h")
        return np.column_stack(cols), names

    def fit(self, X, y):
        y = np.asarray(y, float)
        x = X["target"].to_numpy(float) if "target" in X else np.zeros(len(X))
        width = max(np.ptp(x) / 4, 1e-9)
        best = None
        for center in np.linspace(x.min(), x.max(), self.n_centers):
            design, names = self._design(X, center, width)
            keep = np.r_[True, np.ptp(design[:, 1:], axis=0) > 1e-12]
            coef = np.zeros(design.shape[1])
            coef[keep] = _lstsq(design[:, keep], y)
            sse = float(np.sum((design @ coef - y) ** 2))
            if best is None or sse < best[0]:
                best = (sse, center, coef, names)
        _, self.center_mm_, self.coef_, self.terms_ = best
        self.width_mm_ = width
        self.n_features_in_ = np.shape(X)[1]
        return self

    def predict(self, X):
        check_is_fitted(self, "coef_")
        return self._design(X, self.center_mm_, self.width_mm_)[0] @ self.coef_


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

