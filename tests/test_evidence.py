"""Trace days and ballbar runs in the fleet store beside the laser visits: recorded by
``monitor --store`` and ``circle --store`` on both engines (once, checked, all or nothing),
shown by ``fleet`` with their offsets to the laser's backlash, and joined to the laser series
by ``drift --evidence``; checked against the truth of independent generators (laser visits:
tests/independent_fleet.py, traces: tests/independent_traces.py, ballbar runs:
tests/independent_circle.py) with known offsets between the definitions."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest
from store_files import cli, engine_location, refused, visits

import backlash as bl
from features.readings.errors import InputError
from models.condition.evidence import offset, pairs
from pipeline.store.records import RECORD_FORMAT, check_ballbar, check_trace, read_records
from tests import independent_circle, independent_fleet, independent_traces

WIND_UP_UM = 1.5      # the trace's lost motion holds elastic wind-up the laser does not see
BALLBAR_UM = 2.0      # the ballbar's fitted step reads the play plus this
ADJUST_DROP_UM = 3.0  # an adjustment after the last laser visit: only the traces see it
ADJUST_AFTER = 5      # trace days after the last visit before it


# --------------------------------------------------------------------- known truth
def _traces(days: list[pd.Timestamp], clearance_um: list[float], seed: int = 3) -> pd.DataFrame:
    """Dual-feedback traces of M1 X on ``days``, one clearance [um] each (30 s a day)."""
    rng = np.random.default_rng(seed)
    t, cmd, motor, load = independent_traces.axis_days(rng, clearance_um, seconds=90.0)
    return pd.concat([pd.DataFrame({
        "time": day.normalize() + pd.Timedelta(hours=13) + pd.to_timedelta(t, unit="s"),
        "machine_id": "M1", "axis": "X", "commanded_mm": cmd[k], "motor_mm": motor[k],
        "load_mm": load[k]}) for k, day in enumerate(days)], ignore_index=True)


def _ballbar(days: list[pd.Timestamp], plays: list[tuple], seed: int = 5) -> pd.DataFrame:
    """CW and CCW ballbar runs of M1 XY on ``days``, the play (X, Y) [um] of each."""
    rng = np.random.default_rng(seed)
    frames = []
    for k, (day, play) in enumerate(zip(days, plays)):
        truth = independent_circle.Truth("M1", play, (1.5, 1.0), 2.5, 10.0, (5.0, -5.0),
                                         (0.5, 0.3), (10.0, -8.0))
        for direction in ("CW", "CCW"):
            run = independent_circle.ballbar_run(truth, direction, rng=rng)
            frames.append(run.assign(
                test_id=f"M1-{k}-{direction}", machine_id="M1", plane="XY",
                direction=direction, radius_mm=150.0, feed_mm_min=1000.0, visit=f"b{k}",
                started_at=(day.normalize() + pd.Timedelta(hours=10)).isoformat()))
    return pd.concat(frames, ignore_index=True)


@pytest.fixture(scope="module")
def evidence(tmp_path_factory):
    """A store of M1's laser visits (X and Y, six visits), trace days of X on every visit day
    and after the last one (adjusted ``ADJUST_AFTER`` days after it), ballbar runs on visits
    2, 4 and 6; returns the store and the truth."""
    folder = tmp_path_factory.mktemp("evidence")
    readings, truth, _ = independent_fleet.fleet(visits=6)
    readings = readings[readings["machine_id"] == "M1"]
    truth = truth[truth["machine_id"] == "M1"]
    path = folder / "laser.csv"
    readings.to_csv(path, index=False)
    store = folder / "fleet"
    bl.ingest(path, store=store)
    level = truth.groupby(["axis", "visit"])["backlash_true_um"].mean()
    when = pd.to_datetime(readings[readings["axis"] == "X"].groupby("visit")["started_at"].min())
    visits_ = [str(v) for v in range(1, 7)]
    last = when[visits_[-1]]
    after = [last + pd.Timedelta(days=d) for d in range(1, 11)]
    adjusted = last.normalize() + pd.Timedelta(days=ADJUST_AFTER + 1)
    wear = 0.0  # ten days of wear are negligible beside the step
    clearance = ([level["X", v] + WIND_UP_UM for v in visits_]
                 + [level["X", visits_[-1]] + WIND_UP_UM + wear
                    - (ADJUST_DROP_UM if d >= adjusted else 0.0) for d in after])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.monitor(_traces([when[v] for v in visits_] + after, clearance), store=store)
    # on X's visit days, within a few days of Y's (its wear in between is negligible)
    plays = [(level["X", v] + BALLBAR_UM, level["Y", v] + BALLBAR_UM) for v in ("2", "4", "6")]
    frame = _ballbar([when[v] for v in ("2", "4", "6")], plays)
    bl.circle(frame, store=store)
    return store, {"adjusted": adjusted.date().isoformat(), "last": last.date().isoformat()}


def test_the_offsets_to_the_laser_are_the_known_ones_within_their_uncertainty(evidence):
    store, truth = evidence
    view = bl.fleet(store, as_of="2026-12-31")
    axes = {v.axis: v.to_dict() for v in view.axes}
    x, y = axes["X"], axes["Y"]
    trace = x["offsets_um"]["trace"]
    assert trace["days_in_common"] == 6
    assert abs(trace["value"] - WIND_UP_UM) <= 3 * trace["u"] and trace["u"] < 0.3, trace
    for axis in (x, y):
        ballbar = axis["offsets_um"]["ballbar"]
        assert ballbar["days_in_common"] == 3
        assert abs(ballbar["value"] - BALLBAR_UM) <= 3 * ballbar["u"], ballbar
    assert y["offsets_um"]["trace"] is None and y["evidence"]["trace"] == []
    assert len(x["evidence"]["trace"]) == 16 and len(x["evidence"]["ballbar"]) == 3
    assert {p["plane"] for p in x["evidence"]["ballbar"]} == {"XY"}
    # the laser's own keys are those of a fleet without evidence; X's analysis (trend, change
    # points, forecast) uses its trace days too, Y's (no trace) the laser alone
    plain = {v.axis: v.to_dict() for v in bl.fleet(bl.read(store), as_of="2026-12-31").axes}
    for key in ("backlash_um", "history", "visits", "last_visit"):
        assert x[key] == plain["X"][key]
    assert y == {**plain["Y"], "offsets_um": y["offsets_um"], "evidence": y["evidence"],
                 "page": y["page"]}
    assert plain["X"]["offsets_um"] == {"trace": None, "ballbar": None}
    assert plain["X"]["forecast_uses"] == y["forecast_uses"] == ["laser"]
    assert x["forecast_uses"] == ["laser", "trace"]
    assert x["forecast_offset_um"] == {"trace": trace} and y["forecast_offset_um"] is None
    assert plain["X"]["change_points"] == [] and x["change_points"] == [
        f"trace {truth['adjusted']}"]


def test_drift_with_the_traces_dates_an_adjustment_the_laser_never_saw(evidence):
    store, truth = evidence
    laser = bl.drift(store, as_of="2026-12-31")
    x = next(s for s in laser.to_dict()["series"] if s["axis"] == "X")
    assert x["change_points"] == [] and set(x.get("source", ["laser"])) == {"laser"}
    combined = bl.drift(store, as_of="2026-12-31", evidence="laser,trace")
    j = combined.to_dict()
    x = next(s for s in j["series"] if s["axis"] == "X")
    assert x["change_points"] == [f"trace {truth['adjusted']}"], x["change_points"]
    assert x["change_jumps_um"][0] == pytest.approx(-ADJUST_DROP_UM, abs=0.5)
    assert x["source"].count("laser") == 6 and x["source"].count("trace") == 16
    assert "ballbar" not in x["source"] and j["evidence"] == "laser,trace"
    # each shifted point reads the laser's definition: the traces on visit days agree
    points = pd.DataFrame({"date": x["dates"], "y": x["backlash_um"], "source": x["source"]})
    points["day"] = points["date"].str[:10]
    both = points.pivot_table(index="day", columns="source", values="y").dropna()
    assert len(both) == 6 and (both["trace"] - both["laser"]).abs().max() < 0.5


def test_drift_uses_all_three_sources(evidence, tmp_path):
    store, _ = evidence
    result = bl.drift(store, as_of="2026-12-31", evidence="all")
    y = next(s for s in result.to_dict()["series"] if s["axis"] == "Y")
    assert y["source"].count("ballbar") == 3 and y["offsets_um"]["trace"] is None
    files = result.write(tmp_path / "report")
    assert "ballbar" in files["html"].read_text()


def test_fleet_pages_draw_the_evidence_with_a_legend(evidence, tmp_path):
    store, _ = evidence
    bl.fleet(store, as_of="2026-12-31", out=tmp_path / "site")
    page = next((tmp_path / "site").glob("M1_X*.html")).read_text()
    assert "trace lost motion per day (offset +" in page and "ballbar backlash (offset +" in page
    assert page.count("<polygon") >= 16 + 3 + 2  # the points and their legend keys
    site = json.loads((tmp_path / "site" / "fleet.json").read_text())
    assert {a["axis"]: a["offsets_um"]["trace"] is not None for a in site["axes"]} == {
        "X": True, "Y": False}


# --------------------------------------------------------------------- the estimator
def test_pairs_take_the_nearest_once_within_the_window():
    assert pairs(np.array([0.0, 10.0, 100.0]), np.array([1.0, 2.0, 9.0, 50.0])) == [
        (0, 0), (1, 2)]
    assert pairs(np.array([0.0]), np.array([8.0])) == []


def test_offset_is_the_weighted_mean_with_the_birge_ratio():
    day = pd.Timestamp("2026-01-01", tz="UTC")
    laser = pd.DataFrame({"date": [day, day + pd.Timedelta(days=90)], "value_um": [2.0, 3.0],
                          "u_um": [0.0, 0.0]})
    other = laser.assign(value_um=[3.0, 5.0], u_um=[0.5, 1.0])
    found = offset(laser, other)
    w = np.array([4.0, 1.0])  # 1/u^2
    value = (4.0 * 1.0 + 1.0 * 2.0) / 5.0
    birge = np.sqrt(np.sum(w * (np.array([1.0, 2.0]) - value) ** 2))
    assert found["value"] == pytest.approx(value)
    assert found["u"] == pytest.approx(max(birge, 1.0) / np.sqrt(5.0))
    assert offset(laser, other.assign(date=other["date"] + pd.Timedelta(days=30))) is None


# --------------------------------------------------------------------- records, both engines
@pytest.fixture(params=["folder", pytest.param("postgres", marks=pytest.mark.postgres)])
def store(request, tmp_path) -> str:
    """A store of each engine holding visits 01-02 of the twin's M01 X."""
    location = engine_location(request, tmp_path, "evidence")
    bl.ingest(visits(tmp_path, which=("01", "02")), store=location)
    return location


