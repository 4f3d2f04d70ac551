"""The latest visit: a drop (an adjustment) or a jump at the last visit is a change point at
that visit, in ``drift``, ``fleet`` and the wear clock of ``train``; trend, crossing and next
visit then use only the visits since it. Checked on the independently written fleet
(tests/independent_fleet.py) seen at the visit that follows two machines' adjustment, on the
issue's hand-made series and on the twin's fleet preset."""

from __future__ import annotations

import datetime as dt
import re
import warnings

import numpy as np
import pandas as pd
import pytest
from independent_fleet import ADJUSTED_LAST
from independent_fleet import fleet as independent
from test_drift import visit_readings

import backlash as bl
from features.readings.errors import BacklashWarning
from features.readings.fileio import clean_nan
from features.visits import visit_backlash
from models.condition import drift
from models.wear.wear_map import found_adjustments
from pipeline.workflows.fleet import fleet

ADJUSTED = {"M2", "M4"}
THRESHOLD_UM = 6.0  # the trend through the drop called M2 crossing_soon at this limit


@pytest.fixture(scope="module")
def cut():
    """The independent fleet (5 machines, 10 axes) seen at visit 5, which follows the
    adjustment of M2 and M4; its readings, truth and the fleet view."""
    readings, truth, _ = independent(0, visits=5, machines=ADJUSTED_LAST)
    readings = bl.validate(readings)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        view = fleet(readings, threshold_um=THRESHOLD_UM, as_of=last_day(readings))
    return readings, truth, view


def last_day(readings) -> str:
    """The day of the last test: the view a team takes home from the visit."""
    return pd.to_datetime(readings["started_at"], utc=True).max().date().isoformat()


def true_level(truth: pd.DataFrame) -> pd.Series:
    """True lost motion per machine, axis and visit: the mean over the interior targets."""
    extent = truth.groupby(["machine_id", "axis"])["target"].transform
    inner = (truth["target"] > extent("min")) & (truth["target"] < extent("max"))
    return truth[inner].groupby(["machine_id", "axis", "visit"])["backlash_true_um"].mean()


def test_the_adjusted_axes_show_the_drop_at_the_last_visit(cut):
    _, truth, view = cut
    axes = {(a["machine_id"], a["axis"]): a for a in view.to_dict()["axes"]}
    assert len(axes) == 10
    true = true_level(truth)
    for (machine, axis), a in axes.items():
        last = dt.date.fromisoformat(a["last_visit_date"])
        level = true[(machine, axis, a["last_visit"])]
        assert abs(a["backlash_um"] - level) <= max(0.25, 0.08 * level), (machine, axis)
        if machine not in ADJUSTED:
            assert a["change_points"] == [], (machine, axis)
            assert not {"last_visit_drop", "last_visit_jump"} & set(a["alerts"])
            continue
        assert a["change_points"] == ["5"] and a["change_jumps_um"][0] < 0, (machine, axis)
        assert a["alerts"] == ["last_visit_drop"], (machine, axis)
        fell = a["history"]["backlash_um"][-2] - a["history"]["backlash_um"][-1]
        assert f"lost motion fell by {fell:.2f} um at visit 5" in a["alert_messages"][0]
        assert a["trend_since_visit"] == "5" and a["slope_um_per_month"] is None
        assert a["crossing_date"] is None and a["next_visit_reason"] != "above_threshold"
        assert dt.date.fromisoformat(a["next_visit_due"]) > last, (machine, axis)


def test_without_the_last_visit_the_trend_would_have_called_it_crossing_soon(cut):
    """What the view said before: the same axes with the drop read as part of the trend."""
    _, _, view = cut
    for v in view.axes:
        if v.machine_id in ADJUSTED:
            bent = drift.trend(v.series.visits["t_month"], v.series.visits["backlash_um"])
            assert bent["slope"] > 0  # a rising line through the drop: what misled the view


