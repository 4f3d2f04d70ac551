"""Wear map: backlash as a level plus a wear rate that vary along the screw.

A ball screw wears where the axis works most, so backlash grows with operating hours at a rate
that varies along the axis (DESIGN.md, wear). The model, linear in its coefficients:

    b(x, h, c) = b0(x) + w(x) h / 1000 + k_f f / 1000 + k_T (T - 20 degC)

- x [mm] the target, h [h] the operating hours since the last mechanical adjustment
  (docs/data-contract.md, section 1), f [mm/min] the feed and T [degC] the machine temperature: the condition
  terms of the ``backlash_feed`` and ``backlash_temperature`` effects, each evaluated with unit
  amplitude (``models.physics.effects``);
- b0(x) [um] and the wear-rate map w(x) [um per 1000 h] are B-splines over the position with
  the same basis ([Mechta2022], eq. 4: uniform clamped knots, cubic), or one value per target
  (piecewise linear between the targets) when the targets repeat across visits. The number of
  control points is chosen by leave-one-visit-out cross-validation (visits told apart by their
  hours), so the data choose how much shape the screw shows;
- fitted by least squares with a small ridge penalty for conditioning; the parameter covariance
  s^2 (A'A + P)^-1, plus the part of a common offset per visit (tau, from the spread of the
  visits' mean residuals beyond the point noise), gives the 95 % interval of the predicted
  backlash (which also carries the forecast visit's own offset) and of w(x).

On a fleet (inputs with ``machine_id`` and ``axis`` columns naming more than one machine axis)
every machine axis gets its own maps and condition terms, over its own travel (the position
mapped to 0..1 between its end targets) and its own wear clock, and the axes share strength by
partial pooling (``models.wear.pooling``): an axis with few visits borrows from the fleet's
distribution of maps, an axis with many visits follows its own data. A plan for an axis the model
does not know is forecast from that fleet distribution, with its wider interval. Every axis keeps
its units (``features.readings.schema.deviation_unit``: backlash in arcsec and positions in deg
for a rotary axis, um and mm for a linear one; the names say um and mm): a fleet with both is
pooled unit by unit (``models.wear.wear_fleet.UnitGroups``), one model per unit inside the one
estimator, and ``axis_units_`` says each axis's unit.

A condition the caller cannot give (a plan without machine temperature) may be NaN: the term
then takes its training mean and the interval widens by the term's training spread. Terms whose
input is absent or constant in training are left out; without operating hours (or with one
value of them) there is no wear term and the model cannot forecast (``can_forecast_``).

Follows the estimator convention of the project: a DataFrame names its columns, a numpy input
uses ``features`` when given; unnamed inputs give a constant model.
"""

from __future__ import annotations

from numbers import Integral, Real
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
from scipy.special import stdtrit  # Student t quantile; scipy.stats costs a second to import
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context, clone
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted, validate_data

from features.readings.schema import deviation_unit
from features.statistics import grouped_cv_sse, varies_only_between
from models.wear.wear_basis import (
    CONDITIONS,
    GROUPS,
    HOURS,
    POSITION,
    spline_basis,
    split_groups,
    target_basis,
)
from models.wear.wear_clock import epoch_lines, found_adjustments, latest_epoch, wear_epochs
from models.wear.wear_fleet import FLEET_ARRAYS, FLEET_STATE, UNIT_STATE, FleetWearMap, UnitGroups

# the wear clock (``models.wear.wear_clock``) is importable from here too
__all__ = ["CONDITIONS", "FILE_NAME", "HOURS", "POSITION", "WearMap", "epoch_lines",
           "found_adjustments", "latest_epoch", "spline_basis", "target_basis", "wear_epochs"]

FILE_NAME = "wear_map.json"


