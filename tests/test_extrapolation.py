"""Predictions outside the training ranges are flagged per input: a note naming the input and
its trained range, and the ``extrapolated`` column; plans given as frames are checked like plan
files."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main

DATA = Path(__file__).parents[1] / "experiments" / "data"
PLAN = DATA / "plan_next_visit.csv"  # the demo twin's next visit: feeds 200-1200, targets 50-300


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A wear map trained on the demo twin (feeds 200-1200 mm/min, targets 50-300 mm, hours
    0-2700), saved without MLflow."""
    from features.readings import read_readings
    from features.table import feature_table
    from models.estimators.training import fit_model
    from models.serving.registry import save_model

    table = feature_table(read_readings(DATA / "twin" / "readings.csv"))
    fit = fit_model(table, "wear-map", "random", 0)
    return save_model(fit.trained_model(), tmp_path_factory.mktemp("model") / "wear-map")


def predicted(model, plan):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = bl.predict(model, plan=plan)
    return result, [str(w.message) for w in caught if issubclass(w.category, BacklashWarning)]


def test_the_trained_ranges_are_those_of_the_training_data(model):
    from models.serving.registry import load_model

    ranges = load_model(model).input_ranges_
    readings = pd.read_csv(DATA / "twin" / "readings.csv")
    assert ranges["feed_mm_min"] == (readings["feed_mm_min"].min(),
                                     readings["feed_mm_min"].max()) == (200.0, 1200.0)
    assert ranges["target"] == (50.0, 300.0)


def test_a_plan_inside_the_ranges_has_no_note_and_empty_flags(model):
    plan = pd.read_csv(PLAN)
    inside = plan.assign(operating_hours=2700.0)  # the last trained hour
    result, notes = predicted(model, inside)
    assert notes == [] and result.notes == []
    assert (result.predictions["extrapolated"] == "").all()


def test_twenty_times_the_trained_feeds_names_feed_and_its_range(model):
    plan = pd.read_csv(PLAN).assign(operating_hours=2700.0)
    fast = plan.assign(feed_mm_min=plan["feed_mm_min"] * 20)  # 4000-24000 mm/min
    fast.loc[0, "target"] = 5000.0
    result, notes = predicted(model, fast)
    feed = [n for n in notes if n.startswith("feed_mm_min")]
    assert len(feed) == 1 and "4000 to 24000" in feed[0]
    assert f"{len(plan)} of {len(plan)} points" in feed[0] and "200 to 1200" in feed[0]
    target = [n for n in notes if n.startswith("target")]
    assert len(target) == 1 and "5000 at 1 of" in target[0] and "50 to 300" in target[0]
    flags = result.predictions["extrapolated"]
    assert flags.iloc[0] == "feed_mm_min;target"
    assert (flags.iloc[1:] == "feed_mm_min").all()
    assert result.notes == notes


def test_a_feed_just_outside_flags_only_those_points(model):
    plan = pd.read_csv(PLAN).assign(operating_hours=2700.0)
    plan.loc[[2, 5], "feed_mm_min"] = [1200.5, 199.0]
    result, notes = predicted(model, plan)
    flagged = np.flatnonzero(result.predictions["extrapolated"] == "feed_mm_min")
    assert flagged.tolist() == [2, 5] and (result.predictions["extrapolated"]
                                           .drop(index=[2, 5]) == "").all()
    assert notes == [("feed_mm_min 199 to 1200.5 at 2 of 18 points is outside the trained "
                      "range 200 to 1200: the prediction extrapolates there")]


def test_the_wear_maps_hours_are_flagged_beyond_its_forecast_horizon_only(model):
    # trained 0-2700 h: the horizon reaches 2700 + 1.5 x 2700 = 6750 h
    plan = pd.read_csv(PLAN)
    near, _ = predicted(model, plan.assign(operating_hours=6700.0))
    assert (near.predictions["extrapolated"] == "").all()
    far, notes = predicted(model, plan.assign(operating_hours=6800.0))
    assert (far.predictions["extrapolated"] == "operating_hours").all()
    # (6800 - 2700) / 2700 = 1.5x the span beyond its end
    assert notes == far.notes == [("operating_hours up to 6800 h is 1.5x the training span "
                                   "(0-2700 h) beyond its end; the forecast extrapolates the "
                                   "wear rate that far")]


def test_the_cli_prints_the_note_and_writes_the_column(model, tmp_path, capsys):
    plan = pd.read_csv(PLAN).assign(operating_hours=2700.0)
    plan.assign(feed_mm_min=plan["feed_mm_min"] * 20).to_csv(tmp_path / "fast.csv", index=False)
    out = tmp_path / "p.csv"
    assert main(["predict", str(model), str(tmp_path / "fast.csv"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: feed_mm_min 4000 to 24000 at 18 of 18 points is outside the trained range " \
           "200 to 1200" in err
    assert (pd.read_csv(out)["extrapolated"] == "feed_mm_min").all()


@pytest.mark.parametrize("change, words", [
    (lambda p: p.assign(operating_hours=-480.0), "-480 is not operating hours >= 0"),
    (lambda p: p.assign(axis="Q"), "unknown axis 'Q'"),
    (lambda p: p.assign(feed_mm_min=np.inf), "infinite value"),
])
def test_a_plan_frame_is_checked_like_a_plan_file(model, change, words):
    plan = change(pd.read_csv(PLAN))
    with pytest.raises(InputError, match="^plan, row 1, column") as err:
        bl.predict(model, plan=plan)
    assert words in str(err.value)
