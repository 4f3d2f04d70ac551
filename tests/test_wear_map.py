"""The wear map against known truth: the twin's local growing wear (both measuring systems,
three seeds) and a second, independently written generator with its own wear shape."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features.table import feature_table
from models.condition.backtest import backtest, summary
from models.estimators.evaluation import target_noise_floor, true_backlash, visit_order
from models.physics.campaign import load_config, simulate, wear_rate_um_per_1000h
from models.wear.wear_map import WearMap, latest_epoch


def last_visit_split(table):
    rank = visit_order(table.meta)
    return rank < rank.max(), rank == rank.max()


@pytest.fixture(scope="module")
def fleets():
    """Twin fleets with localized growing wear: 2 measuring systems x 3 seeds."""
    out = []
    for system in ("direct", "indirect"):
        for seed in (1, 2, 3):
            sim = simulate(load_config({"system": system}, preset="wear"), seed=seed)
            out.append((sim, feature_table(sim.readings)))
    return out


def test_next_visit_forecast_beats_the_noise_floor_and_intervals_cover_the_truth(fleets):
    covered, covered_plan = [], []
    for sim, table in fleets:
        train, test = last_visit_split(table)
        model = WearMap().fit(table.X[train], table.y[train])
        truth = true_backlash(table.meta, sim.truth, table.target_kind)[test]
        floor = target_noise_floor(sim.readings, table.target_kind)
        mean, low, high = model.predict_interval(table.X[test])
        # from a plan alone: no deviations and no machine temperature, only targets, hours, feed
        plan = table.X[test].assign(machine_temp_c=np.nan, deviation_up_um=np.nan,
                                    deviation_down_um=np.nan).drop(
            columns=["deviation_up_um", "deviation_down_um"])
        plan_mean, plan_low, plan_high = model.predict_interval(
            plan.reindex(columns=table.X.columns, fill_value=0.0))
        assert np.sqrt(np.mean((mean - truth) ** 2)) < floor
        assert np.sqrt(np.mean((plan_mean - truth) ** 2)) < floor
        covered += list((low <= truth) & (truth <= high))
        covered_plan += list((plan_low <= truth) & (truth <= plan_high))
        assert np.all(plan_high - plan_low > high - low)  # an unknown temperature widens it
    assert 0.85 <= np.mean(covered) <= 0.99, np.mean(covered)
    assert 0.85 <= np.mean(covered_plan) <= 0.99, np.mean(covered_plan)


def test_wear_rate_map_finds_where_and_how_fast_the_screw_wears(fleets):
    for sim, table in fleets:
        visits = sim.visits
        fleet = sim.parameters["config"]["fleet"]
        model = WearMap().fit(table.X, table.y)
        targets = np.unique(table.meta["target"])
        found = model.wear_rate_map(targets)
        true = wear_rate_um_per_1000h(targets, fleet, visits["wear_local_um_per_1000h"].iloc[0])
        inside = (found["wear_rate_low"] <= true) & (true <= found["wear_rate_high"])
        assert inside.mean() >= 0.6, (found, true)
        assert np.abs(found["wear_rate_um_per_1000h"] - true).max() < 0.25
        assert targets[np.argmax(found["wear_rate_um_per_1000h"])] == targets[np.argmax(true)]


def test_backtest_wear_map_beats_persistence_and_the_paper_network(fleets):
    sim, table = fleets[0]
    result = summary(backtest(table, ["wear-map", "shallow-lm"], sim.truth))
    rmse = result.set_index("model")["truth_rmse_um"]
    assert rmse["wear-map"] < 0.6 * rmse["persistence"]
    assert rmse["wear-map"] < 0.6 * rmse["shallow-lm"]
    assert result.iloc[0]["model"] == "wear-map"
    assert result.set_index("model").loc["wear-map", "skill_vs_persistence"] > 0.3


def test_saves_and_loads_itself_as_json(tmp_path, fleets):
    from models.serving.persistence import load_estimator, save_estimator

    _, table = fleets[0]
    model = WearMap().fit(table.X, table.y)
    spec = save_estimator(model, tmp_path, "estimator")
    assert spec["format"] == "self" and (tmp_path / "estimator" / "wear_map.json").is_file()
    back = load_estimator(tmp_path, spec, WearMap())
    np.testing.assert_allclose(back.predict(table.X), model.predict(table.X))
    np.testing.assert_allclose(back.predict_interval(table.X)[2],
                               model.predict_interval(table.X)[2])
    pd.testing.assert_frame_equal(back.wear_rate_map(), model.wear_rate_map())


def test_numpy_input_with_features_names_the_columns(fleets):
    _, table = fleets[0]
    named = WearMap().fit(table.X, table.y)
    plain = WearMap(features=tuple(table.X.columns)).fit(table.X.to_numpy(), table.y.to_numpy())
    np.testing.assert_allclose(plain.predict(table.X.to_numpy()), named.predict(table.X))
    assert WearMap().fit(table.X.to_numpy(), table.y).can_forecast_ is False  # unnamed inputs


def test_single_visit_cannot_forecast(fleets):
    _, table = fleets[0]
    first = visit_order(table.meta) == 1
    model = WearMap().fit(table.X[first], table.y[first])
    assert model.can_forecast_ is False
    assert np.isnan(model.wear_rate_map()["wear_rate_low"]).all()


def test_adjustment_restarts_the_wear_clock():
    meta = pd.DataFrame({"machine_id": "M1", "axis": "X",
                         "visit": ["01", "02", "03", "04", "05"]})
    hours = pd.Series([0.0, 500.0, 1000.0, 0.0, 500.0])
    assert latest_epoch(meta, hours).tolist() == [False, False, False, True, True]
    events = pd.Series(["", "", "adjustment", "", ""])
    assert latest_epoch(meta, None, events).tolist() == [False, False, True, True, True]


# ---- a second generator, written independently of the twin ---------------------------------

def independent_readings(seed: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Linear ISO tests of an indirect axis (every approach carries the lost motion): a uniform
    plus triangular wear profile growing like h^1.1, lost motion rising with feed, a quadratic
    lead error; irregular targets over 0-600 mm. Returns readings and the true backlash per
    visit and target."""
    rng = np.random.default_rng(seed)
    targets = np.round(np.sort(rng.uniform(0, 600, 11)), 1)
    peak_mm, half_mm = rng.uniform(200, 400), 120.0
    rate = 0.3 + 1.5 * np.clip(1 - np.abs(targets - peak_mm) / half_mm, 0, None)  # um/1000 h
    rows, truth = [], []
    for v in range(1, 8):
        hours = 700.0 * (v - 1)
        for feed in (300.0, 900.0, 2000.0):
            b = 1.0 + rate * (hours / 1000) ** 1.1 + 0.4 * feed / 1000
            test = f"v{v}-f{feed:g}"
            truth += [{"visit": f"{v}", "feed_mm_min": feed, "target": x, "true_backlash_um": bi}
                      for x, bi in zip(targets, b, strict=True)]
            for cycle in (1, 2, 3, 4):
                for direction, sign in (("+", 1), ("-", -1)):
                    dev = (2e-5 * targets ** 2 - sign * b / 2
                           + rng.normal(0, 0.25, len(targets)))
                    rows += [{"machine_id": "K7", "axis": "Y", "test_id": test,
                              "method": "linear", "target": x, "direction": direction,
                              "cycle": cycle, "deviation_um": round(d, 2), "visit": f"{v}",
                              "feed_mm_min": feed, "operating_hours": hours,
                              "machine_temp_c": 22.0 + rng.normal(0, 0.3)}
                             for x, d in zip(targets, dev, strict=True)]
    return pd.DataFrame(rows), pd.DataFrame(truth)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_independent_generator_triangular_wear_nonlinear_growth(seed):
    from features.readings.validation import validate

    raw, truth = independent_readings(seed)
    readings = validate(raw.astype(str), __import__("pathlib").Path("independent.csv"), 2)
    table = feature_table(readings, target="iso")
    train, test = last_visit_split(table)
    model = WearMap().fit(table.X[train], table.y[train])
    true = table.meta[test].merge(truth, on=["visit", "feed_mm_min", "target"],
                                  how="left")["true_backlash_um"].to_numpy()
    mean = model.predict(table.X[test])
    last = (table.meta[test].merge(
        table.meta[visit_order(table.meta) == visit_order(table.meta).max() - 1]
        .assign(y=table.y[visit_order(table.meta) == visit_order(table.meta).max() - 1].values),
        on=["feed_mm_min", "target"], how="left")["y"].to_numpy())
    rmse = np.sqrt(np.mean((mean - true) ** 2))
    assert rmse < np.sqrt(np.mean((last - true) ** 2)) / 2  # beats persistence clearly
    assert rmse < target_noise_floor(readings, "iso")
    found = model.wear_rate_map(np.unique(table.meta["target"]))
    peak = found["position_mm"].iloc[found["wear_rate_um_per_1000h"].argmax()]
    targets = np.unique(table.meta["target"])
    assert abs(peak - targets[np.argmin(np.abs(targets - _peak(seed)))]) < 120
    assert found["wear_rate_um_per_1000h"].min() > 0


def _peak(seed: int) -> float:
    rng = np.random.default_rng(seed)
    rng.uniform(0, 600, 11)
    return rng.uniform(200, 400)
