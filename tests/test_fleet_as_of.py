"""The fleet view as of a day (``--as-of``, default today): overdue visits and limits passed
since the last visit, unmeasured; the tests started later left out. Checked on the
independently written fleet (tests/independent_fleet.py), whose last visits are in 2026."""

from __future__ import annotations

import datetime as dt
import warnings

import pandas as pd
import pytest
from independent_fleet import fleet as independent

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.workflows.drift import drift
from pipeline.workflows.fleet import fleet, worst_first

LIMIT_UM = 5.0
LATE = dt.date(2026, 12, 31)  # months after the seventh visits (early July 2026)


@pytest.fixture(scope="module")
def readings():
    return bl.validate(independent(0, visits=7)[0])


def view_as_of(readings, day, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return fleet(readings, threshold_um=LIMIT_UM, as_of=day, **kwargs)


def test_overdue_and_limit_passed_unmeasured(readings):
    view = view_as_of(readings, LATE)
    data = view.to_dict()
    assert data["as_of"] == "2026-12-31"
    passed = 0
    for a in data["axes"]:
        due = dt.date.fromisoformat(a["next_visit_due"])
        late = (LATE - due).days
        assert ("overdue" in a["alerts"]) == (late > 0) and a["days_overdue"] == (
            late if late > 0 else None)
        if late > 0:
            message = a["alert_messages"][a["alerts"].index("overdue")]
            assert f"due on {due.isoformat()}" in message and f"{late} days overdue" in message
        crossed = a["crossing_date"] is not None and a["crossing_date"] < "2026-12-31"
        assert ("limit_passed_unmeasured" in a["alerts"]) == crossed, a["axis"]
        if crossed:
            passed += 1
            message = a["alert_messages"][a["alerts"].index("limit_passed_unmeasured")]
            assert f"reached the limit 5 um on {a['crossing_date']}" in message
    assert passed >= 1  # the case needs one
    # worst first: above the limit, then past it unmeasured, then other alerts
    groups = [worst_first(v)[0] for v in view.axes]
    assert groups == sorted(groups) and 1 in groups


def test_as_of_the_last_visits_nothing_is_overdue(readings):
    last = pd.to_datetime(readings["started_at"], utc=True).max().date()
    view = view_as_of(readings, last)
    for a in view.to_dict()["axes"]:
        assert "limit_passed_unmeasured" not in a["alerts"]
        if "overdue" in a["alerts"]:  # only an axis due before the fleet's last day
            assert a["next_visit_due"] < last.isoformat()


def test_a_view_as_of_an_earlier_day_leaves_the_later_tests_out(readings):
    """As of a day between the sixth and the seventh visits: the view that day."""
    day = dt.date(2026, 5, 1)
    with pytest.warns(BacklashWarning, match=r"test\(s\) started after 2026-05-01 left out"):
        view = fleet(readings, threshold_um=LIMIT_UM, as_of=day)
    before = readings[pd.to_datetime(readings["started_at"], utc=True).dt.date <= day]
    for a in view.to_dict()["axes"]:
        assert a["last_visit_date"] <= "2026-05-01"
        assert a["last_visit"] == str(before.loc[before["machine_id"] == a["machine_id"],
                                                 "visit"].astype(int).max())


def test_the_default_is_today(readings):
    today = dt.datetime.now(dt.UTC).date().isoformat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        assert fleet(readings, threshold_um=LIMIT_UM).to_dict()["as_of"] == today
        assert drift(readings).to_dict()["as_of"] == today


def test_drift_alerts_the_limit_passed_since_the_last_visit(readings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        late = drift(readings, threshold_um=LIMIT_UM, as_of=LATE)
        fleet_view = view_as_of(readings, LATE)
    passed = {(s.machine_id, s.axis) for s in late.series
              if "limit_passed_unmeasured" in [a["kind"] for a in s.alerts]}
    assert passed == {(v.machine_id, v.axis) for v in fleet_view.axes
                      if "limit_passed_unmeasured" in [a["kind"] for a in v.alerts]}


def test_the_pages_say_as_of_when(readings, tmp_path):
    view = view_as_of(readings, LATE, out=tmp_path / "site")
    index = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert "As of <strong>2026-12-31</strong>" in index and "overdue" in index
    for v in view.axes:
        page = (tmp_path / "site" / v.page).read_text(encoding="utf-8")
        assert "as of 2026-12-31" in page
    report = drift(readings, as_of=LATE).write(tmp_path / "drift")
    assert "As of 2026-12-31" in report["html"].read_text(encoding="utf-8")


@pytest.mark.parametrize("value", ["2026-02-30", "today", "2026/03/31", ""])
def test_a_bad_as_of_names_the_parameter(readings, value):
    with pytest.raises(InputError) as err:
        fleet(readings, as_of=value)
    assert err.value.parameter == "as_of" and "YYYY-MM-DD" in str(err.value)
