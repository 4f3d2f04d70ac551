"""``backlash fleet``: one view of the fleet, checked against known truth (the twin's small
fleet and the independently written fleet of ``tests/independent_fleet.py``), its JSON
contract, its worst-first order and next-visit rule, the static site and bad input."""

from __future__ import annotations

import datetime as dt
import json
import re
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import InputError
from pipeline.workflows.fleet import fleet

SMALL = {"fleet": {"machines": 2, "axes": ["X", "Y"], "visits": 6, "adjust_at": [4]}}
QUIET_UM = 20.0       # far above every axis: no alert
CROSSING_UM = 2.5     # every axis of the small twin crosses it within months: crossing_soon
MIXED_UM = 2.2        # some axes of the small twin are already above it at the last visit


def registered() -> bool:
    from pipeline.workflows import NAMES

    return "fleet" in NAMES


cli = pytest.mark.skipif(not registered(), reason="fleet not registered yet")


@pytest.fixture(scope="module")
def twin():
    import backlash as bl

    return bl.simulate(preset="fleet", config=SMALL, seed=0)


@pytest.fixture(scope="module")
def twin_file(twin, tmp_path_factory) -> Path:
    return twin.write(tmp_path_factory.mktemp("twin"))["readings"]


def last_day(sim) -> str:
    """The day of the fleet's last test: the view computed then has nothing overdue yet."""
    return pd.to_datetime(sim.readings["started_at"], utc=True).max().date().isoformat()


@pytest.fixture(scope="module")
def mixed(twin):
    return fleet(twin.readings, threshold_um=MIXED_UM, as_of=last_day(twin))


