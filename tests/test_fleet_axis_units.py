"""Units in ``fleet`` and ``drift``: every axis in its own unit (um for a linear axis, arcsec
for a rotary one) in the JSON, the pages, the charts and the alerts; ``--threshold-um`` for the
linear axes, ``--threshold-arcsec`` for the rotary ones, ``--limits`` per machine axis; a
limit is never compared with a value in another unit. Checked on the independently written
fleet (tests/independent_fleet.py), its X axes beside its rotary C axes."""

from __future__ import annotations

import json
import warnings

import pandas as pd
import pytest
from independent_fleet import fleet as independent

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main
from pipeline.steps.limits import read_limits
from pipeline.workflows.drift import drift
from pipeline.workflows.fleet import fleet

UNITS = {"X": "um", "C": "arcsec"}


@pytest.fixture(scope="module")
def mixed():
    """Five machines with an X axis (um) and a C axis (arcsec, tens of arcsec), six visits."""
    linear = independent(0, visits=6)[0]
    rotary = independent(0, visits=6, rotary=True)[0]
    readings = pd.concat([linear[linear["axis"] == "X"], rotary[rotary["axis"] == "C"]],
                         ignore_index=True)
    return bl.validate(readings)


def quiet(function, readings, **kwargs):
    """``function`` on ``readings`` as of the day of their last test, notes silenced."""
    last = pd.to_datetime(readings["started_at"], utc=True).max().date().isoformat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return function(readings, as_of=last, **kwargs)


def test_each_axis_carries_its_unit_and_its_own_limit(mixed):
    view = quiet(fleet, mixed, threshold_um=6.0, threshold_arcsec=60.0)
    axes = view.to_dict()["axes"]
    assert len(axes) == 10
    for a in axes:
        assert a["unit"] == UNITS[a["axis"]]
        assert a["threshold_um"] == (60.0 if a["axis"] == "C" else 6.0)
        for kind, message in zip(a["alerts"], a["alert_messages"]):
            if kind == "overdue":  # days, no unit
                continue
            assert (" arcsec" in message) == (a["axis"] == "C"), message
            assert (" um" in message) == (a["axis"] == "X"), message
    # the rotary axes are tens of arcsec: compared with 60 arcsec, one of them crosses soon
    assert any(a["alerts"] for a in axes if a["axis"] == "C")
    series = quiet(drift, mixed, threshold_um=6.0, threshold_arcsec=60.0).to_dict()["series"]
    assert {(s["axis"], s["unit"], s["threshold_um"]) for s in series} == {
        ("X", "um", 6.0), ("C", "arcsec", 60.0)}


def test_a_limit_in_um_is_never_compared_with_arcsec(mixed):
    """--threshold-um alone: the C axes (30-60 arcsec, far above 2 as numbers) get no limit
    and no threshold alert; the X axes above 2 um are above it."""
    view = quiet(fleet, mixed, threshold_um=2.0)
    for a in view.to_dict()["axes"]:
        if a["axis"] == "C":
            assert a["backlash_um"] > 2.0 and a["threshold_um"] is None
            assert not {"above_threshold", "crossing_soon"} & set(a["alerts"])
        elif a["backlash_um"] >= 2.0:
            assert "above_threshold" in a["alerts"]


def test_limits_per_machine_axis(mixed, tmp_path):
    path = tmp_path / "limits.toml"
    path.write_text("[M1]\nX_um = 3.5\nC_arcsec = 45.0\n\n[M3]\nC_arcsec = 20\n")
    assert read_limits(path) == {("M1", "X"): 3.5, ("M1", "C"): 45.0, ("M3", "C"): 20.0}
    view = quiet(fleet, mixed, threshold_um=6.0, limits=path)
    limits = {(a["machine_id"], a["axis"]): a["threshold_um"] for a in view.to_dict()["axes"]}
    assert limits[("M1", "X")] == 3.5 and limits[("M1", "C")] == 45.0
    assert limits[("M3", "C")] == 20.0 and limits[("M2", "X")] == 6.0
    assert limits[("M2", "C")] is None  # no --threshold-arcsec, no entry
    assert view.to_dict()["limits"] == str(path)
    # the same limits as a dict, from Python
    again = quiet(fleet, mixed, threshold_um=6.0, limits={"M1": {"X_um": 3.5, "C_arcsec": 45.0},
                                                         "M3": {"C_arcsec": 20}})
    assert [a["threshold_um"] for a in again.to_dict()["axes"]] == [
        a["threshold_um"] for a in view.to_dict()["axes"]]


