"""The wear map on a fleet: one level and wear-rate map per machine axis, pooled.

Trained on inputs whose ``machine_id`` and ``axis`` columns name more than one machine axis,
the wear map (``models.wear.wear_map``) fits every axis its own maps and condition terms:

- over its own travel: the position mapped to 0..1 between the axis's end targets, so axes of
  different lengths share one B-spline basis;
- on its own wear clock: hours count from the axis's ``hours_origin`` (an adjustment that left
  the hour counter running on);
- with its visits before such an adjustment (rows whose hours precede the origin) kept for the
  wear rate when cross-validation on the visits since the adjustments prefers it: that earlier
  epoch gets a level map of its own (its difference from the level since the adjustment, pooled
  like the per-target deviations) and shares the rate map, its hours counted from 0; else
  the rate restarts with the level and those visits are left out;
- with its own per-target wear-rate deviations (hat functions on its own targets), since a
  screw wears where that machine works, in a shape no common basis follows;
- sharing strength by partial pooling (``models.wear.pooling``): an axis with few visits borrows
  from the fleet's distribution of maps, an axis with many visits follows its own data.

The number of control points is chosen by rolling-origin cross-validation over the fleet
(``forecast_folds``: each fold forecasts every axis's next visit), and what the held-out
visits missed beyond the model's own variance (``misfit_um_``: the shape no basis follows)
widens every interval. A plan for an
axis the model does not know is forecast from the fleet's distribution, with its spread of
maps and of per-target deviations in the interval.

Each axis keeps its units: a rotary axis's backlash is in arcsec along a travel in deg, a
linear axis's in um along mm. A fleet that has both is pooled unit by unit (``UnitGroups``):
the fit above runs once on the rotary axes and once on the linear ones, so the fleet
distribution of one unit never informs the other, and a unit with a single axis is fitted as
that axis alone. A plan's rows go to the model of their axis's unit (an unknown rotary axis is
forecast from the rotary axes' distribution).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.special import stdtrit

from features.readings.schema import deviation_unit
from models.wear.wear_basis import (
    AXIS_INDEX,
    CONDITIONS,
    GROUPS,
    HOURS,
    POSITION,
    split_groups,
    target_basis,
)

# the fitted state of a model that knows its machine axes (saved with the rest)
FLEET_STATE = ("pooled_", "axes_", "axis_units_", "axis_range_", "hours_origin_",
               "axis_visits_", "axis_sigma_um_", "misfit_um_", "axis_knots_", "deviation_sd_",
               "axis_coef_", "axis_covariance_", "prior_covariance_", "shrinkage_",
               "epoch_shared_", "epoch_columns_", "epoch_axes_")
FLEET_ARRAYS = ("axis_coef_", "axis_covariance_", "prior_covariance_")
# one-visit-ahead folds of the fleet's cross-validation (``forecast_folds``)
HORIZONS = 3
# 1 on the rows of an axis's visits before its adjustment (its earlier wear epoch)
EPOCH = "__epoch__"


class FleetWearMap:
    """The fleet half of ``models.wear.wear_map.WearMap`` (module docstring): its fit, local
    frames, design, pooled fit, cross-validation and the fleet's wear-rate maps. Uses the
    single-axis design (``_design``, ``_solve``, ``_learn_inputs``) of the estimator."""

    def _fit_fleet(self, frame: pd.DataFrame, y: np.ndarray, labels: np.ndarray,
                   hours_origin: dict, earlier=None):
        axis = self._axis_index(labels)
        x = frame[POSITION].to_numpy(float) if POSITION in frame else np.zeros(len(frame))
        self.axis_range_ = [[float(x[axis == a].min()), float(x[axis == a].max())]
                            for a in range(len(self.axes_))]
        self.hours_origin_ = [float(hours_origin.get(k, 0.0)) for k in self.axes_]
        self.axis_visits_ = [len(np.unique(frame[HOURS].to_numpy(float)[axis == a]))
                             if HOURS in frame else 1 for a in range(len(self.axes_))]
        self.misfit_um_ = 0.0
        local = self._local(frame, axis)
        self.axis_knots_ = [np.unique(local[POSITION].to_numpy(float)[axis == a]).tolist()
                            if POSITION in local else [0.0] for a in range(len(self.axes_))]
        self._learn_inputs(local.drop(columns=AXIS_INDEX), axis)
        self.range_mm_ = (float(x.min()), float(x.max()))
        self.cv_scores_ = {}
        self.epoch_shared_, self.epoch_columns_ = False, 0
        self.epoch_axes_ = [False] * len(self.axes_)
        if self.use_position_:
            self.n_control_, fitted = self._choose_fleet(local, y, axis)
            old = self._earlier_local(earlier) if self.use_hours_ else None
            if old is not None:
                local, y, axis, fitted = self._shared_rate(local, y, axis, old, fitted)
        else:
            self.n_control_ = 1
        A = self._fleet_design(local, self.n_control_)
        if not self.use_position_:
            fitted = self._pool(A, y, local, self._blocks(A, y, axis, local))
        # spread of the axes' own per-target deviations [um per 1000 h, or um without hours]
        self.deviation_sd_ = float(fitted.deviation_sd[0]) if self.use_position_ else 0.0
        self.coef_ = fitted.mu
        self.covariance_ = fitted.mu_covariance
        self.prior_covariance_ = fitted.prior
        self.axis_coef_ = fitted.means
        self.axis_covariance_ = fitted.covariances
        self.shrinkage_ = self._borrowed(A, axis, fitted)
        self.axis_sigma_um_ = fitted.sigma.tolist()
        self.sigma_um_ = float(np.sqrt(np.mean(fitted.sigma ** 2)))
        self.visit_sd_um_ = fitted.tau
        self.dof_ = max(len(y) - A.shape[1], 1)
        self.can_forecast_ = bool(self.use_hours_)
        return self

    def _earlier_local(self, earlier):
        """The visits before an adjustment (``earlier``: frame, y, labels) of the axes whose
        wear clock restarted with the hour counter running on, in their local frame with the
        hours counted from 0 and ``EPOCH`` 1; None when there are none."""
        if earlier is None:
            return None
        frame, y, labels = earlier
        axis = self._axis_index(labels)
        origin = np.array([self.hours_origin_[a] if a >= 0 else 0.0 for a in axis])
        hours = frame[HOURS].to_numpy(float)
        keep = (axis >= 0) & (origin > 0) & (hours < origin)
        if not keep.any():
            return None
        local = self._local(frame[keep].reset_index(drop=True), axis[keep])
        local[HOURS] = hours[keep]
        local[EPOCH] = 1.0
        return local, y[keep], axis[keep]

    def _earlier_epoch(self, local: pd.DataFrame, frame: pd.DataFrame) -> pd.DataFrame:
        """``local`` with the rows of a known axis before its wear clock restarted marked as
        its earlier epoch (hours from 0, ``EPOCH`` 1), when the model keeps that epoch."""
        if not getattr(self, "epoch_shared_", False) or HOURS not in local:
            return local
        axis = local[AXIS_INDEX].to_numpy(int)
        origin = np.array([self.hours_origin_[a] if a >= 0 else 0.0 for a in axis])
        hours = frame[HOURS].to_numpy(float)
        old = (axis >= 0) & (origin > 0) & (hours < origin)
        if not old.any():
            return local
        local = local.copy()
        local.loc[old, HOURS] = hours[old]
        local[EPOCH] = old.astype(float)
        return local

    def _shared_rate(self, local, y, axis, old, fitted):
        """Keep the visits before an adjustment for the wear rate, with a level map of their
        own (``EPOCH`` columns), when the fleet's cross-validation on the visits since the
        adjustments prefers it to a rate that restarts; returns the rows and fit chosen."""
        if not self.cv_scores_:
            return local, y, axis, fitted
        restart = (dict(self.cv_scores_), self.misfit_um_, self.n_control_)
        old_local, old_y, old_axis = old
        both = pd.concat([local.assign(**{EPOCH: 0.0}), old_local], ignore_index=True)
        y2, axis2 = np.r_[y, old_y], np.r_[axis, old_axis]
        self.epoch_shared_ = True
        self.epoch_axes_ = [bool(np.any(old_axis == a)) for a in range(len(self.axes_))]
        self.cv_scores_ = {}
        choice, shared = self._choose_fleet(both, y2, axis2, both[EPOCH].to_numpy(float) > 0)
        if min(self.cv_scores_.values()) < min(restart[0].values()):
            self.n_control_ = choice
            return both, y2, axis2, shared
        self.cv_scores_, self.misfit_um_, self.n_control_ = restart
        self.epoch_shared_, self.epoch_columns_ = False, 0
        self.epoch_axes_ = [False] * len(self.axes_)
        return local, y, axis, fitted

    def _borrowed(self, A: np.ndarray, axis: np.ndarray, fitted) -> list[float]:
        """How much of each axis's mean wear rate rests on the fleet: its posterior variance
        over the fleet's spread of mean wear rates, 0 (its own visits decide) .. 1 (the fleet
        alone)."""
        if not self.use_hours_:
            return [1.0] * len(self.axes_)
        out = []
        for a in range(len(self.axes_)):
            row = self._rate_rows(np.asarray(self.axis_knots_[a], float), a)[1].mean(axis=0)
            spread = float(row @ fitted.prior @ row)
            out.append(float(row @ fitted.covariances[a] @ row / spread) if spread > 0 else 1.0)
        return out

    def _axis_index(self, labels: np.ndarray) -> np.ndarray:
        """Row -> index into ``axes_`` (-1 for an axis the model does not know)."""
        lookup = {k: i for i, k in enumerate(self.axes_)}
        return np.array([lookup.get(tuple(k), -1) for k in labels], int)

    def _local(self, frame: pd.DataFrame, axis: np.ndarray, labels=None) -> pd.DataFrame:
        """The inputs in each axis's own frame: position 0..1 between the axis's end targets,
        operating hours since its wear clock restarted. An axis the model does not know is
        mapped over its own targets in ``frame`` (grouped by ``labels``)."""
        local = frame.copy()
        if POSITION in local:
            x = local[POSITION].to_numpy(float)
            lo, hi = np.zeros(len(x)), np.ones(len(x))
            for a in np.unique(axis):
                rows = axis == a
                if a >= 0:
                    lo[rows], hi[rows] = self.axis_range_[a]
                else:  # unknown axes: each over its own targets
                    for key in {tuple(k) for k in labels[rows]}:
                        own = rows & np.array([tuple(k) == key for k in labels])
                        lo[own], hi[own] = x[own].min(), x[own].max()
            local[POSITION] = np.clip((x - lo) / np.maximum(hi - lo, 1e-12), 0.0, 1.0)
        if HOURS in local:
            origin = np.array([self.hours_origin_[a] if a >= 0 else 0.0 for a in axis])
            local[HOURS] = local[HOURS].to_numpy(float) - origin
        local[AXIS_INDEX] = axis
        return local

    def _fleet_design(self, local: pd.DataFrame, choice) -> np.ndarray:
        """The shared design (``_design``: maps on the common 0..1 basis and the condition
        terms) followed by each axis's own per-target wear-rate deviations."""
        A = np.hstack([self._design(local, choice), self._deviation_design(local)])
        if not getattr(self, "epoch_shared_", False):
            return A
        # the earlier epoch's own level: its difference from the level since the adjustment
        flag = (local[EPOCH].to_numpy(float) if EPOCH in local else np.zeros(len(local)))
        levels = self._basis(local[POSITION].to_numpy(float), choice) * flag[:, None]
        self.epoch_columns_ = levels.shape[1]
        return np.hstack([A, levels])

    def _deviation_design(self, local: pd.DataFrame) -> np.ndarray:
        """Hat functions on each axis's own targets (padded to the fleet's most targets) for
        the wear rate (for the level when there are no hours): where one screw wears in a
        shape the common basis cannot follow. The level needs none: every visit measures it
        again, the wear rate is what a forecast extrapolates. Zero for an axis the model does
        not know."""
        if not self.use_position_:
            return np.zeros((len(local), 0))
        width = max(len(k) for k in self.axis_knots_)
        x, axis = local[POSITION].to_numpy(float), local[AXIS_INDEX].to_numpy(int)
        hats = np.zeros((len(local), width))
        for a in np.unique(axis[axis >= 0]):
            rows = axis == a
            knots = np.asarray(self.axis_knots_[a], float)
            hats[rows, :len(knots)] = (target_basis(x[rows], knots) if len(knots) > 1
                                       else np.ones((rows.sum(), 1)))
        if not self.use_hours_:
            return hats
        return hats * local[HOURS].to_numpy(float)[:, None] / 1000.0

    def _deviations(self, A: np.ndarray, y: np.ndarray, local: pd.DataFrame):
        """The axes' own coefficients for ``models.wear.pooling.pool``: which columns each axis
        has and the starting variance (a twentieth of the backlash spread, per the hours
        span for a rate)."""
        from models.wear.pooling import Deviations

        if not self.use_position_:
            return None
        width = max(len(k) for k in self.axis_knots_)
        used = np.array([[j < len(k) for j in range(width)] for k in self.axis_knots_])
        start = (0.05 * max(float(np.std(y)), 1e-6)) ** 2
        if self.use_hours_:
            start /= max(float(np.ptp(local[HOURS])) / 1000.0, 1e-6) ** 2
        if not getattr(self, "epoch_shared_", False):
            return Deviations(np.zeros(width, int), used, np.array([start]))
        # the earlier epochs' level differences: one more group, used by the adjusted axes
        n = self.epoch_columns_
        used = np.hstack([used, np.repeat(np.array(self.epoch_axes_, bool)[:, None], n, 1)])
        return Deviations(np.r_[np.zeros(width, int), np.ones(n, int)], used,
                          np.array([start, (0.3 * max(float(np.std(y)), 1e-6)) ** 2]))

    def _blocks(self, A: np.ndarray, y: np.ndarray, axis: np.ndarray, local: pd.DataFrame):
        from models.wear.pooling import VisitBlocks

        visit = local[HOURS].to_numpy(float) if HOURS in local else np.zeros(len(y))
        return VisitBlocks.of(A, y, axis, visit, len(self.axes_))

    def _pool(self, A: np.ndarray, y: np.ndarray, local: pd.DataFrame, blocks, warm=None):
        """The pooled fit of the rows ``A``, ``y`` (``blocks`` their statistics); ``warm``: a
        fit to start from (a cross-validation fold starts from the fit on all the data)."""
        from models.wear.pooling import FOLD_ITERATIONS, MAX_ITERATIONS, pool

        deviations = self._deviations(A, y, local)
        shared = A.shape[1] - (deviations.size if deviations else 0)
        start = self._solve(A[:, :shared], y)[0]
        column = np.sqrt(np.mean(A[:, :shared] ** 2, axis=0))
        scale = np.maximum(np.abs(start), np.std(y) / np.maximum(column, 1e-12))
        return pool(blocks, start, np.maximum(scale, 1e-9), deviations, warm,
                    MAX_ITERATIONS if warm is None else FOLD_ITERATIONS)

    def _choose_fleet(self, local: pd.DataFrame, y: np.ndarray, axis: np.ndarray,
                      old: np.ndarray | None = None):
        """Control points by cross-validation over the fleet (``forecast_folds``: each fold
        forecasts every axis's visit one ahead of those it fits, as the model will). Returns
        the choice and its fit on all the rows. ``old``: the rows of earlier wear epochs,
        always trained on, never scored."""
        smallest = min(len(np.unique(local[POSITION].to_numpy(float)[axis == a]))
                       for a in range(len(self.axes_)))
        if self.n_control == "targets":
            raise ValueError("n_control='targets' is for one machine axis; on a fleet every "
                             "axis has per-target deviations from the common B-spline maps")
        candidates = ([self.n_control] if self.n_control is not None
                      else list(range(1, min(self.max_control, smallest) + 1)))
        folds = forecast_folds(local, axis, old)
        scored = max(sum(int(test.sum()) for _, test, _ in folds), 1)
        excess, fits = {}, {}
        for choice in candidates:
            scores = list(self.cv_scores_.values())
            if len(scores) >= 3 and scores[-1] > scores[-2] > scores[-3]:
                break  # worse twice in a row: more control points only fit noise
            A = self._fleet_design(local, choice)
            blocks = self._blocks(A, y, axis, local)
            fits[choice] = whole = self._pool(A, y, local, blocks)
            if len(candidates) == 1:
                break
            sse, expected = 0.0, 0.0
            for train, test, keep in folds:
                part = (blocks.subset(keep) if keep is not None
                        else self._blocks(A[train], y[train], axis[train], local[train]))
                fitted = self._pool(A[train], y[train], local[train], part, whole)
                a = axis[test]
                sse += float(np.sum((y[test] - np.sum(A[test] * fitted.means[a], axis=1)) ** 2))
                expected += float(np.sum(
                    np.einsum("ij,ijk,ik->i", A[test], fitted.covariances[a], A[test])
                    + fitted.tau ** 2 + fitted.sigma[a] ** 2))
            self.cv_scores_[str(choice)] = float(np.sqrt(sse / scored))
            excess[choice] = max(0.0, (sse - expected) / scored)
        best = min(fits) if len(fits) == 1 else int(min(self.cv_scores_,
                                                         key=self.cv_scores_.get))
        # what the held-out visits missed by beyond what the posterior, the visit offset and
        # the point noise explain: the shape the basis cannot follow; every forecast carries it
        self.misfit_um_ = float(np.sqrt(excess.get(best, 0.0)))
        return best, fits[best]

    def _unknown_shape_var(self, local: pd.DataFrame) -> np.ndarray:
        hours = (local[HOURS].to_numpy(float) / 1000.0 if self.use_hours_
                 else np.ones(len(local)))
        return (hours * self.deviation_sd_) ** 2

    def unknown_axes(self, X) -> list[tuple[str, str]]:
        """The machine axes named in ``X`` that the model was not fitted on (a fleet model
        forecasts them from the fleet's distribution of maps)."""
        labels, _ = split_groups(X)
        if labels is None or not getattr(self, "pooled_", False):
            return []
        return sorted({tuple(k) for k in labels} - set(self.axes_))

    def _rate_rows(self, position: np.ndarray, a: int):
        """Design rows of axis ``a`` at ``position`` (0..1) giving its level at 0 h (condition
        terms left out) and its wear rate per 1000 h."""
        frame = pd.DataFrame({POSITION: position, HOURS: 0.0, AXIS_INDEX: a,
                              **{c: self.condition_means_[c] for c in self.conditions_}})
        at_zero = self._fleet_design(frame, self.n_control_)
        at_1000 = self._fleet_design(frame.assign(**{HOURS: 1000.0}), self.n_control_)
        k = self._design(frame, self.n_control_).shape[1]
        at_zero[:, k - len(self.conditions_):k] = 0.0
        return at_zero, at_1000 - self._fleet_design(frame, self.n_control_)

    def _fleet_rate_map(self, positions_mm, level) -> pd.DataFrame:
        """One wear-rate map per machine axis over its own travel (``wear_rate_map``)."""
        maps = []
        z = stdtrit(self.dof_, 0.5 + (level or self.level) / 2)
        for a, ((machine, axis), (lo, hi)) in enumerate(zip(self.axes_, self.axis_range_)):
            x = (np.linspace(lo, hi, 50) if positions_mm is None
                 else np.asarray(positions_mm, float))
            start, rate = self._rate_rows(np.clip((x - lo) / max(hi - lo, 1e-12), 0, 1), a)
            coef, cov = self.axis_coef_[a], self.axis_covariance_[a]
            w = rate @ coef
            half = z * np.sqrt(np.einsum("ij,jk,ik->i", rate, cov, rate))
            maps.append(pd.DataFrame({
                "machine_id": machine, "axis": axis, "position_mm": x,
                "wear_rate_um_per_1000h": w, "wear_rate_low": w - half,
                "wear_rate_high": w + half, "b0_um": start @ coef}))
        return pd.concat(maps, ignore_index=True)