@pytest.fixture(scope="module")
def site(twin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site") / "fleet"
    fleet(twin.readings, threshold_um=MIXED_UM, out=out, as_of=last_day(twin))
    return out


def true_lost_motion(sim) -> pd.Series:
    """True lost motion per machine, axis and visit: the mean over the pendulum tests'
    interior targets (the twin is a direct system: its linear tests do not reverse there)."""
    t = sim.truth
    extent = t.groupby("test_id")["target"].agg(["min", "max"])
    lo, hi = (t["test_id"].map(extent[c]) for c in ("min", "max"))
    inner = (t["target"] > lo) & (t["target"] < hi) & (t["method"] == "pendulum")
    return t[inner].groupby(["machine_id", "axis", "visit"])["true_backlash_um"].mean()


# --------------------------------------------------------------------------- against truth
# The fleet preset's laser resolves 0.1 um, and its visit series (features.visits, not the
# fleet view) reads about 0.07 um below the twin's mean lost motion on every visit (2 u): the
# tolerance is 3 u plus the resolution.
RESOLUTION_UM = 0.1


def test_backlash_now_is_the_true_lost_motion_of_the_last_visit(twin, mixed):
    truth = true_lost_motion(twin)
    for a in mixed.to_dict()["axes"]:
        true = truth[(a["machine_id"], a["axis"], a["last_visit"])]
        error = a["backlash_um"] - true
        assert abs(error) < 3 * a["backlash_u_um"] + RESOLUTION_UM, (a["machine_id"],
                                                                     a["axis"], error)
        assert a["target_kind"] == "paper" and a["visits"] == 6


def test_the_adjusted_axes_show_the_change_point(twin, mixed):
    events = twin.visits[twin.visits["event"] == "adjustment"]
    adjusted = {(m, a): v for m, a, v in events[["machine_id", "axis", "visit"]].itertuples(
        index=False)}
    assert len(adjusted) == 4
    for a in mixed.to_dict()["axes"]:
        visit = adjusted[(a["machine_id"], a["axis"])]
        assert a["change_points"] == [visit]
        assert a["change_jumps_um"][0] < 0          # an adjustment lowers the level
        assert a["trend_since_visit"] == visit      # the trend starts after it
        assert a["slope_um_per_month"] > 0          # wear since then


def test_the_independent_fleet_backlash_change_points_and_late_joiner():
    """An independently written fleet: a machine on its rotary encoder (iso), two machines
    adjusted with their hour counter running on, one machine with three visits only."""
    from independent_fleet import fleet as independent

    import backlash as bl

    readings, truth, _ = independent(0)
    result = fleet(bl.validate(readings), threshold_um=6.0)
    axes = {(a["machine_id"], a["axis"]): a for a in result.to_dict()["axes"]}
    assert len(axes) == 10
    extent = truth.groupby(["machine_id", "axis"])["target"].transform
    inner = (truth["target"] > extent("min")) & (truth["target"] < extent("max"))
    true = truth[inner].groupby(["machine_id", "axis", "visit"])["backlash_true_um"].mean()
    for (machine, axis), a in axes.items():
        error = a["backlash_um"] - true[(machine, axis, a["last_visit"])]
        assert abs(error) < 3 * a["backlash_u_um"], (machine, axis, error)
        assert a["target_kind"] == ("iso" if machine == "M3" else "paper")
        expected = {"M2": ["5"], "M4": ["4"]}.get(machine, [])
        assert a["change_points"] == expected, (machine, axis)
    assert axes[("M5", "X")]["visits"] == 3


# --------------------------------------------------------------------------- JSON contract
TYPES = {"machine_id": str, "axis": str, "unit": str, "visits": int, "first_visit_date": str,
         "last_visit": str, "last_visit_date": str, "target_kind": str, "backlash_um": float,
         "backlash_u_um": float, "slope_um_per_month": (float, type(None)),
         "slope_interval": list, "trend_since_visit": str, "change_points": list,
         "change_jumps_um": list, "threshold_um": (float, type(None)),
         "crossing_date": (str, type(None)), "crossing_interval": list, "next_visit_due": str,
         "next_visit_reason": str, "fleet_wear_rate_per_month": (float, type(None)),
         "days_overdue": (int, type(None)),
         "last_sample": type(None), "stale_after_s": type(None),  # a file: no watcher
         "alerts": list, "alert_messages": list,
         "last_forecast": type(None), "last_compensation": type(None), "history": dict,
         "page": str, "voided_tests": list, "evidence": dict, "offsets_um": dict,
         "forecast_uses": list, "forecast_offset_um": (dict, type(None)),
         "forecast_date": (str, type(None)), "forecast_um": (float, type(None)),
         "forecast_measurement_low_um": (float, type(None)),
         "forecast_measurement_high_um": (float, type(None)),
         "forecast_lost_motion_low_um": (float, type(None)),
         "forecast_lost_motion_high_um": (float, type(None)),
         "forecast_model_error_um": (float, type(None)), "forecast_backtests": int,
         "forecast_note": (str, type(None)),
         "forecast_lost_motion_reference": (dict, type(None)),
         "forecast_lost_motion_note": (str, type(None))}


def test_json_keys_and_types(mixed):
    from features.readings.fileio import dumps

    data = json.loads(dumps(mixed.to_dict()))  # what --json prints: strict JSON
    assert set(data) == {"source", "as_of", "threshold_um", "threshold_arcsec", "limits",
                         "interval_days", "n_alerts", "axes", "probing"}
    assert data["probing"] == []  # a file: no probing records (tests/test_fleet_probing.py)
    assert data["threshold_um"] == MIXED_UM and data["interval_days"] == 90.0
    for a in data["axes"]:
        assert set(a) == set(TYPES)
        for key, kind in TYPES.items():
            assert isinstance(a[key], kind), (key, a[key])
        for key in ("first_visit_date", "last_visit_date", "next_visit_due"):
            dt.date.fromisoformat(a[key])
        assert all(isinstance(k, str) for k in a["alerts"])
        assert a["next_visit_reason"] in ("above_threshold", "crossing", "fleet_rate",
                                          "interval")
        assert set(a["history"]) == {"visits", "dates", "backlash_um", "backlash_u_um"}
        assert a["evidence"] == {"trace": [], "ballbar": []}  # a file: no trace or ballbar
        assert a["offsets_um"] == {"trace": None, "ballbar": None}
        assert a["forecast_uses"] == ["laser"] and a["forecast_offset_um"] is None
        assert len(a["history"]["backlash_um"]) == a["visits"]
        assert a["history"]["backlash_um"][-1] == a["backlash_um"]
    assert data["n_alerts"] == sum(len(a["alerts"]) for a in data["axes"])


def _worst_key(a: dict) -> tuple:
    """The documented order (docs/fleet.md), from the JSON alone."""
    group = 0 if "above_threshold" in a["alerts"] else 1 if a["alerts"] else 2
    crossing = a["crossing_date"]
    return (group, a["next_visit_due"], crossing is None, crossing or "", -a["backlash_um"],
            a["machine_id"], a["axis"])


def test_axes_are_sorted_worst_first(mixed):
    axes = mixed.to_dict()["axes"]
    kinds = [set(a["alerts"]) for a in axes]
    assert any("above_threshold" in k for k in kinds)           # the case needs both kinds
    assert any(k and "above_threshold" not in k for k in kinds)
    assert axes == sorted(axes, key=_worst_key)
    groups = [_worst_key(a)[0] for a in axes]
    assert groups == sorted(groups)


def test_next_visit_due_rule(twin):
    for threshold in (MIXED_UM, CROSSING_UM, QUIET_UM, None):
        result = fleet(twin.readings, threshold_um=threshold, interval_days=45.0)
        for a in result.to_dict()["axes"]:
            last = dt.date.fromisoformat(a["last_visit_date"])
            due = dt.date.fromisoformat(a["next_visit_due"])
            by_interval = last + dt.timedelta(days=45)
            if threshold is not None and a["backlash_um"] >= threshold:
                assert (due, a["next_visit_reason"]) == (last, "above_threshold")
                assert a["crossing_date"] is None
                continue
            early = a["crossing_interval"][0] or a["crossing_date"]
            expected = min(by_interval, max(dt.date.fromisoformat(early), last)) if early \
                else by_interval
            assert due == expected, (a["machine_id"], a["axis"], threshold)
            assert a["next_visit_reason"] == ("interval" if due == by_interval else "crossing")
            if threshold is None:
                assert a["crossing_date"] is None and a["next_visit_reason"] == "interval"


def test_no_alert_without_a_near_threshold(twin):
    quiet = fleet(twin.readings, threshold_um=QUIET_UM, as_of=last_day(twin))
    assert quiet.alerts == []
    assert all(a["crossing_date"] is not None for a in quiet.to_dict()["axes"])  # all growing
    crossing = fleet(twin.readings, threshold_um=CROSSING_UM, as_of=last_day(twin))
    assert {a["kind"] for a in crossing.alerts} == {"crossing_soon"}


# --------------------------------------------------------------------------- the site
class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.tags = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.links += [v for k, v in attrs if k in ("href", "src") and v]


def _parse(page: Path) -> _Links:
    parser = _Links()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def test_the_site_files_exist_and_every_link_resolves(site, mixed):
    names = {"index.html", "fleet.json", *(a.page for a in mixed.axes)}
    assert {p.name for p in site.iterdir()} == names
    assert not [p for p in site.parent.iterdir() if ".backlash-tmp-" in p.name]
    index = _parse(site / "index.html")
    assert sorted(set(index.links)) == sorted({"fleet.json", *(a.page for a in mixed.axes)})
    for page in site.glob("*.html"):
        for link in _parse(page).links:
            assert (site / link).is_file(), (page.name, link)
    assert json.loads((site / "fleet.json").read_text()) == json.loads(
        json.dumps(mixed.to_dict()))


def test_the_index_lists_axes_worst_first_with_a_sparkline_each(site, mixed):
    text = (site / "index.html").read_text(encoding="utf-8")
    order = re.findall(r'<a href="([^"]+\.html)">', text)
    assert order == [a.page for a in mixed.axes]
    assert text.count("<svg class='spark'") == len(mixed.axes)
    page = (site / mixed.axes[0].page).read_text(encoding="utf-8")
    assert page.count("<svg class='chart'") == 3  # history, wear-rate map, ISO chart
    assert page.count("None recorded") == 2  # no forecast, no compensation


def test_no_page_refers_to_anything_outside_the_folder(site):
    for page in site.glob("*.html"):
        text = page.read_text(encoding="utf-8")
        parsed = _parse(page)
        assert "script" not in parsed.tags and "link" not in parsed.tags, page.name
        assert not re.search(r"(?i)\b(?:https?|ftp|file):|//[\w.-]+\.\w", text), page.name
        assert all(not re.match(r"^[a-z]+:|^/", link) for link in parsed.links), page.name


def test_writing_into_an_existing_folder_keeps_other_files(twin, tmp_path):
    out = tmp_path / "site"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    result = fleet(twin.readings, threshold_um=QUIET_UM, out=out)
    assert (out / "notes.txt").read_text() == "mine"
    assert all(p.is_file() for p in result.files.values())


def test_a_failure_while_writing_leaves_nothing(twin, tmp_path, monkeypatch):
    from pipeline.reports import fleet_charts

    result = fleet(twin.readings, threshold_um=QUIET_UM)

    def broken(*args, **kwargs):
        raise RuntimeError("disk gone")

    monkeypatch.setattr(fleet_charts, "wear_chart", broken)
    with pytest.raises(RuntimeError):
        result.write(tmp_path / "site")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(("parameter", "value"), [("threshold_um", 0.0), ("threshold_um", -1.0),
                                                  ("interval_days", 0.0),
                                                  ("interval_days", -30.0)])
def test_a_parameter_out_of_range_names_itself_and_writes_nothing(twin, tmp_path, parameter,
                                                                   value):
    """The runner checks every call against the job's table (``bl.fleet``, the command line,
    an experiment's step): the workflow function itself does not check again."""
    import backlash as bl

    with pytest.raises(InputError) as err:
        bl.fleet(twin.readings, out=tmp_path / "site", track=False, **{parameter: value})
    assert err.value.parameter == parameter
    assert list(tmp_path.iterdir()) == []


def test_an_out_path_that_is_a_file_is_refused(twin, tmp_path):
    target = tmp_path / "site"
    target.write_text("not a folder")
    with pytest.raises(InputError) as err:
        fleet(twin.readings, out=target)
    assert err.value.parameter == "out"
    assert target.read_text() == "not a folder" and list(tmp_path.iterdir()) == [target]


# --------------------------------------------------------------------------- the command
def _cli(args: list[str], capsys) -> tuple[int, str, str]:
    from pipeline.cli import main

    code = main(["fleet", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@cli
def test_cli_exits_3_with_an_alert_and_0_without(twin, twin_file, tmp_path, capsys):
    code, out, err = _cli([str(twin_file), "--threshold-um", str(CROSSING_UM), "--json",
                           "--out", str(tmp_path / "site"), "--as-of", last_day(twin)], capsys)
    assert code == 3, err
    data = json.loads(out)
    assert len(data["axes"]) == 4 and all(a["alerts"] for a in data["axes"])
    assert (tmp_path / "site" / "index.html").is_file()
    code, out, err = _cli([str(twin_file), "--threshold-um", str(QUIET_UM), "--json",
                           "--as-of", last_day(twin)], capsys)
    assert code == 0, err
    assert all(a["alerts"] == [] for a in json.loads(out)["axes"])


@cli
@pytest.mark.parametrize(("args", "flag"), [(["--threshold-um", "0"], "--threshold-um"),
                                            (["--threshold-um", "-2"], "--threshold-um"),
                                            (["--interval-days", "0"], "--interval-days")])
def test_cli_bad_values_are_one_line_exit_2_nothing_written(twin_file, tmp_path, capsys, args,
                                                            flag):
    out = tmp_path / "site"
    code, stdout, err = _cli([str(twin_file), *args, "--out", str(out)], capsys)
    assert code == 2 and stdout == ""
    assert len(err.strip().splitlines()) == 1 and flag in err, err
    assert not out.exists()


@cli
def test_cli_out_that_is_a_file_is_one_line_exit_2(twin_file, tmp_path, capsys):
    target = tmp_path / "site"
    target.write_text("not a folder")
    code, stdout, err = _cli([str(twin_file), "--out", str(target)], capsys)
    assert code == 2 and stdout == "" and len(err.strip().splitlines()) == 1, err
    assert target.read_text() == "not a folder" and list(tmp_path.iterdir()) == [target]


def test_the_command_module_is_ready_to_register():
    """Adding "fleet" to ``pipeline.workflows.NAMES`` is all that is left: the record, the
    command module and its help agree with the workflow contract."""
    import argparse

    from pipeline.commands import fleet as command
    from pipeline.workflows import Workflow, workflow
    from pipeline.workflows.fleet import PARAMETERS

    record = workflow("fleet")
    assert isinstance(record, Workflow) and record.name == "fleet"
    assert record.function is fleet and record.inputs == ("data",)
    assert PARAMETERS["out"].output == "folder"
    assert {"threshold_um", "interval_days", "out"} <= set(PARAMETERS)
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    args = parser.parse_args(["data.csv", "--threshold-um", "8", "--out", "x"])
    assert (args.threshold_um, args.interval_days, args.out) == (8.0, 90.0, "x")
    assert np.isclose(args.alpha, 0.05)


# --------------------------------------------------------------------------- records of a store
HOURS_PER_DAY = 8.0  # the small twin runs 240 h between visits 30 days apart
FORECAST_KEYS = {"date", "recorded_at", "for_visit", "for_date", "for_date_estimated",
                 "for_operating_hours", "backlash_um", "backlash_low_um", "backlash_high_um",
                 "points", "model", "model_dir"}
COMPENSATION_KEYS = {"date", "recorded_at", "controller", "source", "reversal_compensation_um",
                     "max_abs_correction_um", "unit", "points", "files"}


@pytest.fixture(scope="module")
def recorded(twin_file, tmp_path_factory):
    """The small twin in a store with a wear map's forecast of every measured visit, then of
    a planned visit 540 h after the last (no date: the fleet estimates it), and two
    compensations (visits up to 03, then all)."""
    import warnings

    import backlash as bl
    from pipeline.store.records import record_compensation
    from pipeline.workflows.compensate import compensate

    folder = tmp_path_factory.mktemp("recorded")
    store = folder / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bl.BacklashWarning)
        bl.ingest(twin_file, store=store)
        bl.train(store, model="wear-map").write(folder / "model")
        measured = bl.predict(folder / "model", store, store=store)
        readings = bl.read(store)
        last = readings[readings["visit"] == readings["visit"].max()]
        plan = (last[last["method"] == "linear"]
                .drop_duplicates(["machine_id", "axis", "target"])
                [["machine_id", "axis", "target", "feed_mm_min", "dwell_s", "operating_hours"]]
                .assign(visit="07", operating_hours=lambda f: f["operating_hours"] + 540.0))
        planned = bl.predict(folder / "model", plan=plan, store=store)
        early = compensate(bl.read(store, until="2026-04-30"))
        record_compensation(store, early, recorded_at="2026-05-01T08:00:00.000000Z")
        latest = compensate(store)
        record_compensation(store, latest)
    return store, measured, planned, latest, last


def test_the_last_forecast_and_compensation_of_each_axis(recorded):
    store, _, planned, latest, last = recorded
    view = fleet(store, threshold_um=QUIET_UM)
    profiles = {(p.machine_id, p.axis): p for p in latest.profiles}
    for a in view.to_dict()["axes"]:
        key = (a["machine_id"], a["axis"])
        f, c = a["last_forecast"], a["last_compensation"]
        assert set(f) == FORECAST_KEYS and set(c) == COMPENSATION_KEYS
        points = planned.predictions[(planned.predictions["machine_id"] == key[0])
                                     & (planned.predictions["axis"] == key[1])]
        for name in ("backlash_um", "backlash_low_um", "backlash_high_um"):
            assert f[name] == pytest.approx(points[name].mean(), abs=1e-4)
        assert f["for_visit"] == "07" and f["model"] == "wear-map" and f["for_date_estimated"]
        assert f["points"] == len(points)
        last_day = last[(last["machine_id"] == key[0]) & (last["axis"] == key[1])][
            "started_at"].min().date()
        days = (dt.date.fromisoformat(f["for_date"]) - last_day).days
        assert abs(days - 540.0 / HOURS_PER_DAY) <= 1, (key, f["for_date"], last_day)
        p = profiles[key]
        assert c["controller"] == "csv" and c["unit"] == "um" and c["source"] == "measured"
        assert c["reversal_compensation_um"] == pytest.approx(p.backlash, abs=1e-4)
        assert c["max_abs_correction_um"] == pytest.approx(
            np.abs(np.r_[p.mean_up, p.mean_down]).max(), abs=1e-4)
        assert c["date"] == c["recorded_at"][:10] != "2026-05-01"


def test_a_forecast_with_its_own_day_is_shown_for_that_day(recorded, tmp_path):
    """Without the planned visit's forecasts, the last one is the last measured visit's,
    which carries that visit's day."""
    import shutil
    import sqlite3

    from pipeline.store.records import read_records

    store, measured = recorded[:2]
    copy = tmp_path / "fleet"
    shutil.copytree(store, copy)
    assert {len(v) for v in read_records(copy, "forecast").values()} == {7}  # 6 visits + plan
    conn = sqlite3.connect(copy / "manifest.sqlite", isolation_level=None)
    conn.execute("""DELETE FROM forecasts WHERE record LIKE '%"visit":"07"%'""")
    conn.close()
    p = measured.predictions
    for a in fleet(copy, threshold_um=QUIET_UM).to_dict()["axes"]:
        f = a["last_forecast"]
        assert (f["for_visit"], f["for_date"], f["for_date_estimated"]) == (
            a["last_visit"], a["last_visit_date"], False)
        points = p[(p["machine_id"] == a["machine_id"]) & (p["axis"] == a["axis"])
                   & (p["visit"] == a["last_visit"])]
        assert f["backlash_um"] == pytest.approx(points["backlash_um"].mean(), abs=1e-4)


def test_the_printed_table_shows_the_last_forecast_and_compensation(recorded, capsys):
    from pipeline.commands.fleet import print_summary

    store = recorded[0]
    view = fleet(store, threshold_um=QUIET_UM)
    print_summary(view, file=sys.stdout)
    lines = capsys.readouterr().out.splitlines()
    assert "last forecast" in lines[0] and "compensated" in lines[0] and "unit" in lines[0]
    for line, a in zip(lines[1:], view.to_dict()["axes"]):
        f = a["last_forecast"]
        assert (f"{f['backlash_um']:.2f} [{f['backlash_low_um']:.2f}, "
                f"{f['backlash_high_um']:.2f}] ~{f['for_date']}") in line
        assert f"{a['last_compensation']['date']} " in line


def test_the_site_shows_the_records(recorded, tmp_path):
    store = recorded[0]
    view = fleet(store, threshold_um=QUIET_UM, out=tmp_path / "site")
    index = (tmp_path / "site" / "index.html").read_text()
    assert index.count("#9467bd") >= len(view.axes)  # the recorded forecast in each sparkline
    for a in view.to_dict()["axes"]:
        f = a["last_forecast"]
        assert f"{f['backlash_um']:.2f} [{f['backlash_low_um']:.2f}" in index
        page = (tmp_path / "site" / a["page"]).read_text()
        assert "last recorded forecast (95 %)" in page
        assert "Wear-rate map of the last forecast&#x27;s model" in page or \
            "Wear-rate map of the last forecast's model" in page
        assert page.count("<tr><td>20") >= 7 + 2  # seven forecasts, two compensations
        assert "compensation history" in page and "1 earlier" in page
    assert json.loads((tmp_path / "site" / "fleet.json").read_text())["axes"][0][
        "last_compensation"]["controller"] == "csv"


def test_a_file_or_frame_shows_none_recorded(site):
    page = next(p for p in site.glob("*.html") if p.name != "index.html").read_text()
    assert "None recorded" in page and "backlash predict MODEL DATA --store STORE" in page
