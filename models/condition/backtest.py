"""Rolling-origin backtest: forecast the next maintenance visit the way forecasting libraries
backtest (skforecast, sktime): for every origin k, train on visits <= k, predict visit k + 1.

Every predictor is scored on the points of the forecast visit against what was measured there
and, on twin data, against the true backlash; beside them stands *persistence*, the forecast
that the next visit measures what the last one did (the same point's value at visit k, else that
target's mean at visit k). An adjustment restarts the wear clock: training keeps the visits since
the last adjustment before the origin (``models.wear.wear_map.latest_epoch``: a drop in operating
hours, an ``event``, or, given the per-visit backlash series, a downward change point that the
drift statistics find in the visits up to the origin, so nothing is learned from the future),
and an origin whose next visit is itself a known adjustment (hours or event) is skipped
(nothing before it says where the new clock starts). Predictors with ``predict_interval`` also
report how often their 95 % interval covers the measured value (``cover95_measured_pct``) and,
on twin data, the true backlash (``cover95_true_pct``).

A trained predictor's forecasting skill (``forecast_skill``: 1 - RMSE / RMSE of persistence over
a backtest on its own training table) is what ranks registered models for the champion; the
model jobs compute it with the fit, so it is the same whether or not the run is tracked.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError, Progress, report
from features.table import FeatureTable
from models.estimators import evaluation
from models.serving import registry
from models.wear.wear_map import found_adjustments, latest_epoch

PERSISTENCE = "persistence"
MIN_SKILL_VISITS = 3  # the skill's backtest trains on visits <= k (at least 2), forecasts k + 1
MAX_SKILL_ORIGINS = 4  # the skill's backtest forecasts the last visits only: <= 4 extra fits
SAME_POINT = ("machine_id", "axis", "feed_mm_min", "dwell_s", "repeat", "target")


def origins(table: FeatureTable, min_train_visits: int = 2) -> list[int]:
    """Visit ranks k that can serve as an origin: at least ``min_train_visits`` visits up to k."""
    rank = evaluation.visit_order(table.meta)
    visits = np.unique(rank)
    if len(visits) < min_train_visits + 1:
        raise InputError(f"the backtest needs at least {min_train_visits + 1} visits "
                         f"(found {len(visits)}): it trains on visits <= k and forecasts k + 1",
                         file=table.meta.attrs.get("source", "data"))
    return [int(k) for k in visits[min_train_visits - 1:-1]]


def persistence(table: FeatureTable, train: np.ndarray, test: np.ndarray) -> np.ndarray:
    """Last measured value at the same point (same machine, axis, conditions and target) in the
    latest training visit; that target's mean there when the point is new."""
    meta, y = table.meta, table.y.to_numpy(float)
    rank = evaluation.visit_order(meta)
    last = train[rank[train] == rank[train].max()]
    keys = [k for k in SAME_POINT if k in meta]
    known = meta.iloc[last][keys].assign(_y=y[last]).groupby(keys, dropna=False)["_y"].mean()
    found = meta.iloc[test][keys].merge(known.reset_index(), on=keys, how="left")["_y"]
    by_target = (meta.iloc[last][["target"]].assign(_y=y[last]).groupby("target")["_y"].mean())
    fallback = meta.iloc[test]["target"].map(by_target).to_numpy(float)
    out = found.to_numpy(float)
    out = np.where(np.isnan(out), fallback, out)
    return np.where(np.isnan(out), float(np.mean(y[last])), out)


def backtest(table: FeatureTable, names: list[str], truth: pd.DataFrame | None = None,
             random_state: int = 0, min_train_visits: int = 2,
             progress: Progress | None = None,
             visits: pd.DataFrame | None = None,
             params: dict | None = None) -> pd.DataFrame:
    """One row per predictor and origin: ``model, origin, forecast_visit, n_train, n_test,
    rmse_um, mae_um`` (against the measured target), ``truth_rmse_um`` and the share [%] of the
    points whose 95 % interval holds the measured value (``cover95_measured_pct``) and the true
    one (``cover95_true_pct``) where known. ``progress(done, total, what)`` hears of each origin.
    ``visits``: the per-visit backlash (``features.visits.visit_backlash``) whose downward
    change points up to each origin also restart the wear clock. ``params``: predictor name ->
    parameters every origin's fit takes (a trained model's choices, so the backtest scores
    that model rather than choosing again)."""
    meta = table.meta
    rank = evaluation.visit_order(meta)
    y = table.y.to_numpy(float)
    true = evaluation.true_backlash(meta, truth, table.target_kind) if truth is not None else None
    hours = table.X.get("operating_hours", None)
    events = meta.get("event", None)
    visit_rank = dict(zip(meta["visit"].astype(str), rank, strict=True))
    rows = []
    steps = origins(table, min_train_visits)
    for i, k in enumerate(steps):
        report(progress, i, len(steps), f"origin {k}")
        upto = rank <= k + 1
        adjustments = None
        if visits is not None:  # change points from the visits up to the origin only
            known = visits["visit"].astype(str).map(visit_rank) <= k
            adjustments = found_adjustments(visits[known.to_numpy()])
        epoch = np.zeros(len(meta), bool)
        epoch[upto] = latest_epoch(meta[upto], None if hours is None else hours[upto],
                                   None if events is None else events[upto], adjustments)
        test = np.flatnonzero(rank == k + 1)
        if not epoch[test].all():  # the forecast visit is an adjustment: a new clock
            continue
        train = np.flatnonzero(epoch & (rank <= k))
        if len(np.unique(rank[train])) < min_train_visits:
            continue
        forecast_visit = str(meta["visit"].iloc[test[0]])
        for name in [PERSISTENCE, *names]:
            predicted, low, high = _forecast(table, name, train, test, random_state,
                                             (params or {}).get(name, {}))
            row = {"model": name, "origin": int(k), "forecast_visit": forecast_visit,
                   "n_train": len(train), "n_test": len(test),
                   **{f"{m}": v for m, v in evaluation.scores(y[test], predicted).items()
                      if m in ("rmse_um", "mae_um")}}
            if low is not None:
                row["cover95_measured_pct"] = float(100 * np.mean((low <= y[test])
                                                                  & (y[test] <= high)))
            if true is not None and np.isfinite(true[test]).all():
                row["truth_rmse_um"] = float(np.sqrt(np.mean((predicted - true[test]) ** 2)))
                if low is not None:
                    row["cover95_true_pct"] = float(100 * np.mean(
                        (low <= true[test]) & (true[test] <= high)))
            rows.append(row)
    report(progress, len(steps), len(steps), "origins")
    if not rows:
        raise InputError("no origin to backtest: every forecast visit follows an adjustment or "
                         "has too few visits before it", file=meta.attrs.get("source", "data"))
    return pd.DataFrame(rows)


