"""Slips in a ballbar file, an uncertainty budget and a report's meta file that used to print
figures without a word: a deviation column in mm, CW and CCW swapped, a single direction, an
unknown or rotary axis, a temperature in kelvin, a calibration dated after the test or expired
at it. Each is refused (one line naming the file and the field, exit 2, nothing written) or,
where the data cannot tell, noted."""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main
from pipeline.workflows.circle import circle
from tests.independent_circle import ballbar_run, fleet, random_truth

REPO = Path(__file__).resolve().parents[1]
CIRCLE = REPO / "experiments" / "data" / "circle"
BUDGET = REPO / "experiments" / "data" / "paper_uncertainty.toml"
META = REPO / "experiments" / "data" / "report_meta.toml"
ESS = REPO / "experiments" / "data" / "ecmc" / "ess_mcu1025_ISO230.dat"
SWAP = {"CW": "CCW", "CCW": "CW"}


@pytest.fixture
def cli(monkeypatch, tmp_path):
    """``pipeline.cli.main`` from an empty folder, so that nothing lands in the checkout."""
    monkeypatch.chdir(tmp_path)
    return main


def example() -> pd.DataFrame:
    return pd.read_csv(CIRCLE / "ballbar_xy.csv")


def one_error_line(capsys, command: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == "" and len(lines) == 1, lines
    assert lines[0].startswith(f"backlash {command}: error: "), lines
    return lines[0]


# --------------------------------------------------------------------------- circle: units


def test_a_deviation_column_in_mm_is_refused(cli, capsys, tmp_path):
    path = tmp_path / "ballbar_mm.csv"
    frame = example()
    frame.assign(deviation_um=frame["deviation_um"] / 1000.0).to_csv(path, index=False)
    out = tmp_path / "out"
    assert cli(["circle", str(path), "--out", str(out)]) == 2
    line = one_error_line(capsys, "circle")
    assert f"{path}, row 2, column 'deviation_um'" in line
    assert "less than a ballbar's 0.1 um resolution: the column is likely in mm" in line
    assert not out.exists()


def test_six_machines_in_mm_are_refused_in_python():
    table, _ = fleet(n=6, seed=7)
    for machine, rows in table.groupby("machine_id"):
        with pytest.raises(InputError, match="likely in mm") as err:
            circle(rows.assign(deviation_um=rows["deviation_um"] / 1000.0))
        assert err.value.column == "deviation_um", machine


def test_a_path_too_small_for_a_machine_tool_is_noted(cli, capsys, tmp_path):
    """A large path written in mm spans over the ballbar's resolution but under 1 um: the
    figures are given, with a note that they are 1000 times too small if the column is mm."""
    path = tmp_path / "ballbar_big_mm.csv"
    frame = example()
    frame.assign(deviation_um=frame["deviation_um"] * 4 / 1000.0).to_csv(path, index=False)
    assert cli(["circle", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    notes = [ln for ln in captured.err.splitlines() if ln.startswith("note: ")]
    assert len(notes) == 1, captured.err
    assert "deviation_um spans less than 1 um round the circle in 'VMC-7-XY-CCW' CCW" in notes[0]
    assert "if the column is in mm, every figure is 1000 times too small" in notes[0]
    printed = json.loads(captured.out)
    assert printed["notes"] == [notes[0].removeprefix("note: ")]
    # the figures are the example's divided by 250, as they were read
    (item,) = circle(CIRCLE / "ballbar_xy.csv").circles
    assert printed["circles"][0]["G_um"]["CW"] == pytest.approx(item.G_um["CW"] / 250, rel=1e-9)


def test_the_example_in_um_gets_no_note():
    result = circle(CIRCLE / "ballbar_xy.csv")
    assert result.notes == []


# --------------------------------------------------------------------------- circle: labels


def test_swapped_cw_and_ccw_are_refused(cli, capsys, tmp_path):
    truth = json.loads((CIRCLE / "truth.json").read_text(encoding="utf-8"))
    path = tmp_path / "ballbar_swapped.csv"
    frame = example()
    frame.assign(direction=frame["direction"].map(SWAP)).to_csv(path, index=False)
    out = tmp_path / "out"
    assert cli(["circle", str(path), "--out", str(out), "--json"]) == 2
    line = one_error_line(capsys, "circle")
    assert f"{path}, column 'direction': VMC-7 XY visit 2026-03: the CW and CCW labels look " \
           "swapped" in line
    assert "CCW is the direction of increasing angle (XY: from +X towards +Y)" in line
    # exchanged back, the backlash is the file's own diagnosis, close to what was put in
    (item,) = circle(CIRCLE / "ballbar_xy.csv").circles
    for axis, term, play in zip("XY", ("backlash_1", "backlash_2"), truth["play_um"]):
        b = item.diagnosis.value[term]
        assert f"{axis} {b:.2f} um" in line.split("backlash ")[-1]
        assert abs(b - play) <= max(0.6, 0.08 * play)
    assert not out.exists()


@pytest.mark.parametrize("seed", [7, 3, 11])
def test_swapped_labels_of_independent_machines_are_refused(seed):
    table, truths = fleet(n=4, seed=seed)
    for truth in truths:
        rows = table[table["machine_id"] == truth.machine_id]
        right = circle(rows)
        assert right.notes == [], right.notes   # positive plays, no note
        with pytest.raises(InputError, match="the CW and CCW labels look swapped") as err:
            circle(rows.assign(direction=rows["direction"].map(SWAP)))
        assert err.value.column == "direction"


def over_compensated(play_um, spike_um, seed=5) -> pd.DataFrame:
    """Correctly labelled runs of axes whose compensation exceeds their play: the independent
    generator's dead band of negative width (the load leads its command)."""
    rng = np.random.default_rng(seed)
    truth = dataclasses.replace(random_truth(rng, "OC"), play_um=play_um, spike_um=spike_um)
    runs = [ballbar_run(truth, d, rng=rng).assign(direction=d, test_id=f"OC-{d}")
            for d in ("CW", "CCW")]
    return pd.concat(runs, ignore_index=True).assign(machine_id="OC", plane="XY",
                                                     radius_mm=150.0, feed_mm_min=1000.0)


@pytest.mark.parametrize("spike_um", [(2.0, 2.0), (0.0, 0.0)])
def test_an_over_compensated_axis_is_noted_not_refused(spike_um):
    """Over-compensation reads as a negative play too; with the labels exchanged the runs fit
    no better (with spikes: worse), so the figures are given with a note naming both causes."""
    with pytest.warns(BacklashWarning, match="over-compensated"):
        result = circle(over_compensated((-3.0, -5.0), spike_um))
    (item,) = result.circles
    d = item.diagnosis
    assert d.value["backlash_1"] < -2 * d.u["backlash_1"]
    assert d.value["backlash_2"] < -2 * d.u["backlash_2"]
    (text,) = result.notes
    assert text.startswith("OC XY visit 1: negative backlash beyond 2 standard uncertainties")
    assert "or the CW and CCW labels are swapped" in text


# --------------------------------------------------------------------------- circle: one run


def test_a_single_direction_says_no_h_and_no_diagnosis(cli, capsys, tmp_path):
    from pipeline.reports.circle_chart import _box

    path = tmp_path / "cw_only.csv"
    frame = example()
    frame[frame["direction"] == "CW"].to_csv(path, index=False)
    out = tmp_path / "out"
    assert cli(["circle", str(path), "--json", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    note = ("VMC-7 XY visit 2026-03: only CW was run: G only, no H and no diagnosis (they need "
            "CW and CCW)")
    assert f"note: {note}" in captured.err.splitlines()
    printed = json.loads(captured.out)
    assert printed["notes"] == [note]
    (only,) = printed["circles"]
    assert only["H_um"] is None and only["diagnosis"] is None and only["G_um"]["CCW"] is None
    # the page and the plot's box say it too
    assert note in (out / "circles.html").read_text(encoding="utf-8")
    with pytest.warns(BacklashWarning):
        (item,) = circle(path).circles
    assert _box(item).splitlines()[2:] == ["only CW was run:", "no H, no diagnosis",
                                           "(they need CW and CCW)"]


# --------------------------------------------------------------------------- uncertainty


BUDGET_SLIPS = {
    "unknown axis": (('axis = "X"', 'axis = "Q"'),
                     "column 'axis': 'Q' is not an axis; expected one of X, Y, Z"),
    "rotary axis": (('axis = "X"', 'axis = "C"'),
                    ("column 'axis': 'C' is a rotary axis: a budget's contributors are lengths "
                     "(mm, um), not angles")),
    "kelvin": (("machine_temperature_c = 24.0", "machine_temperature_c = 297.15"),
               ("column 'temperature.machine_temperature_c': 297.15 is a temperature in kelvin "
                "(297.15 K = 24.00 °C)")),
    "neither": (("machine_temperature_c = 24.0", "machine_temperature_c = 150.0"),
                ("column 'temperature.machine_temperature_c': 150 is not a machine temperature "
                 "in °C; expected °C between -30 and 100")),
}


def slipped_budget(tmp_path, case: str) -> Path:
    (old, new), _ = BUDGET_SLIPS[case]
    text = BUDGET.read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "budget.toml"
    path.write_text(text.replace(old, new), encoding="utf-8")
    return path


@pytest.mark.parametrize("case", BUDGET_SLIPS)
def test_a_budget_slip_is_one_line_naming_the_key(case, cli, capsys, tmp_path):
    path = slipped_budget(tmp_path, case)
    before = sorted(tmp_path.rglob("*"))
    assert cli(["uncertainty", str(path), "--json"]) == 2
    line = one_error_line(capsys, "uncertainty")
    assert line.startswith(f"backlash uncertainty: error: {path}, ")
    assert BUDGET_SLIPS[case][1] in line
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("case", BUDGET_SLIPS)
def test_a_budget_slip_is_refused_in_python_and_by_report(case, cli, capsys, tmp_path):
    from pipeline.workflows.uncertainty import uncertainty

    path = slipped_budget(tmp_path, case)
    with pytest.raises(InputError) as err:
        uncertainty(path)
    assert err.value.file == str(path)
    assert BUDGET_SLIPS[case][1].split(": ", 1)[1] in str(err.value)
    out = tmp_path / "report"
    assert cli(["report", str(ESS), "--uncertainty", str(path), "--out", str(out)]) == 2
    assert BUDGET_SLIPS[case][1] in one_error_line(capsys, "report") and not out.exists()


def test_a_linear_axis_in_lower_case_and_a_cold_shop_are_accepted(tmp_path):
    from pipeline.workflows.uncertainty import uncertainty

    text = BUDGET.read_text(encoding="utf-8").replace('axis = "X"', 'axis = "y"').replace(
        "machine_temperature_c = 24.0", "machine_temperature_c = 12.0")
    path = tmp_path / "budget.toml"
    path.write_text(text, encoding="utf-8")
    result = uncertainty(path)
    # u_E,machine tool = |T_M - 20| L_T u(alpha): 8 K instead of the paper's 4 K doubles it
    paper = uncertainty(BUDGET)
    lines = {ln.key: ln.value for ln in result.values.lines}
    assert lines["u_E_machine"] == pytest.approx(
        2 * {ln.key: ln.value for ln in paper.values.lines}["u_E_machine"])


# --------------------------------------------------------------------------- report --meta


def meta_file(tmp_path, *edits) -> Path:
    text = META.read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "meta.toml"
    path.write_text(text, encoding="utf-8")
    return path


def dated(*days: str) -> pd.DataFrame:
    """Readings of one test per day (only what dates a test)."""
    return pd.DataFrame({"machine_id": "M1", "axis": "X", "test_id": [f"T{i}" for i in
                                                                      range(len(days))],
                         "started_at": [f"{d}T09:30:00Z" for d in days]})


@pytest.mark.parametrize("edit, key", [
    (("instrument_calibrated_on = 2026-02-10", "instrument_calibrated_on = {future}"),
     "report.instrument_calibrated_on"),
    (("calibrated_on = 2026-01-15\n\n[[report.sensors]]\nname = \"material",
      "calibrated_on = {future}\n\n[[report.sensors]]\nname = \"material"),
     "report.sensors[1].calibrated_on"),
])
def test_a_calibration_dated_in_the_future_is_refused(cli, capsys, tmp_path, edit, key):
    future = (dt.date.today() + dt.timedelta(days=30)).isoformat()
    path = meta_file(tmp_path, (edit[0], edit[1].format(future=future)))
    out = tmp_path / "report"
    assert cli(["report", str(ESS), "--meta", str(path), "--out", str(out)]) == 2
    line = one_error_line(capsys, "report")
    assert f"{path}, column '{key}':" in line
    assert f"is dated {future}, after today ({dt.date.today().isoformat()})" in line
    assert not out.exists()


def test_a_calibration_dated_after_the_test_is_refused():
    from pipeline.reports.report_meta import read_meta

    meta = read_meta(META)   # the instrument calibrated on 2026-02-10
    with pytest.raises(InputError) as err:
        meta.against_tests(dated("2026-03-02", "2026-02-09"))
    assert err.value.file == str(META)
    assert err.value.column == "report.instrument_calibrated_on"
    assert "is dated 2026-02-10, after the test of 2026-02-09" in str(err.value)
    # calibrated the same day as the first test, before it: accepted
    assert meta.against_tests(dated("2026-02-10", "2026-03-02")) == []


def test_a_calibration_expired_at_the_test_is_noted():
    from pipeline.reports.report_meta import read_meta

    meta = read_meta(META)   # instrument 2026-02-10, both sensors 2026-01-15, valid 12 months
    assert meta.calibration_valid_months == 12
    assert meta.against_tests(dated("2026-03-02", "2027-01-15")) == []   # the last valid day
    with pytest.warns(BacklashWarning, match="expired on 2027-01-15"):
        notes = meta.against_tests(dated("2026-03-02", "2027-01-16"))
    assert notes == [
        f"the calibration of sensor {name!r} of 2026-01-15 expired on 2027-01-15 (valid 12 "
        "months): the test of 2027-01-16 was made out of calibration"
        for name in ("air temperature", "material temperature")]
    notes = meta.against_tests(dated("2026-03-02", "2027-02-11", "2027-03-01"))
    assert notes[0] == ("the instrument's calibration of 2026-02-10 expired on 2027-02-10 "
                        "(valid 12 months): 2 test days, 2027-02-11 to 2027-03-01, were made "
                        "out of calibration")


def test_the_validity_is_the_meta_files_and_undated_tests_are_checked_at_today(tmp_path):
    from pipeline.reports.report_meta import read_meta

    six = read_meta(meta_file(tmp_path, ("[report]\n", "[report]\ncalibration_valid_months = 6\n")))
    assert six.calibration_valid_months == 6
    (first, *_) = six.against_tests(dated("2026-07-20"))
    assert first.startswith("the calibration of sensor 'air temperature' of 2026-01-15 expired "
                            "on 2026-07-15 (valid 6 months)")
    # tests without a date: the report's day stands in, and the note says so
    notes = read_meta(META).against_tests(None, today=dt.date(2027, 2, 11))
    assert len(notes) == 3 and notes[0].endswith(
        "before today (2027-02-11); the tests state no date (started_at): check they were made "
        "before it expired")
    assert read_meta(META).against_tests(None, today=dt.date(2027, 1, 15)) == []


def test_a_validity_of_no_months_is_refused(cli, capsys, tmp_path):
    path = meta_file(tmp_path, ("[report]\n", "[report]\ncalibration_valid_months = 0\n"))
    out = tmp_path / "report"
    assert cli(["report", str(ESS), "--meta", str(path), "--out", str(out)]) == 2
    assert "column 'report.calibration_valid_months': 0 is not a validity" in one_error_line(
        capsys, "report")
    assert not out.exists()


def test_report_checks_the_calibration_against_the_tests_it_signs(cli, capsys, tmp_path):
    """End to end: the twin's tests of 2026-01-05 signed with the example's instrument,
    calibrated on 2026-02-10, are refused; a meta file with a 1-month validity and a
    calibration of 2025-10-01 signs them with a note that they were out of calibration."""
    twin = REPO / "experiments" / "data" / "twin" / "readings.csv"
    out = tmp_path / "report"
    assert cli(["report", str(twin), "--meta", str(META), "--out", str(out)]) == 2
    line = one_error_line(capsys, "report")
    assert "is dated 2026-02-10, after the test of 2026-01-05" in line
    assert not out.exists()
    old = meta_file(tmp_path, ("instrument_calibrated_on = 2026-02-10",
                               ("instrument_calibrated_on = 2025-10-01\n"
                                "calibration_valid_months = 1")),
                    ("calibrated_on = 2026-01-15", "calibrated_on = 2025-10-01"))
    assert cli(["report", str(twin), "--meta", str(old), "--out", str(out)]) == 0
    assert "the instrument's calibration of 2025-10-01 expired on 2025-11-01" in (
        capsys.readouterr().err)