def test_one_visit_since_is_planned_with_the_fleets_wear_rate(cut):
    """The next visit of an axis just adjusted: the day its level plus the fleet's wear rate
    (the upper 90 % of the fleet's per-hour rates times the axis's own hours per day) reaches
    the limit, or the interval; the rate lies within the fleet's true rates at this axis's
    usage."""
    readings, truth, _ = cut
    threshold = 2.6  # near enough for the fleet rate to set some adjusted axes' next visit
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        view = fleet(readings, threshold_um=threshold, interval_days=120,
                     as_of=last_day(readings))
    hours = truth.groupby(["machine_id", "axis", "visit"])["operating_hours"].first()
    reasons = []
    for v in view.axes:
        a = v.to_dict()
        if v.machine_id not in ADJUSTED:
            assert a["fleet_wear_rate_per_month"] is None
            continue
        rate = a["fleet_wear_rate_per_month"] / 30.4375  # per day
        assert v.fleet_rate["basis"] == "operating hours"
        last = dt.date.fromisoformat(a["last_visit_date"])
        reach = pd.Timestamp(v.last["date"]) + pd.Timedelta(
            days=(threshold - a["backlash_um"]) / rate)
        expected = min(reach.date(), last + dt.timedelta(days=120))
        assert dt.date.fromisoformat(a["next_visit_due"]) == expected
        reasons.append(a["next_visit_reason"])
        # true wear rates of the fleet's other axes [um per h] at this machine's usage
        mine = hours.xs(v.machine_id, level="machine_id").groupby("visit").first()
        per_day = (mine.iloc[-1] - mine.iloc[0]) / (91.0 * (len(mine) - 1))
        rates = []
        for (m, ax), group in truth[~truth["machine_id"].isin(ADJUSTED)].groupby(
                ["machine_id", "axis"]):
            level = group.groupby("visit")[["backlash_true_um", "operating_hours"]].mean()
            rates.append(np.polyfit(level["operating_hours"], level["backlash_true_um"], 1)[0])
        assert min(rates) * per_day <= rate <= 1.5 * max(rates) * per_day
    assert "fleet_rate" in reasons


def test_the_issue_series_in_drift():
    """Lost motion 1.40, 2.49, 3.43, 4.74, then 1.41 um after an adjustment (the issue's
    series): a change point at visit 5, its alert, no trend, no crossing, no crossing_soon."""
    b = [1.40, 2.49, 3.43, 4.74, 1.41]
    readings = bl.validate(visit_readings(b, months=np.arange(5) * 3.0, noise_um=0.05))
    (s,) = drift.analyse_visits(visit_backlash(readings), threshold_um=5.0)
    j = clean_nan(s.to_dict())
    assert j["change_points"] == ["v05"]
    assert [a["kind"] for a in s.alerts] == ["last_visit_drop"]
    fell = float(re.search(r"lost motion fell by ([\d.]+) um at visit v05",
                           s.alerts[0]["message"]).group(1))
    assert fell == pytest.approx(4.74 - 1.41, abs=0.1)
    assert j["slope_um_per_month"] is None and j["threshold_crossing"] is None


def test_a_steady_last_visit_is_no_change():
    """Wear without a step: no change point at the last visit, whatever its noise (seeds)."""
    for seed in range(20):
        rng = np.random.default_rng(seed)
        t = np.arange(8) * 3.0 + rng.uniform(-0.5, 0.5, 8)
        y = 2.0 + 0.1 * t + rng.normal(0, 0.1, 8)
        assert drift.change_points(t, y, np.full(8, 0.1)) == [], seed


def test_the_wear_clock_restarts_at_the_last_visit(cut):
    readings, _, _ = cut
    steps = found_adjustments(visit_backlash(readings))
    assert set(zip(steps["machine_id"], steps["axis"], steps["visit"])) == {
        (m, a, "5") for m in ADJUSTED for a in ("X", "Y")}
    assert (steps["jump_um"] < 0).all()


def test_the_twin_fleet_preset_seen_at_its_adjustment():
    """The twin's fleet (adjustment at visit 5) cut at visit 5: every axis shows the drop at
    05, none is crossing_soon nor due on the day of its last visit."""
    sim = bl.simulate(preset="fleet", seed=0, config={"fleet": {
        "machines": 2, "axes": ["X", "Y"], "visits": 5, "adjust_at": [5]}})
    view = fleet(sim.readings, threshold_um=4.0, as_of=last_day(sim.readings))
    for a in view.to_dict()["axes"]:
        assert a["change_points"] == ["05"] and "last_visit_drop" in a["alerts"], a["axis"]
        assert "crossing_soon" not in a["alerts"]
        assert a["next_visit_due"] > a["last_visit_date"]


def test_the_site_of_the_cut_fleet(cut, tmp_path):
    _, _, view = cut
    files = view.write(tmp_path / "site")
    adjusted = next(v for v in view.axes if v.machine_id in ADJUSTED)
    page = files[adjusted.page].read_text(encoding="utf-8")
    assert "last_visit_drop: lost motion fell by" in page and "No trend" in page