def test_trace_days_are_recorded_as_monitored_and_once(store):
    day = pd.Timestamp("2026-03-02", tz="UTC")
    trace = _traces([day, day + pd.Timedelta(days=1)], [4.0, 4.2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = bl.monitor(trace, store=store)
        again = bl.monitor(trace, store=store)
    assert (first.recorded.added, again.recorded.added, again.recorded.unchanged) == (2, 0, 2)
    stored = read_records(store, "trace")[("M1", "X")]
    assert [r["date"] for r in stored] == ["2026-03-02", "2026-03-03"]
    expected = first.daily.set_index("date")
    for r in stored:
        assert r["lost_motion_um"] == expected.loc[r["date"], "lost_motion_um"]
        assert r["lost_motion_u_um"] == expected.loc[r["date"], "lost_motion_u_um"]
        assert r["reversals"] == expected.loc[r["date"], "reversals"]


def test_ballbar_backlash_is_recorded_per_axis_and_once(store):
    frame = _ballbar([pd.Timestamp("2026-03-02")], [(4.0, 7.0)])
    first = bl.circle(frame, store=store)
    again = bl.circle(frame, store=store)
    assert (first.recorded.added, again.recorded.added, again.recorded.unchanged) == (2, 0, 2)
    d = first.circles[0].diagnosis
    records = read_records(store, "ballbar")
    assert sorted(records) == [("M1", "X"), ("M1", "Y")]
    for axis, term in (("X", "backlash_1"), ("Y", "backlash_2")):
        [r] = records[("M1", axis)]
        assert (r["backlash_um"], r["backlash_u_um"]) == (d.value[term], d.u[term])
        assert (r["date"], r["plane"], r["visit"]) == ("2026-03-02", "XY", "b0")


def test_a_store_of_records_before_evidence_reads_none_and_gets_its_tables(tmp_path):
    import sqlite3

    from pipeline.store.base import MANIFEST

    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=("01", "02")), store=location)
    conn = sqlite3.connect(location / MANIFEST, isolation_level=None)
    conn.execute("DROP TABLE trace_days")  # as a store made before these records existed
    conn.execute("DROP TABLE ballbar_runs")
    conn.close()
    assert read_records(location, "trace") == {} and read_records(location, "ballbar") == {}
    assert bl.fleet(location).axes[0].to_dict()["evidence"] == {"trace": [], "ballbar": []}
    frame = _ballbar([pd.Timestamp("2026-03-02")], [(4.0, 7.0)])
    assert bl.circle(frame, store=location).recorded.added == 2
    assert sorted(read_records(location, "ballbar")) == [("M1", "X"), ("M1", "Y")]


