"""Forecasting through the CLI: predict from a plan with intervals, guard rails, backtest."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from features.readings.errors import InputError
from models.physics.campaign import simulate
from pipeline.cli import main

POINT = ["machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target"]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wear")
    sim = simulate("wear", seed=4)
    readings = sim.readings
    readings[readings["visit"] < "08"].to_csv(folder / "train.csv", index=False)
    readings[readings["visit"] == "01"].to_csv(folder / "one_visit.csv", index=False)
    new = readings[readings["visit"] == "08"]
    plan = new.groupby(POINT, as_index=False)["operating_hours"].first()
    plan.to_csv(folder / "plan.csv", index=False)
    sim.truth.to_csv(folder / "truth.csv", index=False)
    readings.to_csv(folder / "all.csv", index=False)
    return folder, sim


@pytest.fixture(scope="module")
def wear_model(campaign, tmp_path_factory):
    """A wear map trained on visits 1-7, saved as a model directory (without MLflow)."""
    from features.readings import read_readings
    from features.table import feature_table
    from models.estimators.training import fit_model
    from models.serving.registry import save_model

    folder, _ = campaign
    table = feature_table(read_readings(folder / "train.csv"))
    fit = fit_model(table, "wear-map", "random", 0)
    return save_model(fit.trained_model(), tmp_path_factory.mktemp("model") / "wear-map")


def one_error_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines()
           if line.strip() and not line.startswith("note:")]
    assert len(err) == 1, err
    return err[0]


def test_plan_forecast_has_intervals_that_cover_the_truth(campaign, tmp_path, capsys):
    folder, sim = campaign
    model = tmp_path / "m"
    assert main(["train", str(folder / "train.csv"), "--model", "wear-map", "--out",
                 str(model)]) == 0
    capsys.readouterr()
    out = tmp_path / "p.csv"
    assert main(["predict", str(model), str(folder / "plan.csv"), "--out", str(out),
                 "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    pred = pd.read_csv(out, dtype={"visit": str})
    assert {"backlash_um", "backlash_low_um", "backlash_high_um", "operating_hours"} <= set(pred)
    assert len(printed["predictions"]) == len(pred)
    truth = sim.truth.groupby(["visit", "feed_mm_min", "dwell_s", "target"],
                              as_index=False)["true_backlash_um"].mean()
    both = pred.merge(truth, on=["visit", "feed_mm_min", "dwell_s", "target"])
    inner = both[(both["target"] > 0) & (both["target"] < 350)]  # the model saw interior only
    covered = ((inner["backlash_low_um"] <= inner["true_backlash_um"])
               & (inner["true_backlash_um"] <= inner["backlash_high_um"])).mean()
    assert covered >= 0.85
    assert ((inner["backlash_um"] - inner["true_backlash_um"]) ** 2).mean() ** 0.5 < 0.3


def test_network_given_a_plan_says_it_needs_the_deviations(campaign, tmp_path, capsys):
    folder, _ = campaign
    model = tmp_path / "n"
    assert main(["train", str(folder / "train.csv"), "--model", "ridge", "--out",
                 str(model)]) == 0
    capsys.readouterr()
    out = tmp_path / "p.csv"
    assert main(["predict", str(model), str(folder / "plan.csv"), "--out", str(out)]) == 2
    line = one_error_line(capsys)
    assert "deviation_" in line and "plan" in line
    assert not out.exists()


def test_single_visit_cannot_forecast_and_far_plans_warn(campaign, wear_model, tmp_path,
                                                          capsys):
    folder, _ = campaign
    model = tmp_path / "one"
    assert main(["train", str(folder / "one_visit.csv"), "--model", "wear-map", "--out",
                 str(model)]) == 0
    capsys.readouterr()
    out = tmp_path / "p.csv"
    assert main(["predict", str(model), str(folder / "plan.csv"), "--out", str(out)]) == 2
    assert "single visit" in one_error_line(capsys) and not out.exists()
    trained = wear_model
    far = pd.read_csv(folder / "plan.csv").assign(operating_hours=30000.0)
    far.to_csv(tmp_path / "far.csv", index=False)
    capsys.readouterr()
    assert main(["predict", str(trained), str(tmp_path / "far.csv"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: operating_hours" in err and "x the training span" in err


@pytest.mark.parametrize("change, words", [
    (lambda p: p.assign(target="left"), "is not a number"),
    (lambda p: p.assign(axis="Q"), "unknown axis"),
    (lambda p: p.assign(feed_mm_min=float("inf")), "infinite"),
    (lambda p: pd.concat([p, p.head(1)]), "same point twice"),
    (lambda p: p.assign(colour="red"), "unknown plan column"),
    (lambda p: p.drop(columns="operating_hours"), "operating_hours"),
])
def test_bad_plan_one_line_nothing_written(campaign, wear_model, tmp_path, capsys, change,
                                          words):
    folder, _ = campaign
    model = wear_model
    bad = change(pd.read_csv(folder / "plan.csv"))
    bad.to_csv(tmp_path / "bad.csv", index=False)
    capsys.readouterr()
    out = tmp_path / "p.csv"
    assert main(["predict", str(model), str(tmp_path / "bad.csv"), "--out", str(out)]) == 2
    line = one_error_line(capsys)
    assert words in line and "bad.csv" in line, line
    assert not out.exists()


def test_compare_backtest_table_and_wear_map(campaign, tmp_path, capsys):
    folder, _ = campaign
    out = tmp_path / "bt"
    assert main(["compare", str(folder / "all.csv"), "--split", "backtest", "--models",
                 "wear-map,constant", "--truth", str(folder / "truth.csv"), "--out", str(out),
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    models = {m["model"]: m for m in result["models"]}
    assert set(models) == {"wear-map", "constant", "persistence"}
    assert models["wear-map"]["truth_rmse_um"] < models["persistence"]["truth_rmse_um"]
    assert {"backtest.csv", "backtest_summary.csv", "wear_map.csv", "wear_map.png"} <= {
        p.name for p in out.iterdir()}
    assert len(result["origins"]) == 3 * 6  # origins 2..7, three predictors


def test_backtest_needs_several_visits(campaign, tmp_path, capsys):
    folder, _ = campaign
    assert main(["compare", str(folder / "one_visit.csv"), "--split", "backtest"]) == 2
    assert "at least 3 visits" in one_error_line(capsys)


def test_bootstrap_ensemble_gives_intervals_and_saves_its_members(tmp_path):
    import numpy as np
    from sklearn.linear_model import Ridge

    from features.table import feature_table
    from models.estimators.ensemble import BootstrapEnsemble
    from models.serving.persistence import load_estimator, save_estimator

    table = feature_table(simulate("demo", seed=2).readings)
    model = BootstrapEnsemble(Ridge(alpha=1.0), n_members=8).fit(table.X, table.y)
    mean, low, high = model.predict_interval(table.X)
    members = np.stack([m.predict(table.X) for m in model.members_])
    np.testing.assert_allclose(mean, members.mean(axis=0))
    assert np.all(low < mean) and np.all(mean < high)
    assert np.all(high - low > members.max(axis=0) - members.min(axis=0))  # t(7) x sd x 1.06
    spec = save_estimator(model, tmp_path, "estimator")
    template = BootstrapEnsemble(Ridge(alpha=1.0), n_members=8)
    back = load_estimator(tmp_path, spec, template)
    np.testing.assert_allclose(back.predict_interval(table.X)[1], low)
    spec_file = tmp_path / "estimator" / "ensemble.json"
    state = json.loads(spec_file.read_text())
    state["members"][0]["path"] = "../escape"
    spec_file.write_text(json.dumps(state))
    # a member path that leaves the folder is refused (the part's hash catches the edit first)
    with pytest.raises(InputError, match="outside the model directory|does not match its sha256"):
        load_estimator(tmp_path, spec, template)