def forecast_folds(local: pd.DataFrame, axis: np.ndarray, old: np.ndarray | None = None,
                   horizons: int = HORIZONS) -> list[tuple]:
    """Rolling-origin folds over the fleet, as the model is used: fold j holds out every
    axis's j-th last visit and trains on the visits before it, so each fold forecasts one
    visit ahead of what the pooled fit has seen [Hyndman2021]_, sec. 5.10. An axis with fewer
    than j + 2 visits is not scored in fold j (it still trains on its visits before the
    cut). ``old``: rows of earlier wear epochs, always trained on, never scored.

    Returns ``(train rows, test rows, visit blocks to keep)`` per fold; the blocks (n_axes,
    most visits) match ``_blocks`` when there are no ``old`` rows, else None. Without an
    axis of three visits, five folds by row (no blocks).

    References
    ----------
    .. [Hyndman2021] R. J. Hyndman, G. Athanasopoulos, *Forecasting: Principles and
       Practice*, 3rd ed., OTexts, 2021.
    """
    hours = local[HOURS].to_numpy(float) if HOURS in local else np.zeros(len(local))
    new = np.ones(len(local), bool) if old is None else ~old
    rank, count = np.zeros(len(local), int), np.zeros(len(local), int)
    per_axis = np.zeros(int(axis.max()) + 1, int)
    for a in np.unique(axis):
        rows = (axis == a) & new
        rank[rows] = np.unique(hours[rows], return_inverse=True)[1]
        count[rows] = per_axis[a] = rank[rows].max() + 1 if rows.any() else 0
    if per_axis.max() < 3:
        by_row = np.where(new, np.arange(len(local)) % 5, -1)
        return [(by_row != k, by_row == k, None) for k in range(5)]
    folds = []
    for j in range(1, horizons + 1):
        cut = count - j
        test = new & (rank == cut) & (cut >= 2)
        if not test.any():
            break
        keep = (np.arange(per_axis.max())[None, :] < (per_axis - j)[:, None]
                if old is None else None)
        folds.append(((new & (rank < cut)) | ~new, test, keep))
    return folds