# --------------------------------------------------------------------- refusals
GOOD_TRACE = {"kind": "trace", "format": RECORD_FORMAT, "machine_id": "M1", "axis": "X",
              "date": "2026-03-02", "lost_motion_um": 4.0, "lost_motion_u_um": 0.1,
              "reversals": 20, "source": "t.csv"}
GOOD_BALLBAR = {"kind": "ballbar", "format": RECORD_FORMAT, "machine_id": "M1", "axis": "X",
                "date": "2026-03-02", "plane": "XY", "visit": "1", "radius_mm": 150.0,
                "feed_mm_min": 1000.0, "backlash_um": 4.0, "backlash_u_um": 0.2,
                "source": "b.csv"}


@pytest.mark.parametrize("check, good, change, expected", [
    (check_trace, GOOD_TRACE, {"date": "2026-13-02"}, "not a date"),
    (check_trace, GOOD_TRACE, {"date": None}, "date is missing"),
    (check_trace, GOOD_TRACE, {"lost_motion_u_um": -0.1}, "lost_motion_u_um"),
    (check_trace, GOOD_TRACE, {"lost_motion_um": float("nan")}, "lost_motion_um"),
    (check_trace, GOOD_TRACE, {"extra": 1}, "unknown field(s) extra"),
    (check_ballbar, GOOD_BALLBAR, {"axis": "Q"}, "axis is 'Q'"),
    (check_ballbar, GOOD_BALLBAR, {"plane": ""}, "plane"),
    (check_ballbar, GOOD_BALLBAR, {"backlash_u_um": "0.2"}, "backlash_u_um"),
])
def test_a_record_that_cannot_be_interpreted_is_refused(check, good, change, expected):
    assert check(good) is good
    with pytest.raises(InputError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        check({**good, **change})


def test_circle_store_refusals_are_one_line_with_nothing_recorded(tmp_path, capsys):
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=("01",)), store=location)
    undated = tmp_path / "undated.csv"
    _ballbar([pd.Timestamp("2026-03-02")], [(4.0, 7.0)]).drop(columns="started_at").to_csv(
        undated, index=False)
    line = refused(capsys, ["circle", undated, "--store", location])
    assert "started_at" in line and "needs its date" in line
    assert read_records(location, "ballbar") == {}
    line = refused(capsys, ["circle", undated, "--store", tmp_path / "nowhere"])
    assert "--store: holds no store yet" in line


