"""One maintenance analysis per machine axis (``models.condition``), shared by ``drift`` and
``fleet``: both say the same of every axis of a fleet (its series, slope and interval, change
points, crossing and interval, the forecast of its next visit with both intervals), on machines
with linear and rotary axes; the analysis's one time axis; the schedule's rules on hand-made
numbers; the settings defined once."""

from __future__ import annotations

import datetime as dt
import inspect
import warnings
from dataclasses import astuple

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from independent_fleet import fleet as independent
from test_drift import visit_readings

import backlash as bl
from features.readings.errors import BacklashWarning
from features.visits import DAYS_PER_MONTH
from models.condition import schedule
from models.condition.maintenance import analyse_axes, at_month
from models.condition.settings import DEFAULT_INTERVAL_DAYS, DEFAULTS, MaintenanceSettings
from pipeline.workflows.drift import drift
from pipeline.workflows.fleet import fleet

# what both views must agree on, per axis: the JSON keys of the series and its forecast
SAME = ("change_points", "change_jumps_um", "threshold_um",
        "crossing_interval", "forecast_date", "forecast_um", "forecast_measurement_low_um",
        "forecast_measurement_high_um", "forecast_lost_motion_low_um",
        "forecast_lost_motion_high_um", "forecast_model_error_um", "forecast_backtests",
        "forecast_note", "forecast_lost_motion_reference", "forecast_lost_motion_note")