class WearMap(UnitGroups, FleetWearMap, RegressorMixin, BaseEstimator):
    """Backlash b0(x) + w(x) h + condition terms, smooth along the axis (module docstring).

    Parameters
    ----------
    features : tuple of str, optional
        Column names of a numpy input (a DataFrame names its own).
    n_control : int or 'targets', optional
        Control points of b0 and w; default chosen by leave-one-visit-out cross-validation
        among 1 .. ``max_control`` cubic B-splines and one value per target.
    max_control : int
        Largest number of B-spline control points tried.
    alpha : float
        Ridge penalty relative to the mean diagonal of A'A (conditioning only).
    level : float
        Coverage of the intervals (default 0.95).
    """

    _parameter_constraints: ClassVar[dict] = {
        "features": [None, "array-like"],
        "n_control": [None, Interval(Integral, 1, None, closed="left"), StrOptions({"targets"})],
        "max_control": [Interval(Integral, 1, None, closed="left")],
        "alpha": [Interval(Real, 0, None, closed="left")],
        "level": [Interval(Real, 0, 1, closed="neither")],
    }

    def __init__(self, features=None, n_control=None, max_control: int = 8,
                 alpha: float = 1e-8, level: float = 0.95):
        self.features = features
        self.n_control = n_control
        self.max_control = max_control
        self.alpha = alpha
        self.level = level

    # ---- inputs -------------------------------------------------------------------------
    def _names(self, X, n_columns: int) -> list[str]:
        if isinstance(X, pd.DataFrame):
            return [str(c) for c in X.columns]
        if self.features is not None and len(self.features) == n_columns:
            return list(self.features)
        return [f"x{i}" for i in range(n_columns)]

    # ---- design -------------------------------------------------------------------------
    def _basis(self, x: np.ndarray, choice) -> np.ndarray:
        if choice == "targets":
            return target_basis(x, self.knots_mm_)
        lo, hi = (0.0, 1.0) if getattr(self, "pooled_", False) else self.range_mm_
        return spline_basis(x, lo, hi, int(choice))

    def _design(self, frame: pd.DataFrame, choice) -> np.ndarray:
        from models.physics import effects

        n = len(frame)
        x = frame[POSITION].to_numpy(float) if self.use_position_ else np.zeros(n)
        basis = self._basis(x, choice) if self.use_position_ else np.ones((n, 1))
        cols = [basis]
        if self.use_hours_:
            cols.append(basis * frame[HOURS].to_numpy(float)[:, None] / 1000.0)
        for name in self.conditions_:
            effect, amplitude = CONDITIONS[name]
            values = frame[name].to_numpy(float)
            values = np.where(np.isnan(values), self.condition_means_[name], values)
            cols.append(effects.contribution(effect, np.zeros(n), 0, {name: values},
                                             **{amplitude: 1.0})[:, None])
        return np.hstack(cols)

    def _solve(self, A: np.ndarray, y: np.ndarray):
        gram = A.T @ A
        penalty = self.alpha * max(np.trace(gram) / len(gram), 1e-12) * np.eye(len(gram))
        inverse = np.linalg.pinv(gram + penalty)
        return inverse @ (A.T @ y), inverse

    # ---- fit ----------------------------------------------------------------------------
    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y, hours_origin: dict | None = None):
        """Fit on the inputs ``X`` and backlash ``y`` [um; arcsec for a rotary axis].

        ``hours_origin`` maps (machine_id, axis) to the operating hours [h] at which that
        axis's wear clock restarts (an adjustment that left the hour counter running on);
        the axis's hours count from there. Its rows before that origin are its earlier wear
        epoch: a fleet keeps them for the wear rate, with a level of their own, when
        cross-validation prefers it (one axis alone leaves them out). ``y`` is in each axis's
        unit (arcsec for a rotary axis); rotary and linear axes are pooled apart
        (``models.wear.wear_fleet.UnitGroups``).
        """
        labels, X = split_groups(X)
        names = (self._names(X, X.shape[1])
                 if hasattr(X, "shape") and len(X.shape) == 2 else None)
        values, y = validate_data(self, X, y, reset=True, y_numeric=True)
        frame = pd.DataFrame(values, columns=names or self._names(values, values.shape[1]))
        y = np.asarray(y, float)
        earlier = None
        old = _before_origin(frame, labels, hours_origin or {})
        if old.any():
            earlier = (frame[old].reset_index(drop=True), y[old], labels[old])
            frame, y, labels = frame[~old].reset_index(drop=True), y[~old], labels[~old]
        # the machine axis of each row is its identity, not an input: feature_names_in_ keeps
        # the numeric inputs only
        self.axes_ = sorted({tuple(k) for k in labels}) if labels is not None else []
        self.pooled_ = len(self.axes_) > 1
        self.visit_hours_ = _visit_hours(frame, labels, self.axes_)
        self.axis_units_ = [deviation_unit(a) for _, a in self.axes_]
        vars(self).pop("unit_maps_", None)  # a refit of one unit
        if len(set(self.axis_units_)) > 1:
            return self._fit_units(frame, y, labels, hours_origin or {}, earlier)
        if self.pooled_:
            return self._fit_fleet(frame, y, labels, hours_origin or {}, earlier)
        return self._fit_axis(frame, y)

    def _fit_axis(self, frame: pd.DataFrame, y: np.ndarray):
        """One machine axis (or data that name none): the single-axis model."""
        self._learn_inputs(frame)
        self.cv_scores_ = {}
        self.n_control_ = self._choose(frame, y) if self.use_position_ else 1
        A = self._design(frame, self.n_control_)
        self.coef_, inverse = self._solve(A, y)
        dof = max(len(y) - A.shape[1], 1)
        residual = y - A @ self.coef_
        self.sigma_um_ = float(np.sqrt(np.sum(residual ** 2) / dof))
        self.dof_ = dof
        self.visit_sd_um_, visit_sums = self._visit_effect(frame, A, residual)
        # errors shared by the points of one visit (its conditions on the day) correlate the
        # residuals: cov = s^2 (A'A)^-1 + tau^2 (A'A)^-1 (sum_g A_g'1 1'A_g) (A'A)^-1
        self.covariance_ = (self.sigma_um_ ** 2 * inverse
                            + self.visit_sd_um_ ** 2 * inverse @ visit_sums @ inverse)
        self.can_forecast_ = bool(self.use_hours_)
        return self

    def _learn_inputs(self, frame: pd.DataFrame, axis: np.ndarray | None = None) -> None:
        """Which inputs the model uses, their ranges, means and spreads. On a fleet (``axis``:
        each row's machine axis) a condition must vary within some axis: one that is constant
        on every axis (a machine's usual feed) cannot be told from the axes' own levels."""
        names = list(frame.columns)
        self.use_position_ = POSITION in names and np.ptp(frame[POSITION]) > 0
        self.use_hours_ = HOURS in names and np.ptp(frame[HOURS]) > 0
        self.conditions_ = [c for c in CONDITIONS if c in names and np.ptp(frame[c]) > 0
                            and not self._confounded_with_wear(frame, c)
                            and (axis is None or _varies_within(frame[c], axis))]
        self.condition_means_ = {c: float(frame[c].mean()) for c in self.conditions_}
        self.condition_sd_ = {c: float(frame[c].std(ddof=1)) for c in self.conditions_}
        self.used_features_ = [c for c in (POSITION, HOURS, *self.conditions_)
                               if c in names and (c != POSITION or self.use_position_)
                               and (c != HOURS or self.use_hours_)]
        x = frame[POSITION].to_numpy(float) if self.use_position_ else np.zeros(len(frame))
        self.range_mm_ = (float(x.min()), float(x.max()))
        self.knots_mm_ = np.unique(x)
        self.hours_range_ = ((float(frame[HOURS].min()), float(frame[HOURS].max()))
                             if HOURS in names else (0.0, 0.0))

    def _confounded_with_wear(self, frame: pd.DataFrame, name: str) -> bool:
        """With fewer than four visits (told apart by their hours), a condition that varies
        only between visits (``features.statistics.varies_only_between``) cannot be told from
        the wear term and the visit's own offset: a level, a wear rate and a condition slope
        fitted to three visit levels leave nothing to tell a condition effect from the
        day-to-day offset of a visit."""
        if not self.use_hours_:
            return False
        hours = frame[HOURS].to_numpy(float)
        if len(np.unique(hours)) >= 4:
            return False
        return varies_only_between(frame[name].to_numpy(float), hours)

    def _visit_effect(self, frame: pd.DataFrame, A: np.ndarray, residual: np.ndarray):
        """Standard deviation tau [um] of a common offset per visit (visits told apart by their
        hours), from the spread of the visits' mean residuals beyond what the point noise
        explains, and sum_g (A_g'1)(A_g'1)'."""
        p = A.shape[1]
        if not self.use_hours_:
            return 0.0, np.zeros((p, p))
        hours = frame[HOURS].to_numpy(float)
        labels, codes = np.unique(hours, return_inverse=True)
        if len(labels) < 3:
            return 0.0, np.zeros((p, p))
        counts = np.bincount(codes)
        means = np.bincount(codes, residual) / counts
        tau2 = max(0.0, float(np.var(means, ddof=1)) - self.sigma_um_ ** 2 * float(np.mean(
            1.0 / counts)))
        sums = np.stack([A[codes == g].sum(axis=0) for g in range(len(labels))])
        return float(np.sqrt(tau2)), sums.T @ sums

    def _candidates(self) -> list:
        n_unique = len(self.knots_mm_)
        splines = list(range(1, min(self.max_control, n_unique) + 1))
        if self.n_control is not None:
            return [self.n_control]
        return splines + (["targets"] if 2 < n_unique <= 40 else [])

    def _choose(self, frame: pd.DataFrame, y: np.ndarray):
        """Control points by leave-one-visit-out CV (visits told apart by their hours; 5 folds
        when there is one visit)."""
        candidates = self._candidates()
        if len(candidates) == 1:
            return candidates[0]
        groups = (frame[HOURS].to_numpy(float) if self.use_hours_
                  else np.arange(len(frame)) % 5)
        if len(np.unique(groups)) < 3:
            groups = np.arange(len(frame)) % 5
        for choice in candidates:
            sse = grouped_cv_sse(self._design(frame, choice), y, groups,
                                 solve=lambda A, b: self._solve(A, b)[0])
            self.cv_scores_[str(choice)] = float(np.sqrt(sse / len(y)))
        best = min(self.cv_scores_, key=self.cv_scores_.get)
        return best if best == "targets" else int(best)

    # ---- predict ------------------------------------------------------------------------
    def _predict_frame(self, X) -> pd.DataFrame:
        _check_fitted(self)
        if isinstance(X, pd.DataFrame) and set(GROUPS) <= set(map(str, X.columns)):
            X = X.drop(columns=list(GROUPS))
        if isinstance(X, pd.DataFrame) and not hasattr(self, "feature_names_in_"):
            X = X.to_numpy(float)  # fitted on unnamed columns: take them by position
        if isinstance(X, pd.DataFrame):
            frame = X.copy()
            frame.columns = [str(c) for c in frame.columns]
        else:
            values = validate_data(self, X, reset=False, ensure_all_finite=False)
            frame = pd.DataFrame(values, columns=self._names(values, values.shape[1]))
        values = frame.to_numpy(float)
        if np.isinf(values).any():
            raise ValueError("Input X contains infinity")
        nan = [c for c in frame.columns[np.isnan(values).any(axis=0)] if c not in self.conditions_]
        if nan:
            raise ValueError(f"Input X contains NaN in {nan[0]!r}; only a condition the model "
                             f"uses ({', '.join(self.conditions_) or 'none'}) may be missing")
        for name in (POSITION, HOURS):
            if name in self.used_features_ and name not in frame:
                raise ValueError(f"the wear map needs the input column {name!r}")
        for name in self.conditions_:
            if name not in frame:
                frame[name] = np.nan
        return frame

    def visit_hours(self, key: tuple[str, str] | None = None) -> np.ndarray:
        """Operating hours [h] of the visits the model was fitted on (since each axis's wear
        clock restarted; visits told apart by their hours), ascending: of machine axis ``key``
        = (machine_id, axis) when the model knows its axes, else of its one axis. Empty for
        an axis it does not know, or a model saved without them."""
        _check_fitted(self)
        known = getattr(self, "visit_hours_", None) or []
        if key is not None and self.axes_:
            index = {tuple(k): i for i, k in enumerate(self.axes_)}.get(tuple(map(str, key)))
            known = [known[index]] if index is not None and index < len(known) else []
        return np.asarray(known[0] if known else [], float)

    def chosen_params(self) -> dict:
        """The parameters cross-validation chose (the control points), to refit the same model
        on other rows (a backtest) without choosing again; a model of rotary and linear axes
        gives one only when both units chose the same (else each chooses again)."""
        _check_fitted(self)
        if hasattr(self, "unit_maps_"):
            chosen = {m.n_control_ for m in self.unit_maps_.values()}
            return {"n_control": chosen.pop()} if len(chosen) == 1 else {}
        return {"n_control": self.n_control_}

    def predict(self, X) -> np.ndarray:
        return self.predict_interval(X)[0]

    def predict_interval(self, X, level: float | None = None):
        """Predicted backlash [um] and its interval (low, high) at ``level`` (default the
        estimator's): parameter covariance (on a fleet, the axis's posterior; the fleet's
        distribution for an axis the model does not know), plus the training spread of every
        condition term whose input is missing (NaN). In each axis's unit (arcsec for a rotary
        axis); an axis of a unit the model has no axis of is an ``InputError``."""
        _check_fitted(self)
        labels, rest = split_groups(X)
        if getattr(self, "pooled_", False) and labels is None:
            raise ValueError(f"the model knows {len(self.axes_)} machine axes: the inputs need "
                             f"the columns {', '.join(GROUPS)}")
        self._check_units(labels)
        if hasattr(self, "unit_maps_"):
            return self._predict_units(X, labels, level)
        frame = self._predict_frame(rest)
        z = stdtrit(self.dof_, 0.5 + (level or self.level) / 2)
        if not getattr(self, "pooled_", False):
            mean, var = self._moments(frame, self.coef_, self.covariance_)
            return mean, mean - z * np.sqrt(var), mean + z * np.sqrt(var)
        axis = self._axis_index(labels)
        local = self._earlier_epoch(self._local(frame, axis, labels), frame)
        mean, var = np.zeros(len(frame)), np.zeros(len(frame))
        for a in np.unique(axis):
            rows = axis == a
            coef, cov = ((self.axis_coef_[a], self.axis_covariance_[a]) if a >= 0 else
                         (self.coef_, self.prior_covariance_ + self.covariance_))
            mean[rows], var[rows] = self._moments(local[rows], coef, cov)
            if a < 0:  # its own shape: the fleet's spread of per-target deviations
                var[rows] += self._unknown_shape_var(local[rows])
        var += getattr(self, "misfit_um_", 0.0) ** 2
        half = z * np.sqrt(var)
        return mean, mean - half, mean + half

    def _moments(self, frame: pd.DataFrame, coef: np.ndarray, cov: np.ndarray):
        """Mean and variance of the backlash at the rows of ``frame`` for coefficients
        ``coef`` with covariance ``cov``."""
        A = self._design(frame, self.n_control_)
        offset = A.shape[1] - len(self.conditions_)
        if getattr(self, "pooled_", False):  # each axis's own columns follow the shared ones
            A = self._fleet_design(frame, self.n_control_)
        mean = A @ coef
        # the forecast visit carries its own common offset too
        var = np.einsum("ij,jk,ik->i", A, cov, A) + self.visit_sd_um_ ** 2
        for j, name in enumerate(self.conditions_):
            missing = frame[name].isna().to_numpy()
            effect, amplitude = CONDITIONS[name]
            scale = float(np.ptp(_unit_term(effect, amplitude, name, [0.0, 1.0])))
            var = var + missing * (coef[offset + j] * scale * self.condition_sd_[name]) ** 2
        return mean, var

    def wear_rate_map(self, positions_mm=None, level: float | None = None) -> pd.DataFrame:
        """The wear-rate map w(x) [um per 1000 h] with its interval, and b0(x) [um], at
        ``positions_mm`` (default 50 points over the training range); on a fleet one map per
        machine axis over its own travel (``positions_mm`` then in each axis's travel), with
        ``machine_id`` and ``axis`` columns. A model that knows a rotary axis adds a ``unit``
        column: its map is in arcsec per 1000 h along deg (the names say um and mm)."""
        _check_fitted(self)
        if hasattr(self, "unit_maps_"):
            return self._units_rate_map(positions_mm, level)
        if not getattr(self, "pooled_", False):
            x = (np.linspace(*self.range_mm_, 50) if positions_mm is None
                 else np.asarray(positions_mm, float))
            rate = self._rate_map(x, x, self.coef_, self.covariance_, level)
        else:
            rate = self._fleet_rate_map(positions_mm, level)
        rotary = set(getattr(self, "axis_units_", None) or []) == {"arcsec"}
        return rate.assign(unit="arcsec") if rotary else rate

    def _rate_map(self, x, positions_mm, coef, cov, level) -> pd.DataFrame:
        basis = (self._basis(x, self.n_control_) if self.use_position_
                 else np.ones((len(x), 1)))
        k = basis.shape[1]
        b0 = basis @ coef[:k]
        if self.use_hours_:
            rate = basis @ coef[k:2 * k]
            var = np.einsum("ij,jk,ik->i", basis, cov[k:2 * k, k:2 * k], basis)
        else:
            rate, var = np.zeros(len(x)), np.full(len(x), np.nan)
        half = stdtrit(self.dof_, 0.5 + (level or self.level) / 2) * np.sqrt(var)
        return pd.DataFrame({"position_mm": positions_mm, "wear_rate_um_per_1000h": rate,
                             "wear_rate_low": rate - half, "wear_rate_high": rate + half,
                             "b0_um": b0})

    # ---- persistence (JSON, no pickle) ----------------------------------------------------
    def save(self, directory) -> Path:
        """Write ``wear_map.json`` (parameters and fitted state) into ``directory``."""
        from models.serving.persistence import write_state

        _check_fitted(self)
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        params = self.get_params()
        params["features"] = list(params["features"]) if params["features"] else None
        return write_state(directory / FILE_NAME, self, {"params": params, **self._state()})

    def _state(self) -> dict:
        """The fitted state as JSON values; a model of rotary and linear axes nests each
        unit's model's under ``unit_maps_``."""
        if hasattr(self, "unit_maps_"):
            return {**{name: _jsonable(getattr(self, name)) for name in UNIT_STATE},
                    "unit_maps_": {u: m._state() for u, m in self.unit_maps_.items()}}
        return {**{name: _jsonable(getattr(self, name)) for name in _STATE},
                **{name: _jsonable(getattr(self, name)) for name in (*FLEET_STATE, *_OPTIONAL)
                   if hasattr(self, name)}}

    @classmethod
    def load(cls, directory) -> WearMap:
        """Read ``save``'s file; every problem is an ``InputError`` naming it."""
        from features.readings.errors import InputError
        from models.serving.persistence import checked_params, read_state

        path = Path(directory) / FILE_NAME
        state = read_state(path, ("params",))
        try:
            params = dict(state["params"])
            if params.get("features") is not None:
                params["features"] = tuple(params["features"])
            model = checked_params(cls(**params), path)
            model._restore_state(state, path)
        except (TypeError, ValueError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError(f"broken {FILE_NAME}: {err}", file=path) from None
        return model

    def _restore_state(self, state: dict, path) -> WearMap:
        """Set ``_state``'s attributes (and the inputs ``state`` names) on this model."""
        from features.readings.errors import InputError
        from models.serving.persistence import restore_inputs

        units = state.get("unit_maps_")
        needed = (*UNIT_STATE, "unit_maps_") if units is not None else _STATE
        missing = [name for name in needed if name not in state]
        if missing:
            raise InputError(f"broken {FILE_NAME}: lacks the key {missing[0]!r}", file=path)
        for name in (*needed, *FLEET_STATE, *_OPTIONAL):
            if name in state and name != "unit_maps_":
                setattr(self, name, _restore(name, state[name]))
        if units is not None:
            if (not isinstance(units, dict) or not set(units) <= {"um", "arcsec"}
                    or not all(isinstance(s, dict) and "unit_maps_" not in s
                               for s in units.values())):
                raise ValueError("unit_maps_ must map 'um' and 'arcsec' to one unit's model")
            self.unit_maps_ = {u: clone(self)._restore_state({**s, **_inputs(state)}, path)
                               for u, s in units.items()}
        return restore_inputs(self, state)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        # unnamed numpy inputs carry no position or hours: the model is then a constant
        tags.regressor_tags.poor_score = True
        tags.input_tags.allow_nan = False
        return tags


def _varies_within(values: pd.Series, axis: np.ndarray) -> bool:
    """Whether ``values`` change within at least one group of ``axis``."""
    groups = values.groupby(axis)
    return bool(((groups.max() - groups.min()) > 0).any())


def _before_origin(frame: pd.DataFrame, labels, hours_origin: dict) -> np.ndarray:
    """Rows of an axis whose wear clock restarted with the hour counter running on
    (``hours_origin``) that precede the restart: its earlier wear epoch."""
    if labels is None or not hours_origin or HOURS not in frame:
        return np.zeros(len(frame), bool)
    origin = np.array([float(hours_origin.get(tuple(k), 0.0)) for k in labels])
    return (origin > 0) & (frame[HOURS].to_numpy(float) < origin)


def _check_fitted(model) -> None:
    check_is_fitted(model, ("coef_", "unit_maps_"), all_or_any=any)


def _inputs(state: dict) -> dict:
    """The fitted inputs ``write_state`` put beside the state (a unit model shares them)."""
    from models.serving.persistence import INPUT_KEYS

    return {key: state[key] for key in INPUT_KEYS}


_STATE = ("use_position_", "use_hours_", "conditions_", "condition_means_", "condition_sd_",
          "used_features_", "range_mm_", "knots_mm_", "hours_range_", "cv_scores_",
          "n_control_", "coef_", "sigma_um_", "dof_", "covariance_", "can_forecast_",
          "visit_sd_um_")
# state a model saved by an earlier version may lack (loaded when present)
_OPTIONAL = ("visit_hours_",)
_ARRAYS = ("knots_mm_", "coef_", "covariance_", *FLEET_ARRAYS)


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def _restore(name: str, value):
    if name in _ARRAYS:
        return np.asarray(value, float)
    if name in ("range_mm_", "hours_range_"):
        return tuple(float(v) for v in value)
    if name == "axes_":
        return [tuple(str(v) for v in pair) for pair in value]
    return value


def _unit_term(effect: str, amplitude: str, name: str, values) -> np.ndarray:
    from models.physics import effects

    values = np.asarray(values, float)
    return effects.contribution(effect, np.zeros(len(values)), 0, {name: values},
                                **{amplitude: 1.0})


def _visit_hours(frame: pd.DataFrame, labels, axes: list) -> list[list[float]]:
    """The distinct operating hours [h] (the visits) of every machine axis in ``axes``, or of
    the one axis when the inputs name none: what a forecast's default point is made from."""
    hours = frame[HOURS].to_numpy(float) if HOURS in frame else np.zeros(0)
    if not axes:
        return [np.unique(hours).tolist()]
    if not len(hours):
        return [[] for _ in axes]
    keys = np.array([f"{m}\x00{a}" for m, a in labels])
    return [np.unique(hours[keys == f"{m}\x00{a}"]).tolist() for m, a in axes]
