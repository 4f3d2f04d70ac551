"""Names a file does not state: an ecmc file names no axis (and its machine only by the file's
name), a paper Table-2 file may name neither. ``--machine``/``--axis`` then name them, for
every command that reads DATA, instead of selecting tests; a linear file is never named a
rotary axis (its deviations are um, not arcsec), nor the reverse."""

from __future__ import annotations

import json

import pytest
from store_files import cli, refused

import backlash as bl
from features.readings import schema


def test_an_ecmc_file_states_neither_name(ess_file):
    frame = bl.read(ess_file)
    assert frame.attrs[schema.UNSTATED] == ("machine_id", "axis")
    assert set(frame["axis"]) == {"X"}  # until named


def test_axis_and_machine_options_name_an_ecmc_test(ess_file, capsys):
    code, out, err = cli(capsys, ["iso", ess_file, "--axis", "y", "--machine", "mcu1025",
                                  "--json"])
    [test] = json.loads(out)
    assert code == 0 and (test["machine_id"], test["axis"]) == ("mcu1025", "Y")
    assert any("states no axis; named Y" in line for line in err), err


def test_compensation_files_carry_the_named_axis(ess_file, tmp_path, capsys):
    out = tmp_path / "comp"
    code, _, err = cli(capsys, ["compensate", ess_file, "--axis", "Y", "--controller",
                                "linuxcnc", "--out", out])
    assert code == 0, err
    [ini] = out.glob("*_Y_linuxcnc.ini")
    assert "[JOINT_1]" in ini.read_text() and not list(out.glob("*_X*"))


def test_ingest_stores_the_named_machine_and_axis(ess_file, tmp_path, capsys):
    store = tmp_path / "fleet"
    code, _, err = cli(capsys, ["ingest", ess_file, "--store", store, "--machine", "mcu1025",
                                "--axis", "Z"])
    assert code == 0, err
    stored = bl.read(store)
    assert set(zip(stored["machine_id"], stored["axis"])) == {("mcu1025", "Z")}


def test_a_file_that_states_its_names_is_still_selected(tmp_path, capsys, psi_file):
    """A canonical CSV states machine and axis: --axis selects, and selects nothing here."""
    path = tmp_path / "psi.csv"
    with pytest.warns(bl.BacklashWarning, match="states no axis; taken as X"):
        frame = bl.read(psi_file)
    frame.assign(axis="Y").to_csv(path, index=False)
    line = refused(capsys, ["iso", path, "--axis", "X"])
    assert "no test matches axis X" in line


@pytest.mark.parametrize("axis, words", [
    ("C", "the file holds a linear axis (deviations in um); --axis C is rotary"),
    ("X,Y", "the file states no axis; expected one --axis to name it, got X, Y"),
])
def test_a_name_that_cannot_hold_is_one_line(ess_file, tmp_path, capsys, axis, words):
    out = tmp_path / "comp"
    line = refused(capsys, ["compensate", ess_file, "--axis", axis, "--controller", "csv",
                            "--out", out]) if axis == "C" else \
        refused(capsys, ["iso", ess_file, "--axis", axis])
    assert words in line and not out.exists()


# --------------------------------------------------------------------------- the PV's axis
def ecmc_file(folder, name: str, setpoint: str | None, unit: str = "mm"):
    """A small ecmc file of our own: 3 targets, 2 cycles, reversal 10 um, with the set-point PV
    ``setpoint`` in its header (none when None)."""
    lines = ["REF_PV=LAB:Enc01-PosAct", "TEST_PV=LAB:TestNumber"]
    lines += [] if setpoint is None else [f"TGT_SET_PV={setpoint}"]
    lines += [f"UNIT={unit}", "CYCLES=2", "POSITIONS=3"]
    for i, target in enumerate((0.0, 10.0, 20.0), start=1):
        lines.append(f"TGT_DATA[{i}]={target:g}")
        for cycle in (1, 2):
            noise = 0.0002 * cycle
            lines.append(f"REF_DATA_FWD[{i},{cycle}]={target + 0.005 + noise:.4f}")
            lines.append(f"REF_DATA_BWD[{i},{cycle}]={target - 0.005 + noise:.4f}")
    path = folder / f"{name}_ISO230.dat"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("pv, axis", [
    ("TARGET_DU:Z-PosCmd", "Z"), ("TARGET_DU:Y-PosCmd", "Y"), ("LAB:Mtr-Y1-PosSet", "Y"),
    ("MC:AxisX-PosSet", "X"), ("MC:Axis_Z-PosSet", "Z"), ("ROT:C-PosCmd", "C"),
    ("TARGET_DU:Z", "Z"),
    # the real files' and the camonitor logs' PVs: axis numbers, motors, terminals
    ("IOC_TEST:Axis1-PosSet", None), ("sls-sioc-ecat01:M1-PosSet", None),
    ("IOC_TEST:Axis1-PosAct", None), ("IOC_TEST:ec0-s4-EL7211-Enc-PosAct", None),
    ("LAB:X-Y-PosSet", None), ("X_DU:Motor-PosSet", None), ("", None),
])
def test_the_axis_a_set_point_pv_names(pv, axis):
    from features.readings.formats import axis_from_pv

    assert axis_from_pv(pv) == axis