def quiet(function, readings, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return function(readings, **kwargs)


def last_day(readings) -> str:
    return pd.to_datetime(readings["started_at"], utc=True).max().date().isoformat()


def assert_the_same(readings, **limits):
    """``drift`` and ``fleet`` of ``readings`` say the same of every axis with two visits or
    more (``fleet`` also lists the axes with one)."""
    day = last_day(readings)
    found = quiet(drift, readings, as_of=day, **limits)
    view = quiet(fleet, readings, as_of=day, **limits)
    by_drift = {(f.machine_id, f.axis): f for f in found.forecasts}
    by_fleet = {(v.machine_id, v.axis): v for v in view.axes}
    assert set(by_drift) == {k for k, v in by_fleet.items() if len(v.series.visits) >= 2}
    assert len({k[0] for k in by_drift}) >= 2
    for key, d in by_drift.items():
        v = by_fleet[key]
        f = v.forecast
        for column in ("visit", "date", "backlash_um", "backlash_u_um", "sigma_um", "t_month"):
            pd.testing.assert_series_equal(d.series.visits[column], f.series.visits[column],
                                           check_exact=True)
        assert sorted(d.series.trend) == sorted(f.series.trend)
        np.testing.assert_array_equal([d.series.trend[k] for k in sorted(d.series.trend)],
                                      [f.series.trend[k] for k in sorted(f.series.trend)])
        assert d.series.change_points == f.series.change_points, key
        assert d.crossing == f.crossing and d.next_visit == f.next_visit, key
        np.testing.assert_equal(astuple(d.series.terms), astuple(f.series.terms))
        dj, fj = d.to_dict(), v.to_dict()
        for name in SAME:
            assert dj[name] == fj[name], (key, name)
        assert dj["threshold_crossing"] == fj["crossing_date"]
        assert dj["visits"] == fj["history"]["visits"]
        slope = dj["slope_um_per_month"]
        assert fj["slope_um_per_month"] == (None if not np.isfinite(slope) else round(slope, 4))
        # the bands start at the last visit with the same numbers, whatever their horizons
        if d.band is not None:
            assert d.band["at"][0] == f.band["at"][0]
            for name in ("fit_um", "measurement_low_um", "measurement_high_um",
                         "lost_motion_low_um", "lost_motion_high_um"):
                assert d.band[name][0] == f.band[name][0], (key, name)
        else:
            assert f.band is None
    return by_drift


@pytest.fixture(scope="module")
def mixed():
    """Five machines with an X axis (um) and a C axis (arcsec), six visits, two of the machines
    adjusted; one machine joins late with a single visit."""
    linear = independent(0, visits=6)[0]
    rotary = independent(0, visits=6, rotary=True)[0]
    return bl.validate(pd.concat([linear[linear["axis"] == "X"], rotary[rotary["axis"] == "C"]],
                                 ignore_index=True))


def test_drift_and_fleet_say_the_same_of_every_linear_and_rotary_axis(mixed):
    found = assert_the_same(mixed, threshold_um=6.0, threshold_arcsec=60.0)
    assert {k[1] for k in found} == {"X", "C"}
    assert any(f.series.change_points for f in found.values())  # the adjustments
    assert any(f.crossing[0] is not None for f in found.values())
    assert any(f.band is not None for f in found.values())


@settings(max_examples=6, deadline=None)
@given(data=st.data())
def test_drift_and_fleet_say_the_same_of_any_small_fleet(data):
    """Two or three machines, each with a linear axis X [um] and a rotary axis C [arcsec]:
    visits a month or two apart, a trend, the scatter of the laser, a step at some visit."""
    machines = data.draw(st.integers(2, 3), label="machines")
    frames = []
    for m in range(machines):
        for axis, level, scale in (("X", 2.0, 1.0), ("C", 20.0, 10.0)):
            n = data.draw(st.integers(2, 8), label=f"visits M{m} {axis}")
            gaps = data.draw(st.lists(st.floats(0.7, 2.5), min_size=n - 1, max_size=n - 1),
                             label="months between visits")
            slope = data.draw(st.floats(0.0, 0.3), label="slope per month") * scale
            step = data.draw(st.integers(0, n), label="step at visit")  # n: none
            months = np.concatenate([[0.0], np.cumsum(gaps)])
            b = level + slope * months - np.where(np.arange(n) >= step, 1.5 * scale, 0.0)
            frames.append(visit_readings(np.maximum(b, 0.5 * scale), machine=f"M{m + 1}",
                                         axis=axis, months=months, seed=m, noise_um=0.1 * scale))
    readings = bl.validate(pd.concat(frames, ignore_index=True))
    assert_the_same(readings, threshold_um=3.0, threshold_arcsec=30.0)


# --------------------------------------------------------------------------- one time axis
def test_the_time_axis_is_the_visits_dates_and_the_crossing_their_day():
    rng = np.random.default_rng(1)
    months = np.array([0.0, 1.3, 2.1, 3.8, 5.0, 6.4])
    visits = pd.DataFrame({
        "machine_id": "M1", "axis": "X", "visit": [str(i) for i in range(6)],
        "date": pd.Timestamp("2025-03-04T09:30", tz="UTC")
        + pd.to_timedelta(months * DAYS_PER_MONTH, "D"),
        "backlash_um": 2.0 + 0.2 * months + rng.normal(0, 0.02, 6), "backlash_u_um": 0.02})
    (f,) = analyse_axes(visits, MaintenanceSettings(threshold_um=4.0))
    at = at_month(f.series, f.series.visits["t_month"].to_numpy())
    assert np.abs((at - pd.DatetimeIndex(visits["date"])).total_seconds()).max() < 1e-3
    assert f.day(f.crossing[0]) == f.series.date_at(f.series.crossing[0])
    assert f.band["at"][0] == at[-1] and f.band["at"][-1] == f.horizon_end
    assert f.trend_line["at"][-1] == f.horizon_end
    # without an interval (drift): the band reaches the end of the crossing interval
    assert f.crossing[2] is not None and f.horizon_end == f.crossing[2]
    # with one (fleet): one interval past the last visit, or up to the crossing date, never
    # more than the cap past the last visit
    last = visits["date"].iloc[-1]
    for days, cap in ((30.0, 24.0), (30.0, 1.0), (900.0, 24.0)):
        (g,) = analyse_axes(visits, MaintenanceSettings(threshold_um=4.0, interval_days=days,
                                                        forecast_cap_months=cap))
        expected = max(last + pd.Timedelta(days=days),
                       min(g.crossing[0], last + pd.Timedelta(days=cap * DAYS_PER_MONTH)))
        assert abs((g.horizon_end - expected).total_seconds()) < 1e-3, (days, cap)
        assert g.crossing == f.crossing and g.next_visit == f.next_visit


# --------------------------------------------------------------------------- the schedule
LAST = pd.Timestamp("2026-03-01T10:00", tz="UTC")


def test_next_visit_due_rules():
    due = schedule.next_visit_due
    assert due(LAST, 5.0, 4.0, 90) == (dt.date(2026, 3, 1), "above_threshold")
    assert due(LAST, 2.0, None, 90) == (dt.date(2026, 5, 30), "interval")
    # one visit since the last change: the level plus the planned rate reaches the limit
    rate = {"per_day": 0.05, "basis": "calendar"}
    assert due(LAST, 2.0, 4.0, 90, rate=rate) == (dt.date(2026, 4, 10), "fleet_rate")
    assert due(LAST, 2.0, 4.0, 30, rate=rate) == (dt.date(2026, 3, 31), "interval")
    # a planned rate near zero: the limit lies past any calendar, the interval rules
    slow = {"per_day": 1e-12, "basis": "calendar"}
    assert due(LAST, 2.0, 4.0, 90, rate=slow) == (dt.date(2026, 5, 30), "interval")
    # the early end of the crossing interval, never before the last visit
    crossing = (LAST + pd.Timedelta(days=50), LAST + pd.Timedelta(days=20), None)
    assert due(LAST, 2.0, 4.0, 90, crossing=crossing) == (dt.date(2026, 3, 21), "crossing")
    early = (LAST + pd.Timedelta(days=50), LAST - pd.Timedelta(days=3), None)
    assert due(LAST, 2.0, 4.0, 90, crossing=early) == (dt.date(2026, 3, 1), "crossing")
    assert due(LAST, 2.0, 4.0, 90, crossing=(crossing[0], None, None))[1] == "crossing"


def test_worst_first_compares_crossing_dates_not_days_since_each_axis_s_first_visit():
    """Two axes due the same day: the one crossing first comes first, whatever the day each
    was first measured (the days since each axis's first visit do not compare)."""
    due = dt.date(2026, 6, 1)
    soon = schedule.priority(["crossing_soon"], due, pd.Timestamp("2026-07-01", tz="UTC"), 2.0,
                             "M2", "X")
    later = schedule.priority(["crossing_soon"], due, pd.Timestamp("2026-09-01", tz="UTC"), 3.0,
                              "M1", "X")
    never = schedule.priority(["crossing_soon"], due, None, 9.0, "M0", "X")
    assert sorted([never, later, soon]) == [soon, later, never]
    above = schedule.priority(["above_threshold"], dt.date(2027, 1, 1), None, 1.0, "M9", "Z")
    assert min(above, soon) == above


def test_a_forecast_for_operating_hours_gets_the_day_the_counter_reaches_them():
    dates = pd.Series(pd.to_datetime(["2026-01-01", "2026-01-31", "2026-03-02"], utc=True))
    when = schedule.date_at_hours(dates, [100.0, 340.0, 580.0], 820.0)
    assert abs((when - pd.Timestamp("2026-04-01", tz="UTC")).total_seconds()) < 1.0
    assert schedule.date_at_hours(dates, [100.0, np.nan, np.nan], 820.0) is None
    assert schedule.date_at_hours(dates, [300.0, 200.0, 100.0], 820.0) is None


def test_the_fleet_wear_rate_is_a_high_quantile_of_the_axes_rates():
    months = np.arange(4.0)
    rows = []
    for k, slope in enumerate((0.1, 0.2, 0.3, 0.4, -0.1)):
        rows.append(pd.DataFrame({
            "machine_id": f"M{k}", "axis": "X", "visit": [str(i) for i in range(4)],
            "date": pd.Timestamp("2026-01-01", tz="UTC")
            + pd.to_timedelta(months * DAYS_PER_MONTH, "D"),
            "backlash_um": 2.0 + slope * months, "backlash_u_um": 0.01}))
    series = [f.series for f in analyse_axes(pd.concat(rows, ignore_index=True))]
    rates = schedule.fleet_wear_rates(series)
    assert rates["um"]["per_hour"] is None
    assert rates["um"]["per_month"] == pytest.approx(np.quantile([0.1, 0.2, 0.3, 0.4, 0.0],
                                                                 schedule.FLEET_RATE_QUANTILE))
    one = series[0].__class__("M9", "X", series[0].visits.iloc[:1].copy())
    assert schedule.planned_rate(one, rates)["basis"] == "calendar"
    assert schedule.planned_rate(series[0], rates) is None  # a trend of its own


# --------------------------------------------------------------------------- defined once
def test_the_shared_settings_and_their_defaults_are_defined_once():
    from models.condition.drift import analyse_series
    from pipeline.steps.parameters import MAINTENANCE
    from pipeline.workflows import drift as drift_module
    from pipeline.workflows import fleet as fleet_module

    for module in (drift_module, fleet_module):
        table = module.PARAMETERS
        assert all(table[name] is param for name, param in MAINTENANCE.items())
    for function in (drift, fleet, analyse_series):
        signature = inspect.signature(function).parameters
        for name in ("alpha", "min_jump_sigma", "warn_months"):
            assert signature[name].default == getattr(DEFAULTS, name), (function, name)
    assert inspect.signature(fleet).parameters["interval_days"].default == DEFAULT_INTERVAL_DAYS
    assert inspect.signature(analyse_series).parameters["horizon_months"].default == \
        DEFAULTS.crossing_horizon_months


def test_a_line_too_flat_to_reach_the_limit_in_a_century_has_no_crossing_date(tmp_path):
    """A nearly flat trend (a tiny positive Theil-Sen slope) once put its crossing centuries
    ahead, past the last date pandas holds: drift and fleet stopped with OutOfBoundsTimedelta.
    Its crossing date is null, as a line not growing."""
    from models.condition.drift import MAX_CROSSING_MONTHS, crossing_forecast

    t, y = np.arange(5.0), np.array([2.0, 2.1, 1.9, 2.0, 2.0])
    assert crossing_forecast(t, y, 0.1, 3.0, slope=1e-9, intercept=2.0)[0] is None
    slope = 1.0 / (MAX_CROSSING_MONTHS - 10.0)  # within the century: a date
    assert crossing_forecast(t, y, 0.1, 3.0, slope=slope, intercept=2.0)[0] is not None
    b = 2.0 + 1e-7 * np.arange(6.0)
    readings = bl.validate(pd.concat([visit_readings(b, machine=m, noise_um=0.0)
                                      for m in ("M1", "M2")], ignore_index=True))
    found = assert_the_same(readings, threshold_um=3.0)
    assert all(f.crossing[0] is None for f in found.values())