def test_circle_and_monitor_store_on_the_command_line(tmp_path, capsys):
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=("01",)), store=location)
    runs = tmp_path / "ballbar.csv"
    _ballbar([pd.Timestamp("2026-03-02")], [(4.0, 7.0)]).to_csv(runs, index=False)
    code, _, err = cli(capsys, ["circle", runs, "--store", location])
    assert code == 0 and f"2 ballbars recorded in {location}" in err, err
    code, _, err = cli(capsys, ["circle", runs, "--store", location])
    assert f"0 ballbars recorded in {location} (2 already recorded)" in err, err
    trace = tmp_path / "trace.csv"
    _traces([pd.Timestamp("2026-03-02", tz="UTC")], [4.0]).to_csv(trace, index=False)
    code, _, err = cli(capsys, ["monitor", trace, "--store", location])
    assert code == 0 and f"1 trace recorded in {location}" in err, err


def test_drift_evidence_refusals(tmp_path, capsys):
    files = visits(tmp_path, which=("01", "02"))
    line = refused(capsys, ["drift", *files[:1], "--json", "--evidence", "trace"])
    assert "--evidence" in line and "fleet store" in line
    location = tmp_path / "fleet"
    bl.ingest(files, store=location)
    line = refused(capsys, ["drift", location, "--json", "--evidence", "laser,sonar"])
    assert "--evidence: names 'sonar'" in line


def test_a_day_recorded_twice_counts_once_the_latest_and_as_of_cuts_later_days():
    import datetime as dt

    from pipeline.steps.evidence import evidence_frame

    older = {**GOOD_TRACE, "recorded_at": "2026-03-02T10:00:00.000000Z"}
    newer = {**GOOD_TRACE, "lost_motion_um": 4.4, "source": "again.csv",
             "recorded_at": "2026-03-05T10:00:00.000000Z"}
    later = {**GOOD_TRACE, "date": "2026-04-01", "recorded_at": "2026-04-01T10:00:00.000000Z"}
    records = {"trace": {("M1", "X"): [older, newer, later]}}
    frame = evidence_frame(records, ("M1", "X"))
    assert frame["value_um"].tolist() == [4.4, 4.0]
    cut = evidence_frame(records, ("M1", "X"), as_of=dt.date(2026, 3, 31))
    assert cut["label"].tolist() == ["trace 2026-03-02"]
