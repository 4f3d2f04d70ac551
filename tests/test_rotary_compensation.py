"""Rotary axes in compensation files: degrees and arcsec, never mm or um.

A rotary table C measured over 0-315 deg: deviations (arcsec) are a 30 arcsec/turn pitch error
plus a 20 arcsec lost motion (indirect: mean_up = e - b/2, mean_down = e + b/2).
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from pipeline.workflows.compensate import compensate

LOST_ARCSEC = 20.0
LINEAR_UNITS = re.compile(r"\b(mm|um)\b|\[mm\]|\[um\]")


def rotary_readings() -> pd.DataFrame:
    target = np.arange(0.0, 360.0, 45.0)
    error = 30.0 * target / 360.0
    rows = []
    for cycle in range(1, 6):
        for direction, side in (("+", -1), ("-", 1)):
            for x, e in zip(target, error):
                wobble = 0.2 * ((cycle * 7 + int(x)) % 3 - 1)  # repeatability, arcsec
                rows.append({"machine_id": "R1", "axis": "C", "test_id": "R1-C-1",
                             "method": "linear", "target": x, "direction": direction,
                             "cycle": cycle, "deviation_um": e + side * LOST_ARCSEC / 2 + wobble})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    path = tmp_path_factory.mktemp("rotary") / "rotary.csv"  # a canonical readings file
    rotary_readings().to_csv(path, index=False)
    return compensate(path, controller="linuxcnc,sinumerik,heidenhain,fanuc,csv")


def test_files_speak_degrees_and_arcsec(result):
    for name, content in result.contents.items():
        text = content.decode()
        lines = (text.splitlines() if not name.endswith(".COM")
                 else [line for line in text.splitlines() if line.startswith(";")])
        assert not [line for line in lines if LINEAR_UNITS.search(line)], name
    eec = result.contents["R1_C_AX_EEC.INI"].decode()
    assert "[deg], 0 at the reference point 0 deg" in eec
    assert "points every 45 deg" in eec and "arcsec; needs MD38000" in eec
    ini = result.contents["R1_C_linuxcnc.ini"].decode()
    assert "rotary joint C: TYPE = ANGULAR" in ini and "[JOINT_5]\nTYPE = ANGULAR\n" in ini
    sheet = result.contents["R1_C_fanuc.txt"].decode().splitlines()
    assert "DETECTION UNIT = 0.001 deg" in sheet and "REFERENCE POSITION = 0.0000 deg" in sheet
    assert "3625 C = 360000" in "\n".join(sheet)
    assert result.contents["R1_C.COM"].decode().count("BEGIN R1_C.COM DEG\n") == 1


def test_a_full_turn_is_a_modulo_table(result):
    """0 to 315 deg every 45 deg closes the turn: SINUMERIK writes IS_MODULO=1 from 0 to 360 deg
    with the value at 360 deg that at 0 deg; read back, every file takes up the constant lost
    motion (Fanuc to half its detection unit of 0.001 deg = 1.8 arcsec)."""
    eec = result.contents["R1_C_AX_EEC.INI"].decode()
    assert "$AA_ENC_COMP_IS_MODULO[0,AX6]=1\n" in eec
    assert "$AA_ENC_COMP_MIN[0,AX6]=0.000000\n$AA_ENC_COMP_MAX[0,AX6]=360.000000\n" in eec
    assert re.search(r"^\$AA_ENC_COMP\[0,0,AX6\]=(\S+)$", eec, re.MULTILINE)[1] == re.search(
        r"^\$AA_ENC_COMP\[0,8,AX6\]=(\S+)$", eec, re.MULTILINE)[1]
    for w in result.written:
        limit = 1.8 if w["controller"] == "fanuc" else 0.5  # arcsec: B_i is one value
        assert w["reversal_left_um"] < limit, w["controller"]


def test_values_are_in_degrees(result):
    """MD32450 and LinuxCNC's BACKLASH hold b / 3600 deg; the LinuxCNC nominals are the
    targets in degrees and its actual columns differ by the lost motion in degrees."""
    b_deg = LOST_ARCSEC / 3600
    md = result.contents["R1_C_MD32450.INI"].decode()
    assert float(re.search(r"\$MA_BACKLASH\[0,AX6\]=(\S+)", md)[1]) == pytest.approx(b_deg,
                                                                                     abs=1e-6)
    table = np.loadtxt(result.contents["R1_C.comp"].decode().splitlines())
    assert np.allclose(table[:, 0], np.arange(0.0, 361.0, 45.0))  # the turn closed at 360
    assert np.allclose(table[-1, 1:] - 360, table[0, 1:])
    assert np.allclose(table[:, 2] - table[:, 1], b_deg, atol=2e-5)
    sheet = result.contents["R1_C_fanuc.txt"].decode()
    assert int(re.search(r"^1851 C = (\d+)", sheet, re.MULTILINE)[1]) == round(LOST_ARCSEC / 3.6)
    mp = result.contents["R1_C_heidenhain_MP.txt"].decode()
    mp710 = float(re.search(r"^MP710\.5 = (\S+)", mp, re.MULTILINE)[1])
    assert mp710 == pytest.approx(b_deg, abs=5e-5)
    linuxcnc = next(w for w in result.written if w["controller"] == "linuxcnc")
    assert linuxcnc["reversal_left_um"] < 0.01  # arcsec: the table carries the reversal


def test_summary_in_arcsec(result):
    lines = result.summary()
    assert lines[0] == ("R1 C (measured): reversal compensation 20.000 arcsec; the axis's lost "
                        "motion 20.000 arcsec (docs/backlash.md), 8 targets")
    assert all(not LINEAR_UNITS.search(line) for line in lines)


def test_csv_columns_are_degrees_and_arcsec_and_read_back(result, tmp_path):
    """The CSV names its columns target_deg, *_arcsec; read back, its offsets are degrees:
    the indirect lost motion of 20 arcsec is 20 / 3600 deg between the two directions."""
    from models.physics.controller import csv_table

    text = result.contents["R1_C_compensation.csv"].decode()
    header = text.splitlines()[0].split(",")
    assert "target_deg" in header and "correction_plus_arcsec" in header
    assert not [name for name in header if LINEAR_UNITS.search(name.replace("_", " "))]
    path = tmp_path / "R1_C_compensation.csv"
    path.write_text(text)
    comp = csv_table(path)
    x = np.arange(0.0, 360.0, 45.0)
    gap = comp.offset_mm(x, -1) - comp.offset_mm(x, 1)  # correction minus - plus [deg]
    np.testing.assert_allclose(gap, -LOST_ARCSEC / 3600, atol=2e-4 / 3600 * 1000)
