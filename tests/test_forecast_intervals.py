"""The forecast of the next visit states two intervals, the next measurement's and the axis's
lost motion's, says when the data cannot give one, and is the same from ``drift`` and
``fleet``. Their coverage on the twin's fleet and an independent fleet is in
tests/test_calibration.py."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
from independent_fleet import fleet as independent

import backlash as bl
from features.readings.errors import BacklashWarning
from models.condition.drift import DriftSeries, forecast_interval, forecast_terms
from pipeline.workflows.drift import drift
from pipeline.workflows.fleet import fleet

AS_OF = "2026-12-31"
KEYS = ("forecast_date", "forecast_um", "forecast_measurement_low_um",
        "forecast_measurement_high_um", "forecast_lost_motion_low_um",
        "forecast_lost_motion_high_um", "forecast_model_error_um", "forecast_backtests",
        "forecast_note")


def quiet(call, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return call(*args, **kwargs)


def test_a_known_line_and_scatter_are_covered_at_the_stated_rate():
    """Lines with a known slope, a visit-to-visit variation of the lost motion itself (0.05)
    and a laser repeatability (u = 0.03): the measurement interval holds the next measured
    value, the lost-motion interval the next true value, each about 95 % of 600 times."""
    rng = np.random.default_rng(12)
    t = np.arange(6.0)
    held_m, held_l = [], []
    for _ in range(600):
        true = 2.0 + 0.1 * np.arange(7.0) + rng.normal(0, 0.05, 7)
        measured = true + rng.normal(0, 0.03, 7)
        f = forecast_interval(t, measured[:6], np.full(6, 0.03), 6.0)
        held_m.append(f["measurement_low_um"] <= measured[6] <= f["measurement_high_um"])
        held_l.append(f["lost_motion_low_um"] <= true[6] <= f["lost_motion_high_um"])
    assert 0.92 <= np.mean(held_m) <= 0.98
    assert 0.92 <= np.mean(held_l) <= 0.99


def test_the_target_s_own_uncertainty_widens_only_the_lost_motion_interval():
    t, y = np.arange(5.0), 2.0 + 0.1 * np.arange(5.0) + np.array([0, .02, -.03, .01, 0])
    u = np.full(5, 0.03)
    plain = forecast_interval(t, y, u, 5.0)
    # without a budget the target states only its repeatability: one width, two meanings
    assert plain["lost_motion_high_um"] == pytest.approx(plain["measurement_high_um"])
    budget = forecast_interval(t, y, u, 5.0, target_u_um=np.full(5, 0.2))
    assert budget["measurement_high_um"] == pytest.approx(plain["measurement_high_um"])
    assert budget["lost_motion_high_um"] - budget["fit_um"] > 2 * 0.2


def test_backtests_find_the_model_error_of_wear_that_bends():
    """Ten axes of eight visits: on straight lines the backtests add nothing to speak of, on
    lines that bend (wear that speeds up) they add a model error."""
    rng = np.random.default_rng(3)

    def series(bend):
        out = []
        for k in range(10):
            t = np.arange(8.0)
            v = pd.DataFrame({"t_month": t, "visit": [str(i) for i in range(8)],
                              "backlash_um": 2 + 0.1 * t + bend * t ** 2
                              + rng.normal(0, 0.03, 8), "backlash_u_um": 0.03})
            out.append(DriftSeries("M", str(k), v))
        return out

    straight, bent = forecast_terms(series(0.0)), forecast_terms(series(0.02))
    assert straight.backtests == bent.backtests == 10 * 5
    assert straight.scatter_um == pytest.approx(0.03, rel=0.2)
    assert straight.model_error_um < 0.02 < bent.model_error_um


def test_two_visits_give_no_interval_and_say_why(tmp_path):
    two = bl.validate(independent(0, visits=2)[0])
    with pytest.warns(BacklashWarning, match="nor a forecast interval"):
        view = fleet(two, as_of=AS_OF, out=tmp_path / "site")
    for v in view.axes:
        a = v.to_dict()
        assert all(a[k] is None for k in KEYS if k not in ("forecast_note", "forecast_backtests"))
        assert "two visits since visit 1" in a["forecast_note"]
        page = (tmp_path / "site" / v.page).read_text(encoding="utf-8")
        assert "Forecast: none, two visits since visit 1" in page
    text = quiet(drift, two, as_of=AS_OF).write(tmp_path / "drift")["html"].read_text(
        encoding="utf-8")
    assert "the scatter between visits cannot be estimated" in text


@pytest.fixture(scope="module")
def five():
    """The independent fleet after its fifth visit: M4 adjusted at visit 4, M2 at visit 5 (one
    visit since: no interval), M5 not yet joined."""
    return bl.validate(independent(0, visits=5)[0])


def test_drift_and_fleet_give_every_axis_the_same_forecast(five, tmp_path):
    by_fleet = {(a["machine_id"], a["axis"]): a for a in quiet(
        fleet, five, threshold_um=6.0, as_of=AS_OF).to_dict()["axes"]}
    result = quiet(drift, five, threshold_um=6.0, as_of=AS_OF)
    stated = 0
    for s in result.to_dict()["series"]:
        a = by_fleet[(s["machine_id"], s["axis"])]
        assert s["slope_um_per_month"] == pytest.approx(a["slope_um_per_month"], abs=1e-4)
        assert s["change_points"] == a["change_points"]
        assert (s["threshold_crossing"], s["crossing_interval"]) == (a["crossing_date"],
                                                                     a["crossing_interval"])
        assert {k: s[k] for k in KEYS} == {k: a[k] for k in KEYS}
        if s["forecast_date"] is not None:
            stated += 1
            assert s["forecast_measurement_low_um"] < s["forecast_um"] \
                < s["forecast_measurement_high_um"]
            assert s["forecast_lost_motion_low_um"] < s["forecast_um"] \
                < s["forecast_lost_motion_high_um"]
    assert stated >= 4  # M1 and M3 (five visits); M2 just adjusted, M4 two visits since
    # an adjustment just before the last visit: one visit since it, no trend, no interval
    assert all("one visit since visit 5" in by_fleet[("M2", x)]["forecast_note"]
               for x in ("X", "Y"))
    # the page names the band it draws and the table both intervals
    text = result.write(tmp_path / "drift")["html"].read_text(encoding="utf-8")
    assert "forecast: measurement" in text and "forecast: lost motion" in text