# per-axis state of a model that knows its machine axes, in ``axes_`` order
AXIS_SUMMARY = ("axis_visits_", "hours_origin_", "axis_sigma_um_", "shrinkage_", "axis_range_")
# what a model of several units keeps beside its per-unit models (``unit_maps_``)
UNIT_STATE = ("pooled_", "axes_", "axis_units_", "visit_hours_", *AXIS_SUMMARY,
              "use_position_", "use_hours_", "conditions_", "used_features_", "can_forecast_")


class UnitGroups:
    """A fleet of rotary and linear axes (module docstring): one fitted model per unit
    (``unit_maps_``: deviation unit -> model fitted on that unit's axes alone, by the same
    ``fit``), and their per-axis state merged in ``axes_`` order."""

    def _fit_units(self, frame: pd.DataFrame, y: np.ndarray, labels: np.ndarray,
                   hours_origin: dict, earlier=None):
        from sklearn.base import clone

        units = row_units(labels)
        self.unit_maps_ = {}
        for unit in dict.fromkeys(self.axis_units_):
            rows = units == unit
            X = pd.concat([pd.DataFrame(labels[rows].tolist(), columns=list(GROUPS)),
                           frame[rows].reset_index(drop=True)], axis=1)
            own = y[rows]
            if earlier is not None:  # its rows before a restart of the wear clock
                mine = row_units(earlier[2]) == unit
                X = pd.concat([X, pd.concat(
                    [pd.DataFrame(earlier[2][mine].tolist(), columns=list(GROUPS)),
                     earlier[0][mine].reset_index(drop=True)], axis=1)], ignore_index=True)
                own = np.r_[own, earlier[1][mine]]
            self.unit_maps_[unit] = clone(self).fit(X, own, hours_origin=hours_origin)
        self._merge_units(hours_origin)
        return self

    def _merge_units(self, hours_origin: dict) -> None:
        """The per-axis state of ``axes_`` from the unit models, and the inputs any of them
        uses (a plan gives them all; each model reads its own)."""
        models = self.unit_maps_.values()
        per_axis = {}
        for model in models:
            summary = axis_summary(model, hours_origin)
            for i, key in enumerate(model.axes_):
                per_axis[key] = {name: values[i] for name, values in summary.items()}
        for name in AXIS_SUMMARY:
            setattr(self, name, [per_axis[key][name] for key in self.axes_])
        self.use_position_ = any(m.use_position_ for m in models)
        self.use_hours_ = any(m.use_hours_ for m in models)
        self.can_forecast_ = all(m.can_forecast_ for m in models)
        used = {c for m in models for c in m.used_features_}
        self.conditions_ = [c for c in CONDITIONS if any(c in m.conditions_ for m in models)]
        self.used_features_ = [c for c in (POSITION, HOURS, *self.conditions_) if c in used]

    def _predict_units(self, X: pd.DataFrame, labels: np.ndarray, level):
        """Every row from the model of its axis's unit: (mean, low, high)."""
        units = row_units(labels)
        out = np.zeros((3, len(X)))
        for unit, model in self.unit_maps_.items():
            rows = units == unit
            if rows.any():
                out[:, rows] = model.predict_interval(X[rows], level)
        return out[0], out[1], out[2]

    def _units_rate_map(self, positions_mm, level) -> pd.DataFrame:
        """Every unit model's wear-rate maps (``wear_rate_map``), with the unit of each
        (``um`` or ``arcsec`` per 1000 h)."""
        maps = []
        for unit, model in self.unit_maps_.items():
            rate = model.wear_rate_map(positions_mm, level)
            if "axis" not in rate:  # one axis alone
                rate.insert(0, "axis", model.axes_[0][1])
                rate.insert(0, "machine_id", model.axes_[0][0])
            maps.append(rate.assign(unit=unit))
        return pd.concat(maps, ignore_index=True)

    def _check_units(self, labels: np.ndarray | None) -> None:
        """Refuse rows of an axis whose unit (rotary: arcsec, linear: um) none of the model's
        axes has: no fleet of that unit to forecast it from."""
        from features.readings.errors import InputError

        known = {deviation_unit(a) for _, a in (getattr(self, "axes_", None) or [])}
        if labels is None or not known:
            return
        strange = sorted({(m, a) for m, a in labels if deviation_unit(a) not in known})
        if strange:
            names = ", ".join(f"{m} {a}" for m, a in strange[:3])
            raise InputError(f"{names}: backlash in {deviation_unit(strange[0][1])}, but the "
                             f"model knows only axes in {', '.join(sorted(known))}; train on "
                             "axes of that kind", column="axis")


def row_units(labels: np.ndarray) -> np.ndarray:
    """Deviation unit (``um``, ``arcsec``) of every row's machine axis."""
    return np.array([deviation_unit(a) for _, a in labels], dtype=object)


def axis_summary(model, hours_origin: dict) -> dict[str, list]:
    """``AXIS_SUMMARY`` of a fitted model over its ``axes_``: a fleet's own, or for one axis
    alone its visits, where its hours count from, its noise [um or arcsec], nothing borrowed
    and its travel."""
    if model.pooled_:
        return {name: list(getattr(model, name)) for name in AXIS_SUMMARY}
    key = model.axes_[0]
    return {"axis_visits_": [max(len(model.visit_hours_[0]), 1)],
            "hours_origin_": [float(hours_origin.get(key, 0.0))],
            "axis_sigma_um_": [model.sigma_um_], "shrinkage_": [0.0],
            "axis_range_": [list(model.range_mm_)]}