def _forecast(table, name, train, test, random_state, params):
    if name == PERSISTENCE:
        return persistence(table, train, test), None, None
    from models.estimators.training import model_inputs

    estimator = registry.make(name, random_state, **params)
    (X, extra), y = model_inputs(table, name), table.y
    estimator.fit(X.iloc[train], y.iloc[train], **extra)
    if hasattr(estimator, "predict_interval"):
        return estimator.predict_interval(X.iloc[test])
    return np.asarray(estimator.predict(X.iloc[test]), float), None, None


def summary(results: pd.DataFrame) -> pd.DataFrame:
    """Per predictor, over all origins: RMSE pooled over points (measured and true), MAE,
    the 95 % intervals' coverage of the measured and the true values (``cover95_measured_pct``,
    ``cover95_true_pct``), and the skill against persistence (1 - RMSE / RMSE of persistence)."""
    def pooled(frame, column):
        return float(np.sqrt(np.sum(frame[column] ** 2 * frame["n_test"]) / frame["n_test"].sum()))

    rows = []
    for name, frame in results.groupby("model", sort=False):
        row = {"model": name, "origins": len(frame), "rmse_um": pooled(frame, "rmse_um"),
               "mae_um": float(np.average(frame["mae_um"], weights=frame["n_test"]))}
        if "truth_rmse_um" in frame and frame["truth_rmse_um"].notna().all():
            row["truth_rmse_um"] = pooled(frame, "truth_rmse_um")
        for column in ("cover95_measured_pct", "cover95_true_pct"):
            if column in frame and frame[column].notna().all():
                row[column] = float(np.average(frame[column], weights=frame["n_test"]))
        rows.append(row)
    out = pd.DataFrame(rows)
    base = out.set_index("model").loc[PERSISTENCE, "rmse_um"]
    out["skill_vs_persistence"] = 1 - out["rmse_um"] / base
    return out.sort_values("rmse_um", kind="stable").reset_index(drop=True)


def forecast_skill(fit, min_visits: int = MIN_SKILL_VISITS,
                   max_origins: int = MAX_SKILL_ORIGINS) -> dict:
    """Forecasting skill of a predictor that forecasts (``models.serving.registry`` record
    ``forecasts``) from a rolling-origin backtest on its training table.

    Parameters
    ----------
    fit : models.estimators.training.Fit
        The fitted predictor; its table (for a wear map: the visits since each axis's last
        adjustment) is the backtest's data.
    min_visits : int
        Fewer visits give no skill (the backtest trains on >= 2 visits, forecasts the next).
    max_origins : int
        The backtest forecasts the last ``max_origins`` visits only, each from every visit
        before it: its cost is at most that many extra fits of the predictor.

    Returns
    -------
    dict
        ``skill`` = 1 - RMSE / RMSE of persistence over the origins' points (rounded to 4
        decimals), ``rmse_um``, ``persistence_rmse_um`` and ``origins``; or ``skill`` None and
        ``reason`` (the predictor does not forecast, too few visits, no origin).
    """
    import math

    if not registry.predictor(fit.name).forecasts:
        return {"skill": None, "reason": f"{fit.name} does not forecast a plan"}
    visits = len(set(evaluation.visit_order(fit.table.meta).tolist()))
    if visits < min_visits:
        return {"skill": None, "reason": f"{visits} visit(s) in the training data; the "
                                         f"backtest needs at least {min_visits}"}
    try:
        # the trained model's own choices (a wear map's control points): no CV per origin
        chosen = getattr(fit.estimator, "chosen_params", dict)()
        results = backtest(fit.table, [fit.name], min_train_visits=max(2, visits - max_origins),
                           params={fit.name: chosen})
        scored = summary(results).set_index("model")
    except InputError as err:
        return {"skill": None, "reason": err.message}
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:  # a fold failed to fit
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        return {"skill": None, "reason": f"the backtest failed: {first[:200]}"}
    skill = float(scored.loc[fit.name, "skill_vs_persistence"])
    if not math.isfinite(skill):
        return {"skill": None, "reason": "persistence forecasts the training data exactly"}
    return {"skill": round(skill, 4), "rmse_um": float(scored.loc[fit.name, "rmse_um"]),
            "persistence_rmse_um": float(scored.loc[PERSISTENCE, "rmse_um"]),
            "origins": int(scored.loc[fit.name, "origins"])}
