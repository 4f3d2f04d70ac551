"""Wear map at fleet scale: 100 machines x 3 axes x 12 visits of the ``wear`` preset, one model
per machine and axis trained on visits 1-11 and forecasting visit 12; time, forecast error
against the truth, and the ratio against fitting the paper network (8-8-8-1, LM) on the same
axes (timed on a sample of axes and scaled, as it is far slower); and all axes in one pooled
fit (one map per axis, sharing strength across the fleet) against the axis-by-axis fits."""

from __future__ import annotations

import time

import numpy as np

from bench import size

MACHINES, AXES, VISITS = size(100, 1), ("X", "Y", "Z"), size(12, 3)
NETWORK_SAMPLE = size(6, 1)  # axes the network is timed on
NETWORK = size({}, {"epochs": 5})  # the paper network's settings; a tiny run's fit is short


def main() -> None:
    from features.table import feature_table
    from models.estimators.evaluation import true_backlash, visit_order
    from models.physics.campaign import load_config, simulate
    from models.serving.registry import make, with_axes

    config = load_config({"fleet": {"machines": MACHINES, "axes": list(AXES),
                                    "visits": VISITS}}, preset="wear")
    start = time.perf_counter()
    sim = simulate(config, seed=0)
    table = feature_table(sim.readings)
    truth = true_backlash(table.meta, sim.truth, table.target_kind)
    prepare_s = time.perf_counter() - start
    groups = table.meta.groupby(["machine_id", "axis"]).indices
    rank = visit_order(table.meta)
    errors, fit_s = [], 0.0
    for rows in groups.values():
        last = rank[rows].max()
        train, test = rows[rank[rows] < last], rows[rank[rows] == last]
        start = time.perf_counter()
        model = make("wear-map").fit(table.X.iloc[train], table.y.iloc[train])
        predicted, _, _ = model.predict_interval(table.X.iloc[test])
        fit_s += time.perf_counter() - start
        errors.append(predicted - truth[test])
    # the same axes in one pooled fit (models.wear.pooling): every axis its own map, sharing
    # strength across the fleet
    X = with_axes(table.X, table.meta)
    train = np.concatenate([rows[rank[rows] < rank[rows].max()] for rows in groups.values()])
    test = np.concatenate([rows[rank[rows] == rank[rows].max()] for rows in groups.values()])
    start = time.perf_counter()
    pooled = make("wear-map").fit(X.iloc[train], table.y.iloc[train])
    predicted, _, _ = pooled.predict_interval(X.iloc[test])
    pooled_s = time.perf_counter() - start
    pooled_rmse = float(np.sqrt(np.mean((predicted - truth[test]) ** 2)))
    network_s = 0.0
    for rows in list(groups.values())[:NETWORK_SAMPLE]:
        train = rows[rank[rows] < rank[rows].max()]
        start = time.perf_counter()
        make("shallow-lm", **NETWORK).fit(table.X.iloc[train], table.y.iloc[train])
        network_s += time.perf_counter() - start
    network_all_s = network_s / NETWORK_SAMPLE * len(groups)
    rmse = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    print(f"simulate + feature table, {len(sim.readings):,} readings: {prepare_s:.1f} s")
    print(f"wear-map fit + forecast, {len(groups)} axes x {VISITS} visits: {fit_s:.2f} s "
          f"({1000 * fit_s / len(groups):.1f} ms per axis); next-visit RMSE vs truth "
          f"{rmse:.3f} um")
    print(f"pooled wear-map fit + forecast of the same {len(groups)} axes in one model: "
          f"{pooled_s:.2f} s ({1000 * pooled_s / len(groups):.1f} ms per axis, "
          f"{pooled_s / fit_s:.2f}x the axis-by-axis fits; goal 2x); next-visit RMSE vs truth "
          f"{pooled_rmse:.3f} um")
    print(f"paper network fit on the same axes: {network_all_s:.0f} s (timed on "
          f"{NETWORK_SAMPLE} axes); ratio network / wear-map {network_all_s / fit_s:.0f}x")


if __name__ == "__main__":
    main()
