"""Monitoring a trained predictor across visits: residuals against its validation band and
drift of its inputs against the training inputs (range and Kolmogorov-Smirnov)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from features.visits import SERIES_KEYS


def residual_band_um(validation_rmse_um: float, n_points, quantile: float = 0.99):
    """Upper bound [um] of a visit's RMSE when the model still performs as validated.

    With n independent residuals of scale rmse_val, n RMSE²/rmse_val² ~ chi²_n, so
    bound = rmse_val sqrt(chi²_{n, quantile} / n).
    """
    n = np.asarray(n_points, float)
    return validation_rmse_um * np.sqrt(stats.chi2.ppf(quantile, n) / n)


def monitor_model(model, readings: pd.DataFrame, *, alpha: float = 0.01) -> pd.DataFrame:
    """Residuals and input drift of a trained predictor on every visit.

    Parameters
    ----------
    model : object with ``predict(X)``, ``feature_names_``, ``validation_rmse_`` [um],
        ``input_ranges_`` {feature: (lo, hi)}, ``training_inputs_`` (DataFrame or None) and
        optionally ``target_kind``
    readings : validated readings table
    alpha : level of the residual band (quantile 1 - alpha) and of the KS tests
        (Bonferroni over the inputs)

    Returns
    -------
    DataFrame, one row per (machine_id, axis, visit): ``n_points``, ``rmse_um``, ``bias_um``,
    ``band_um``, ``retrain`` (rmse above the band), ``out_of_range`` (inputs with values outside
    the training range), ``ks_p`` {input: p}, ``drifted`` (inputs whose KS p < alpha/k).
    """
    from features.table import feature_table

    features = list(model.feature_names_)
    table = feature_table(readings, target=getattr(model, "target_kind", "auto"),
                          features=features)
    from models.serving.registry import with_axes

    residual = table.y.to_numpy(float) - np.asarray(
        model.predict(with_axes(table.X, table.meta)), float)
    keys = [*SERIES_KEYS, "visit"]
    meta = table.meta[keys].reset_index(drop=True)
    frame = meta.assign(r=residual, r2=residual ** 2)
    g = frame.groupby(keys, sort=True)
    out = pd.DataFrame({"n_points": g.size(), "rmse_um": np.sqrt(g["r2"].mean()),
                        "bias_um": g["r"].mean()})
    out["band_um"] = residual_band_um(float(model.validation_rmse_), out["n_points"],
                                      1 - alpha)
    out["retrain"] = out["rmse_um"] > out["band_um"]
    X = table.X.reset_index(drop=True)
    ranges = getattr(model, "input_ranges_", {}) or {}
    training = getattr(model, "training_inputs_", None)
    ranged = [f for f in features if f in ranges]
    tested = [f for f in features if training is not None and f in training.columns]
    outside, ks_p, drifted = [], [], []
    for key in out.index:  # one entry per visit, not per reading
        rows = X.iloc[g.indices[key]]
        outside.append([f for f in ranged
                        if ((rows[f] < ranges[f][0]) | (rows[f] > ranges[f][1])).any()])
        p = {f: float(stats.ks_2samp(training[f].dropna(), rows[f].dropna()).pvalue)
             for f in tested if rows[f].nunique() > 0}
        ks_p.append(p)
        drifted.append([f for f, pv in p.items() if pv < alpha / max(len(p), 1)])
    out["out_of_range"], out["ks_p"], out["drifted"] = outside, ks_p, drifted
    return out.reset_index()


