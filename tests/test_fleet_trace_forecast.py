"""The fleet's forecast with trace days: an axis whose store holds trace days sharing enough
days with its laser visits gets its trend, crossing and next visit from both (the traces
shifted onto the laser's definition), closer to the truth than from the laser visits alone; an
axis whose traces share too few days with the laser keeps the laser-only forecast, with a
note. Truth: laser visits of tests/independent_fleet.py, traces of tests/independent_traces.py
whose clearance follows the same wear line, plus a known wind-up."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from tests import independent_fleet, independent_traces

WIND_UP_UM = 1.5     # the trace reads the laser's backlash plus this
AHEAD_DAYS = 63      # trace days after the last laser visit, up to the view's day
MARGIN_DAYS = 150    # the truth crosses the threshold this long after the last laser visit


def _traces(axis: str, days: list[pd.Timestamp], clearance_um: list[float], seed: int):
    rng = np.random.default_rng(seed)
    t, cmd, motor, load = independent_traces.axis_days(rng, clearance_um, seconds=90.0)
    return pd.concat([pd.DataFrame({
        "time": day.normalize() + pd.Timedelta(hours=13) + pd.to_timedelta(t, unit="s"),
        "machine_id": "M1", "axis": axis, "commanded_mm": cmd[k], "motor_mm": motor[k],
        "load_mm": load[k]}) for k, day in enumerate(days)], ignore_index=True)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A store of M1's laser visits (X and Y, four visits); X's trace days every week from its
    first visit to ``AHEAD_DAYS`` after its last, on the wear line through the true levels;
    Y's on two of its visit days only. Returns the store, the view's day, the threshold and
    the true crossing date of X."""
    folder = tmp_path_factory.mktemp("trace_forecast")
    readings, truth, _ = independent_fleet.fleet(visits=4)
    readings, truth = (f[f["machine_id"] == "M1"] for f in (readings, truth))
    path = folder / "laser.csv"
    readings.to_csv(path, index=False)
    store = folder / "fleet"
    bl.ingest(path, store=store)
    level = truth.groupby(["axis", "visit"])["backlash_true_um"].mean()
    when = {a: pd.to_datetime(readings[readings["axis"] == a].groupby("visit")["started_at"]
                              .min()) for a in ("X", "Y")}
    # X's true wear: the line through its true levels against time
    t0 = when["X"].iloc[0]
    x_days = np.array([(when["X"][v] - t0).days for v in level["X"].index], float)
    slope, intercept = np.polyfit(x_days, level["X"].to_numpy(), 1)
    last = when["X"].iloc[-1]
    threshold = intercept + slope * ((last - t0).days + MARGIN_DAYS)
    days = sorted({*(when["X"][v] for v in level["X"].index),
                   *pd.date_range(t0 + pd.Timedelta(days=7), last + pd.Timedelta(
                       days=AHEAD_DAYS), freq="7D")})
    clearance = [intercept + slope * (d - t0).days + WIND_UP_UM for d in days]
    y_days = [when["Y"].iloc[1], when["Y"].iloc[2], when["Y"].iloc[2] + pd.Timedelta(days=30)]
    y_clear = [level["Y", "2"], level["Y", "3"], level["Y", "3"]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.monitor(pd.concat([_traces("X", days, clearance, 3),
                              _traces("Y", y_days, [c + WIND_UP_UM for c in y_clear], 4)]),
                   store=store)
    truth_cross = t0 + pd.Timedelta(days=(threshold - intercept) / slope)
    as_of = (last + pd.Timedelta(days=AHEAD_DAYS)).date().isoformat()
    return store, as_of, float(threshold), truth_cross.date()


def _axes(data, as_of, threshold):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        view = bl.fleet(data, as_of=as_of, threshold_um=threshold)
    return {v.axis: v.to_dict() for v in view.axes}, [str(w.message) for w in caught]


def _days(date: str, truth) -> int:
    return abs((pd.Timestamp(date).date() - truth).days)


def test_the_crossing_with_trace_days_is_closer_to_the_truth_than_the_laser_alone(case):
    store, as_of, threshold, truth = case
    both, _ = _axes(store, as_of, threshold)
    laser, _ = _axes(bl.read(store), as_of, threshold)
    x, plain = both["X"], laser["X"]
    assert x["forecast_uses"] == ["laser", "trace"] and plain["forecast_uses"] == ["laser"]
    off = x["forecast_offset_um"]["trace"]
    assert off["days_in_common"] == 4
    assert abs(off["value"] - WIND_UP_UM) <= 3 * off["u"] + 0.1, off
    assert x["crossing_date"] is not None and plain["crossing_date"] is not None
    error, error_laser = _days(x["crossing_date"], truth), _days(plain["crossing_date"], truth)
    early, late = (pd.Timestamp(d).date() for d in x["crossing_interval"])
    assert early <= truth <= late, (x["crossing_interval"], truth)  # honest
    width = (late - early).days
    plain_early, plain_late = plain["crossing_interval"]
    width_laser = ((pd.Timestamp(plain_late).date() - pd.Timestamp(plain_early).date()).days
                   if plain_late else np.inf)
    assert error < error_laser or width < width_laser, (error, error_laser, width, width_laser)
    assert error <= 30, (x["crossing_date"], truth)
    # the laser's measurements are listed as they are: the traces only move the forecast
    assert x["history"] == plain["history"] and x["backlash_um"] == plain["backlash_um"]


def test_an_axis_whose_traces_share_too_few_days_with_the_laser_keeps_its_laser_forecast(case):
    store, as_of, threshold, _ = case
    both, notes = _axes(store, as_of, threshold)
    laser, _ = _axes(bl.read(store), as_of, threshold)
    y = both["Y"]
    assert y["offsets_um"]["trace"]["days_in_common"] == 2
    assert y["forecast_uses"] == ["laser"] and y["forecast_offset_um"] is None
    for key in ("slope_um_per_month", "crossing_date", "crossing_interval", "change_points",
                "next_visit_due"):
        assert y[key] == laser["Y"][key], key
    assert any("M1 axis Y" in n and "share 2 day(s)" in n and "laser visits alone" in n
               for n in notes), notes


def test_the_axis_page_says_which_points_the_forecast_used(case, tmp_path):
    store, as_of, threshold, _ = case
    bl.fleet(store, as_of=as_of, threshold_um=threshold, out=tmp_path / "site")
    x_page = next((tmp_path / "site").glob("M1_X*.html")).read_text()
    y_page = next((tmp_path / "site").glob("M1_Y*.html")).read_text()
    assert "Trend and forecast from the laser visits and the trace days" in x_page
    assert "day(s) in common), weighted by their uncertainty" in x_page
    assert "Trend and forecast from the laser visits." in y_page


def test_drift_leaves_out_trace_days_sharing_too_few_days_with_the_laser(case):
    """One rule for drift and the fleet: the axis whose traces share 2 days with the laser
    keeps the laser's series in ``drift --evidence laser,trace`` too, with the note; the axis
    sharing more gets its trace days."""
    store, as_of, _, _ = case
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        both = bl.drift(store, as_of=as_of, evidence="laser,trace", track=False).to_dict()
        laser = bl.drift(store, as_of=as_of, track=False).to_dict()
    notes = [str(w.message) for w in caught]
    series = {s["axis"]: s for s in both["series"]}
    plain = {s["axis"]: s for s in laser["series"]}
    assert set(series["Y"].get("source", ["laser"])) == {"laser"}
    assert set(series["X"]["source"]) == {"laser", "trace"}
    assert series["Y"]["backlash_um"] == plain["Y"]["backlash_um"]
    assert any("M1 axis Y" in n and "share 2 day(s)" in n for n in notes), notes
