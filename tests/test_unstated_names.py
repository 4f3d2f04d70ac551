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
    bl.read(psi_file).assign(axis="Y").to_csv(path, index=False)
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
