"""Drift monitoring against the twin's truth: a fleet with wear, an adjustment and a failure."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features.visits import DAYS_PER_MONTH, visit_backlash
from models.condition import drift
from models.physics.campaign import simulate

THRESHOLD_UM = 8.0


@pytest.fixture(scope="module")
def fleet():
    sim = simulate("drift", seed=1)
    return sim, drift.analyse_visits(visit_backlash(sim.readings), threshold_um=THRESHOLD_UM)


def true_series(sim, machine_id):
    truth = sim.truth[sim.truth["machine_id"] == machine_id]
    per_visit = truth.groupby("visit")["true_backlash_um"].mean()
    visits = sim.visits[sim.visits["machine_id"] == machine_id].set_index("visit")
    return visits.join(per_visit)


def test_detected_changes_are_the_true_adjustment_and_failure(fleet):
    sim, series = fleet
    assert len(series) == 3
    for s in series:
        visits = true_series(sim, s.machine_id)
        assert s.to_dict()["change_points"] == visits.index[visits["event"] != ""].tolist()


def test_slope_interval_and_crossing_interval_cover_the_truth(fleet):
    sim, series = fleet
    for s in series:
        j = s.to_dict()
        truth = true_series(sim, s.machine_id)
        last = truth.loc[j["change_points"][-1]:]
        months = (last["started_at"] - last["started_at"].iloc[0]).dt.days / DAYS_PER_MONTH
        slope, intercept = np.polyfit(months, last["true_backlash_um"], 1)
        low, high = j["slope_interval"]
        assert low <= slope <= high
        crossing = last["started_at"].iloc[0] + pd.Timedelta(
            days=(THRESHOLD_UM - intercept) / slope * DAYS_PER_MONTH)
        early, late = (pd.Timestamp(d) for d in j["crossing_interval"])
        assert early <= crossing <= late, (s.machine_id, crossing, early, late)


def test_stable_axis_raises_no_alert():
    stable = simulate({"system": "indirect", "plan": {"feeds_mm_min": [500.0], "dwells_s": [5.0],
                                                      "repeats": 1},
                       "fleet": {"visits": 10, "wear_um_per_1000h": 0.0}}, seed=2)
    (series,) = drift.analyse_visits(visit_backlash(stable.readings), threshold_um=THRESHOLD_UM)
    assert series.change_points == [] and series.alerts == []
