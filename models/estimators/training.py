"""Fit one named predictor on a feature table with a hold-out split and score it.

Scores on the held-out points (``test_*``), on the training points (``train_*``) and, when the
twin's truth is known, against the true backlash (``truth_*``) — the number that says whether a
model learned the physics or the noise of the measured target.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.schema import is_rotary
from features.table import FeatureTable, check_features
from models.estimators import evaluation
from models.serving import registry


@dataclass
class Fit:
    name: str
    estimator: object
    table: FeatureTable
    train_index: np.ndarray
    test_index: np.ndarray
    predicted_um: np.ndarray              # for every row of the table
    metrics: dict = field(default_factory=dict)
    truth_um: np.ndarray | None = None
    inputs: pd.DataFrame | None = None    # what the estimator saw (with the axes, per axis)
    refit_all: bool = False               # ``estimator`` refit on every row after the scores

    def trained_model(self, meta: dict | None = None) -> registry.TrainedModel:
        """The fitted estimator with what monitoring needs (input ranges, training inputs) and
        what it may answer for: the machine axes and units of its table (``scope``,
        ``models.serving.signature.scope_of``)."""
        X_train = self.table.X if self.refit_all else self.table.X.iloc[self.train_index]
        meta_train = self.table.meta if self.refit_all else self.table.meta.iloc[self.train_index]
        ranges = {c: (float(X_train[c].min()), float(X_train[c].max())) for c in X_train}
        from models.serving.signature import SCOPE, scope_of

        axes = _known_axes(self.estimator)
        return registry.TrainedModel(
            self.name, self.estimator, list(self.table.X.columns), self.table.target_kind,
            self.metrics["test_rmse_um"], ranges, X_train.reset_index(drop=True),
            {"metrics": self.metrics, SCOPE: scope_of(meta_train),
             **({"axes": axes} if axes else {}), **(meta or {})})


def _known_axes(estimator) -> list[dict]:
    """model.json's list of the machine axes a per-axis model knows: visits since the wear
    clock restarted, where the hours count from, the axis's noise and how much it borrowed
    from the fleet, and the unit of its backlash (``um``, ``arcsec`` for a rotary axis)."""
    from features.readings.schema import deviation_unit

    known = registry.knows_axes(estimator)
    return [{"machine_id": m, "axis": a, "unit": deviation_unit(a),
             "visits": int(estimator.axis_visits_[i]),
             "hours_origin": float(estimator.hours_origin_[i]),
             "noise_um": round(float(estimator.axis_sigma_um_[i]), 4),
             "borrowed": round(float(estimator.shrinkage_[i]), 3)}
            for i, (m, a) in enumerate(known)]


def fit_model(table: FeatureTable, name: str, split: str = "random", random_state: int = 0,
              truth: pd.DataFrame | None = None, noise_floor_um: float | None = None,
              source: str = "data", hours_origin: dict | None = None) -> Fit:
    """Fit ``name`` (``models.serving.registry``) on the training part of ``split`` and score it.

    A per-axis predictor sees each row's machine axis and ``hours_origin`` (from
    ``since_adjustment``): where each axis's wear clock restarted with its counter running on.
    """
    check_features(table.X, source)
    train, test = evaluation.holdout(table.meta, split, random_state, source)
    estimator = registry.make(name, random_state)
    registry.check_inputs(name, estimator, table.X.columns, source)
    X, extra = model_inputs(table, name, hours_origin)
    earlier = earlier_inputs(table, name)
    estimator.fit(*with_earlier(X.iloc[train], table.y.iloc[train], earlier), **extra)
    predicted = np.asarray(estimator.predict(X), float)
    y = table.y.to_numpy(float)
    rotary = (table.meta["axis"].map(is_rotary).to_numpy(bool) if "axis" in table.meta
              else np.zeros(len(y), bool))
    mixed = bool(rotary.any() and not rotary.all())
    metrics = {f"{part}_{k}": v for part, rows in (("test", test), ("train", train))
               for k, v in evaluation.scores_by_unit(y[rows], predicted[rows], rotary[rows],
                                                     mixed).items()}
    fit = Fit(name, estimator, table, train, test, predicted, metrics, inputs=X)
    if registry.predictor(name).forecasts:  # scored on the hold-out, saved fitted on it all
        fit.estimator = registry.make(name, random_state).fit(
            *with_earlier(X, table.y, earlier), **extra)
        fit.refit_all = True
    if truth is not None:
        fit.truth_um = evaluation.true_backlash(table.meta, truth, table.target_kind)
        known = test[np.isfinite(fit.truth_um[test])]
        if known.size:
            metrics |= {f"truth_{k}": v for k, v in
                        evaluation.scores(fit.truth_um[known], predicted[known]).items()}
            # what the measured target itself misses the truth by: the noise floor in practice
            metrics["target_truth_rmse_um"] = float(np.sqrt(np.mean(
                (y[known] - fit.truth_um[known]) ** 2)))
    if noise_floor_um is not None:
        metrics["noise_floor_um"] = float(noise_floor_um)
    return fit


def earlier_inputs(table: FeatureTable, name: str):
    """The inputs and targets of the visits ``since_adjustment`` set aside before an
    adjustment that left the hour counter running on, for a fleet's per-axis predictor (it
    tells them by their axis's hours origin and may keep them for the wear rate); None
    otherwise. They are trained on, never held out nor scored."""
    earlier = table.earlier
    if (earlier is None or not registry.predictor(name).per_axis
            or table.meta.groupby(["machine_id", "axis"], observed=True).ngroups < 2):
        return None
    return model_inputs(earlier, name)[0], earlier.y


def with_earlier(X: pd.DataFrame, y: pd.Series, earlier) -> tuple[pd.DataFrame, pd.Series]:
    """``X``, ``y`` followed by the rows of ``earlier_inputs`` (when there are any)."""
    if earlier is None:
        return X, y
    return (pd.concat([X, earlier[0]], ignore_index=True),
            pd.concat([y, earlier[1]], ignore_index=True))


def model_inputs(table: FeatureTable, name: str, hours_origin: dict | None = None):
    """The inputs predictor ``name`` is fitted on and the keyword arguments of its ``fit``: a
    per-axis predictor gets each row's machine axis and the axes' wear-clock origins."""
    if not registry.predictor(name).per_axis:
        return table.X, {}
    return registry.with_axes(table.X, table.meta), {"hours_origin": hours_origin or {}}


def visit_series(readings: pd.DataFrame, stats: pd.DataFrame | None = None,
                 points: pd.DataFrame | None = None) -> tuple[pd.DataFrame | None, str]:
    """Per-visit backlash of every machine axis (``features.visits.visit_backlash``) for the
    change-point search of ``since_adjustment``, or None and why it cannot be had; ``stats``
    the readings' ``features.iso230.per_target`` and ``points`` their 'auto' backlash points
    when already computed."""
    from features.readings.errors import InputError
    from features.visits import visit_backlash

    try:
        return visit_backlash(readings, stats, points=points), ""
    except InputError as err:
        return None, f"no change-point search ({err.message})"


def since_adjustment(table: FeatureTable, readings: pd.DataFrame | None = None,
                     stats: pd.DataFrame | None = None):
    """The rows since the last mechanical adjustment of each machine axis, and a note.

    An adjustment is a drop in operating hours, an ``event`` 'adjustment', or a downward level
    change point of the per-visit backlash found by the drift statistics (when ``readings``
    with dates are given). Returns the reduced table and a note for the model's meta:
    ``series`` (per machine axis: visits kept, visits dropped, reason), ``change_points``
    ('searched' or why not), ``rows_used`` and ``rows``. ``stats``: the readings'
    ``features.iso230.per_target`` when already computed.
    """
    from models.wear.wear_map import found_adjustments, wear_epochs

    series, why_not = (visit_series(readings, stats, table.auto_points) if readings is not None
                       else (None, "no change-point search (no readings)"))
    adjustments = found_adjustments(series) if series is not None else None
    mask, notes = wear_epochs(table.meta, table.X.get("operating_hours"),
                              table.meta.get("event"), adjustments)
    note = {"series": notes, "change_points": "searched" if series is not None else why_not,
            "rows_used": int(mask.sum()), "rows": len(mask)}
    kept = FeatureTable(table.X[mask].reset_index(drop=True),
                        table.y[mask].reset_index(drop=True),
                        table.meta[mask].reset_index(drop=True), table.target_kind, table.reason)
    kept.earlier = earlier_epoch(table, mask, notes, adjustments)
    return kept, note


def earlier_epoch(table: FeatureTable, mask: np.ndarray, notes: list[dict],
                  adjustments: pd.DataFrame | None):
    """The wear epoch just before the last adjustment of each machine axis whose hour counter
    ran on through it (a wear map may keep those visits for the wear rate, with a level of
    their own), or None. ``mask``, ``notes``: ``wear_epochs`` of the table."""
    from models.wear.wear_map import wear_epochs

    if "machine_id" not in table.meta or "axis" not in table.meta:
        return None
    running = {(n["machine_id"], n["axis"]) for n in notes
               if n["dropped"] and "operating hours drop" not in n["reason"]}
    if not running or "operating_hours" not in table.X:
        return None
    rest = ~mask
    meta = table.meta[rest].reset_index(drop=True)
    events = meta.get("event")
    before, _ = wear_epochs(meta, table.X["operating_hours"][rest].reset_index(drop=True),
                            events, adjustments)
    axes = pd.MultiIndex.from_frame(meta[["machine_id", "axis"]].astype(str))
    rows = np.zeros(len(mask), bool)
    rows[rest] = before & axes.isin(list(running))
    if not rows.any():
        return None
    return FeatureTable(table.X[rows].reset_index(drop=True),
                        table.y[rows].reset_index(drop=True),
                        table.meta[rows].reset_index(drop=True), table.target_kind, table.reason)


def hours_origins(table: FeatureTable, notes: list[dict]) -> dict:
    """Where each machine axis's wear clock restarted with its hour counter running on:
    (machine_id, axis) -> the operating hours [h] of its first visit since the adjustment (the
    adjustment's own hours are not recorded; the level b0 of that axis is then its backlash at
    that visit). Axes whose hours dropped at the adjustment, or that were never adjusted,
    count from 0."""
    hours = table.X.get("operating_hours")
    if hours is None:
        return {}
    origins = {}
    for note in notes:
        if not note["dropped"] or "operating hours drop" in note["reason"]:
            continue
        rows = ((table.meta["machine_id"].astype(str) == note["machine_id"])
                & (table.meta["axis"].astype(str) == note["axis"])).to_numpy()
        if rows.any():
            origins[(note["machine_id"], note["axis"])] = float(hours[rows].min())
    return origins
