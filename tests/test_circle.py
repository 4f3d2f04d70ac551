"""Circular tests (ISO 230-4): the contract's reader, G and H against hand-computed paths, the
diagnosis against the truth of an independent ballbar generator (``independent_circle``), the
command's outputs and its refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features import circle as fc
from features.readings.errors import InputError
from pipeline.cli import main
from pipeline.workflows.circle import circle
from tests.independent_circle import fleet

EXAMPLE = Path(__file__).resolve().parents[1] / "experiments" / "data" / "circle"


@pytest.fixture(scope="module")
def six():
    """Six machines, XY, R 150 mm, CW and CCW; the table and the truths."""
    return fleet(n=6, seed=7)


@pytest.fixture(scope="module")
def six_result(six):
    return circle(six[0])


def hand_run(direction, deviation, n=360, test_id=None, **extra) -> pd.DataFrame:
    angle = np.arange(n) * 360.0 / n
    return pd.DataFrame({"test_id": test_id or f"T-{direction}", "machine_id": "M1",
                         "plane": "XY", "direction": direction, "angle_deg": angle,
                         "radius_mm": 100.0, "feed_mm_min": 2000.0,
                         "deviation_um": deviation(np.radians(angle)), **extra})


# --------------------------------------------------------------------------- the standard


def test_g_is_the_band_about_the_least_squares_centre():
    # a 2-per-rev ellipse of amplitude 3 um, a 40 um set-up offset and a 5 um radius error:
    # about the least-squares centre the path spans exactly 2 x 3 um
    run = hand_run("CCW", lambda t: 5 + 3 * np.cos(2 * t) + 40 * np.cos(t) - 25 * np.sin(t))
    frame = fc.read_circles(run)
    (test,) = fc.circles(frame)
    r = test.runs["CCW"]
    assert fc.circular_deviation(r.angle_deg, r.deviation_um) == pytest.approx(6.0, abs=1e-9)
    assert fc.centre_fit(r.angle_deg, r.deviation_um) == pytest.approx((5.0, 40.0, -25.0))


def test_h_is_the_largest_difference_between_the_directions():
    # servo mismatch alone: +-2 um sin 2t, turning with the direction -> H = 4 um, G = 4 um each
    table = pd.concat([hand_run("CCW", lambda t: 2 * np.sin(2 * t)),
                       hand_run("CW", lambda t: -2 * np.sin(2 * t) + 10 * np.cos(t))])
    (item,) = circle(table).circles
    assert item.H_um == pytest.approx(4.0, abs=1e-3)
    assert item.G_um == pytest.approx({"CW": 4.0, "CCW": 4.0}, abs=1e-3)


# --------------------------------------------------------------------------- the diagnosis


def test_backlash_and_squareness_of_six_machines_within_the_tolerance(six, six_result):
    _, truths = six
    assert len(six_result.circles) == 6
    for item, truth in zip(six_result.circles, truths):
        d = item.diagnosis_json()
        for axis, play in zip("XY", truth.play_um):
            assert abs(d["backlash_um"][axis] - play) <= max(0.6, 0.08 * play), (truth, d)
        assert abs(d["squareness_um_per_m"] - truth.squareness_um_per_m) <= 3.0, (truth, d)
        assert item.G_um["CW"] > 0 and item.G_um["CCW"] > 0 and item.H_um > 0


def test_scale_servo_and_spikes_of_six_machines(six, six_result):
    _, truths = six
    for item, truth in zip(six_result.circles, truths):
        d = item.diagnosis_json()
        scale = truth.scale_ppm[0] - truth.scale_ppm[1]
        assert d["scale_mismatch_ppm"] == pytest.approx(scale, abs=3.0)
        assert d["servo_mismatch_ms"] == pytest.approx(truth.lag_ms[0] - truth.lag_ms[1],
                                                       abs=0.1)
        for axis, spike in zip("XY", truth.spike_um):
            assert d["reversal_spike_um"][axis] == pytest.approx(spike, abs=max(0.6, 0.25 * spike))
        for key in ("backlash_um", "reversal_spike_um"):
            assert all(0 < u < 1 for u in d["uncertainty"][key].values())


def test_an_arc_of_220_degrees_still_shows_each_axis_reversing(six):
    table, truths = six
    a = table["angle_deg"]
    arc = table[(table["machine_id"] == "M2") & ((a < 200) | (a > 340))]
    d = circle(arc).circles[0].diagnosis_json()
    for axis, play in zip("XY", truths[1].play_um):
        assert abs(d["backlash_um"][axis] - play) <= max(0.6, 0.08 * play)
    assert abs(d["squareness_um_per_m"] - truths[1].squareness_um_per_m) <= 3.0


def test_readings_on_the_reversals_themselves_belong_before_them():
    # ballbar software often reads at whole degrees from 0: a reading at 0, 90, 180 or 270 deg
    # is taken as the axis arrives at its extreme, before the play is taken up
    table, truths = fleet(n=2, seed=5, step_deg=1.0, start_deg=0.0)
    assert np.isin([0.0, 90.0, 180.0, 270.0], table["angle_deg"].round(9)).all()
    for item, truth in zip(circle(table).circles, truths):
        d = item.diagnosis_json()
        for axis, play in zip("XY", truth.play_um):
            assert abs(d["backlash_um"][axis] - play) <= max(0.6, 0.08 * play)


def test_the_machine_twin_s_circles_are_diagnosed():
    # the product's machine twin (models.physics.machine, of the volumetric job) reads circles
    # in this contract with its own feed drives: play, a spike decaying along the axis travel,
    # a first-order servo lag of 30 ms per axis (0.5 ms apart)
    twin = pytest.importorskip("models.physics.machine")
    if not all(hasattr(twin, n) for n in ("paper_machine", "without", "circle_test")):
        pytest.skip("the machine twin has no circular test")
    machine = twin.without(twin.paper_machine(), geometry=True)
    table = pd.concat([twin.circle_test(machine, plane=plane, radius_mm=150.0, direction=d)
                       for plane in ("XY", "YZ") for d in ("CW", "CCW")])
    for item in circle(table).circles:
        d = item.diagnosis_json()
        first, second = item.circle.axes
        for axis in (first, second):
            drive = machine.drives[axis]
            assert abs(d["backlash_um"][axis] - drive.backlash_um) <= max(
                0.6, 0.08 * drive.backlash_um), (axis, d)
            assert d["reversal_spike_um"][axis] == pytest.approx(drive.spike_um, rel=0.25)
        lag = machine.drives[first].servo_ms - machine.drives[second].servo_ms
        assert d["servo_mismatch_ms"] == pytest.approx(lag, abs=0.2)
        assert abs(d["squareness_um_per_m"]) < 1.0


def test_the_uncertainty_grows_with_the_noise():
    quiet, _ = fleet(n=1, seed=3, noise_um=0.1)
    loud, _ = fleet(n=1, seed=3, noise_um=0.8)
    u = [circle(t).circles[0].diagnosis.u["backlash_1"] for t in (quiet, loud)]
    assert u[1] > 4 * u[0]


def test_the_plane_names_the_axes_and_a_single_direction_gives_g_only(six):
    table = six[0][six[0]["machine_id"] == "M1"]
    xy = circle(table).circles[0].diagnosis_json()
    yz = circle(table.assign(plane="YZ")).circles[0].diagnosis_json()
    assert list(yz["backlash_um"]) == ["Y", "Z"]
    assert list(yz["backlash_um"].values()) == list(xy["backlash_um"].values())
    result = circle(table[table["direction"] == "CW"])
    (item,) = result.circles
    assert item.diagnosis is None and item.H_um is None and item.G_um["CCW"] is None
    assert item.G_um["CW"] > 0 and "need CW and CCW" in result.notes[0]


# --------------------------------------------------------------------------- the command


def test_the_command_prints_the_schema_and_writes_the_report(six, tmp_path, capsys):
    path = tmp_path / "ballbar.parquet"
    six[0][six[0]["machine_id"].isin(["M1", "M2"])].to_parquet(path)
    out = tmp_path / "out"
    assert main(["circle", str(path), "--json", "--out", str(out), "--tolerance", "25"]) == 0
    printed = json.loads(capsys.readouterr().out)
    first = printed["circles"][0]
    assert set(first) >= {"machine_id", "plane", "G_um", "H_um", "diagnosis"}
    assert set(first["G_um"]) == {"CW", "CCW"}
    assert set(first["diagnosis"]) >= {"backlash_um", "reversal_spike_um", "squareness_um_per_m",
                                       "scale_mismatch_ppm", "servo_mismatch_ms", "uncertainty"}
    assert set(first["diagnosis"]["backlash_um"]) == {"X", "Y"}
    assert sorted(p.name for p in out.iterdir()) == [
        "circle_M1_XY_1.png", "circle_M2_XY_1.png", "circles.csv", "circles.html"]
    summary = pd.read_csv(out / "circles.csv")
    assert summary["backlash_X_um"].tolist() == pytest.approx(
        [c["diagnosis"]["backlash_um"]["X"] for c in printed["circles"]])
    assert "circle_M2_XY_1.png" in (out / "circles.html").read_text(encoding="utf-8")


def test_the_example_file_recovers_its_truth():
    truth = json.loads((EXAMPLE / "truth.json").read_text(encoding="utf-8"))
    (item,) = circle(EXAMPLE / "ballbar_xy.csv").circles
    d = item.diagnosis_json()
    for axis, play in zip("XY", truth["play_um"]):
        assert abs(d["backlash_um"][axis] - play) <= max(0.6, 0.08 * play)


# --------------------------------------------------------------------------- refusals


def write(tmp_path, table: pd.DataFrame) -> str:
    path = tmp_path / "circle.csv"
    table.to_csv(path, index=False)
    return str(path)


def good() -> pd.DataFrame:
    return pd.concat([hand_run("CCW", lambda t: np.cos(2 * t)),
                      hand_run("CW", lambda t: np.cos(2 * t))], ignore_index=True)


@pytest.mark.parametrize("change, words", [
    (lambda t: t.drop(columns="plane"), "row 1, column 'plane': missing required column"),
    (lambda t: t.assign(plane=["XZ"] + ["XY"] * (len(t) - 1)),
     "row 2, column 'plane': 'XZ' is not a plane; expected one of XY, YZ, ZX"),
    (lambda t: t.assign(direction=t["direction"].where(t.index != 5, "up")),
     "row 7, column 'direction': 'up' is not a direction"),
    (lambda t: t.assign(deviation_um=t["deviation_um"].where(t.index != 3, 1500.2)),
     "row 5, column 'deviation_um': 1500.2 um is beyond"),
    (lambda t: t.assign(deviation_um=t["radius_mm"] + t["deviation_um"] / 1000),
     "row 2, column 'deviation_um': test 'T-CCW' CCW: deviation_um holds the nominal radius"),
    (lambda t: t.assign(radius_mm=t["radius_mm"].where(t.index != 0, -100.0)),
     "row 2, column 'radius_mm': -100 is not a nominal radius > 0 mm"),
    (lambda t: t.assign(angle_deg=t["angle_deg"].astype(object).where(t.index != 2, "n/a")),
     "row 4, column 'angle_deg': 'n/a' is not a number"),
    (lambda t: t[(t["direction"] == "CW") | (t.index % 40 == 0)],
     "test 'T-CCW' CCW has 9 readings; expected at least 16"),
    (lambda t: t[(t["direction"] == "CW") | (t["angle_deg"] < 150)],
     "test 'T-CCW' CCW leaves a gap of 211 deg"),
    (lambda t: pd.concat([t, t[t["direction"] == "CW"].assign(test_id="T-CW2")],
                         ignore_index=True),
     ("row 722, column 'test_id': machine 'M1' plane XY visit '1' (R 100 mm, F 2000 mm/min) "
      "has CW runs 'T-CW' and 'T-CW2'; expected one run per direction")),
    (lambda t: t.assign(feed_mm_min=np.where(t.index == 400, 1000.0, t["feed_mm_min"])),
     "test 'T-CW' CW changes feed_mm_min within the run"),
])
def test_bad_input_is_one_line_naming_where_and_writes_nothing(tmp_path, capsys, change, words):
    path = write(tmp_path, change(good()))
    out = tmp_path / "out"
    assert main(["circle", path, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"backlash circle: error: {path}, ") and "\n" not in err
    assert words in err
    assert not out.exists()


def test_a_vendor_export_is_refused_not_guessed(tmp_path):
    path = tmp_path / "export.csv"
    path.write_text("Angle,Radius\n0.0,150.0012\n1.0,150.0013\n", encoding="utf-8")
    with pytest.raises(InputError, match="a ballbar vendor's own export is not read") as err:
        circle(str(path))
    assert (err.value.row, err.value.column) == (1, "test_id")


def test_a_bad_tolerance_names_the_option(tmp_path, capsys):
    path = write(tmp_path, good())
    assert main(["circle", path, "--tolerance", "-5"]) == 2
    assert "--tolerance" in capsys.readouterr().err