def test_the_pages_write_each_axis_in_its_unit(mixed, tmp_path):
    view = quiet(fleet, mixed, threshold_um=6.0, threshold_arcsec=60.0, out=tmp_path / "site")
    for v in view.axes:
        page = (tmp_path / "site" / v.page).read_text(encoding="utf-8")
        unit = "arcsec" if v.axis == "C" else "µm"
        assert f"backlash [{unit}]" in page  # the history chart's axis and the visit table
        assert f"threshold {60 if v.axis == 'C' else 6} {unit}" in page
        if v.axis == "C":
            assert "[µm]" not in page and "µm/month" not in page
        if v.axis == "C" and v.wear is not None:
            assert "wear rate [arcsec/1000 h]" in page and "position [deg]" in page
    index = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert "6 µm (linear axes); 60 arcsec (rotary axes)" in index
    data = json.loads((tmp_path / "site" / "fleet.json").read_text())
    assert data["threshold_arcsec"] == 60.0 and all("unit" in a for a in data["axes"])
    report = quiet(drift, mixed, threshold_arcsec=60.0).write(tmp_path / "drift")
    text = report["html"].read_text(encoding="utf-8")
    assert "backlash [arcsec]" in text and "backlash [µm]" in text


BAD_LIMITS = {
    "unknown key": ("[M1]\nX = 3.5\n", "unknown key M1.X: expected <axis>_um"),
    "unknown unit": ("[M1]\nX_mm = 3.5\n", "unknown key M1.X_mm"),
    "negative": ("[M1]\nX_um = -1.0\n", "M1.X_um = -1.0: expected a positive finite number"),
    "zero": ("[M1]\nC_arcsec = 0\n", "M1.C_arcsec = 0: expected a positive"),
    "text": ("[M1]\nX_um = \"8\"\n", "M1.X_um = '8': expected a positive"),
    "wrong unit": ("[M1]\nC_um = 40.0\n", "M1.C_um: axis C is measured in arcsec, not um"),
    "wrong unit linear": ("[M1]\nX_arcsec = 4\n", "axis X is measured in um, not arcsec"),
    "not a table": ("X_um = 3.5\n", "key 'X_um': expected a table [X_um]"),
    "not toml": ("[M1\nX_um = 1\n", "invalid TOML"),
}


@pytest.mark.parametrize("case", sorted(BAD_LIMITS))
def test_a_bad_limits_file_is_one_line_exit_2_nothing_written(mixed, tmp_path, capsys, case):
    text, expected = BAD_LIMITS[case]
    path = tmp_path / "limits.toml"
    path.write_text(text)
    with pytest.raises(InputError, match="limits"):
        read_limits(path)
    data = tmp_path / "mixed.csv"
    mixed.head(400).to_csv(data, index=False)
    for command in (["fleet", str(data), "--out", str(tmp_path / "site")],
                    ["drift", str(data), "--out", str(tmp_path / "drift")]):
        code = main([*command, "--limits", str(path)])
        captured = capsys.readouterr()
        assert code == 2 and captured.out == "", captured.err
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0] and "--limits" in lines[0], lines
    assert not (tmp_path / "site").exists() and not (tmp_path / "drift").exists()


def test_cli_threshold_arcsec_and_json_units(mixed, tmp_path, capsys):
    data = tmp_path / "mixed.csv"
    mixed.to_csv(data, index=False)
    code = main(["fleet", str(data), "--threshold-um", "20", "--threshold-arcsec", "500",
                 "--json"])
    captured = capsys.readouterr()
    assert code in (0, 3), captured.err
    out = json.loads(captured.out)
    assert {(a["axis"], a["unit"], a["threshold_um"]) for a in out["axes"]} == {
        ("X", "um", 20.0), ("C", "arcsec", 500.0)}
    header = captured.err.splitlines()[0]
    assert "unit" in header and "backlash um" not in header
    code = main(["fleet", str(data), "--threshold-arcsec", "-3"])
    captured = capsys.readouterr()
    assert code == 2 and "--threshold-arcsec" in captured.err


def test_an_undated_test_is_left_out_with_one_note(mixed):
    """One test without a start date (as an ecmc file ingested without one): the view goes
    on without it and one note names it."""
    readings = mixed.copy()
    undated = readings["test_id"] == readings["test_id"].iloc[-1]  # M5's last C test
    readings.loc[undated, "started_at"] = pd.NaT
    with pytest.warns(BacklashWarning) as caught:
        view = fleet(readings, threshold_um=6.0, threshold_arcsec=60.0, as_of="2026-12-31")
    texts = [str(w.message) for w in caught if "start date" in str(w.message)]
    name = readings.loc[undated, "test_id"].iloc[0]
    expected = (f"1 test(s) without a start date (started_at) left out of the date-based "
                f"view: {name}")
    assert texts == [expected]
    assert texts[0] in view.notes and len(view.axes) == 10
    c = next(v for v in view.axes if (v.machine_id, v.axis) == ("M5", "C"))
    assert (c.series.visits["n_tests"] == [2] * (len(c.series.visits) - 1) + [1]).all()