def test_real_ecmc_headers_name_no_axis_letter():
    """Every real ecmc file and camonitor log at hand: their PVs number the axis (Axis1, M1),
    so each is X with a note, as before the rule."""
    import re
    from pathlib import Path

    from features.readings.formats import axis_from_pv

    real = Path(__file__).resolve().parents[1] / "experiments" / "data" / "ecmc"
    pvs = [re.search(r"^TGT_SET_PV=(\S+)", p.read_text(), re.MULTILINE)[1]
           for p in real.glob("*.dat")]
    assert sorted(pvs) == ["IOC_TEST:Axis1-PosSet", "sls-sioc-ecat01:M1-PosSet"]
    assert [axis_from_pv(pv) for pv in pvs] == [None, None]


@pytest.mark.parametrize("pv, unit, axis, noted", [
    ("TARGET_DU:Z-PosCmd", "mm", "Z", None),
    ("TARGET_DU:Y-PosCmd", "um", "Y", None),
    ("ROT:B-PosCmd", "deg", "B", None),
    ("IOC_TEST:Axis1-PosSet", "mm", "X", "states no axis; taken as X (name it with --axis)"),
    (None, "mm", "X", "states no axis; taken as X"),
    (None, "deg", "A", "states no axis; taken as A"),
    ("TARGET_DU:Z-PosCmd", "deg", "A", "names axis Z, but UNIT deg is a rotary axis's"),
])
def test_an_ecmc_file_is_named_by_its_set_point_pv(tmp_path, pv, unit, axis, noted):
    import warnings

    path = ecmc_file(tmp_path, "du", pv, unit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frame = bl.read(path)
    notes = [str(w.message) for w in caught]
    assert set(frame["axis"]) == {axis}
    assert (noted is None and not notes) or any(noted in n for n in notes), notes


@pytest.mark.parametrize("command", ["iso", "report", "compensate", "ingest", "convert"])
def test_every_command_takes_the_pvs_axis(tmp_path, capsys, command):
    path = ecmc_file(tmp_path, "du", "TARGET_DU:Z-PosCmd")
    out = tmp_path / "out"
    argv = {"iso": ["iso", path, "--json"],
            "report": ["report", path, "--out", out],
            "compensate": ["compensate", path, "--controller", "csv", "--out", out],
            "ingest": ["ingest", path, "--store", out],
            "convert": ["convert", path, "--out", tmp_path / "du.csv"]}[command]
    code, stdout, err = cli(capsys, argv)
    assert code == 0, err
    notes = [line for line in err if line.startswith("note:")]
    assert not any("axis" in line for line in notes), err  # the PV named it: nothing to note
    if command == "iso":
        assert [t["axis"] for t in json.loads(stdout)] == ["Z"]
    elif command == "report":
        from tests.test_report_pdf import pdf_pages

        [page] = pdf_pages(out / "iso_report.pdf")
        assert "du, axis Z" in page and "axis: Z" in page
    elif command == "compensate":
        assert [p.name for p in out.glob("*.csv")] == ["du_Z_compensation.csv"]
    else:
        stored = bl.read(out if command == "ingest" else tmp_path / "du.csv")
        assert set(stored["axis"]) == {"Z"}


def test_axis_option_overrides_the_pv(tmp_path, capsys):
    path = ecmc_file(tmp_path, "du", "TARGET_DU:Z-PosCmd")
    code, out, err = cli(capsys, ["iso", path, "--axis", "Y", "--json"])
    assert code == 0 and [t["axis"] for t in json.loads(out)] == ["Y"]
    assert any("set-point PV TGT_SET_PV=TARGET_DU:Z-PosCmd names axis Z; named Y (--axis)"
               in line for line in err), err
    line = refused(capsys, ["iso", path, "--axis", "C"])  # a linear file is no rotary axis
    assert "the file holds a linear axis (deviations in um); --axis C is rotary" in line


def test_a_real_file_without_an_axis_letter_is_x_with_a_note(ess_file, capsys):
    code, out, err = cli(capsys, ["iso", ess_file, "--json"])
    assert code == 0 and [t["axis"] for t in json.loads(out)] == ["X"]
    assert any("ess_mcu1025_ISO230.dat: the file states no axis; taken as X (name it with "
               "--axis)" in line for line in err), err
