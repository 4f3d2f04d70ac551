"""Rotary axes in the table formats: one turn as a modulo table, degrees in every line, and the
controller model applying what was written.

A rotary table C measured every 45 deg over 0-315 deg (the turn closes: 315 + 45 = 360) with a
once-per-turn eccentricity error (30 arcsec amplitude, 5 arcsec offset) and a 20 arcsec lost
motion (indirect: mean_up = e - b/2, mean_down = e + b/2). A correct table, read back by the
controller model and added to the command, leaves the error minus its value at the reference
point (a constant no ISO figure sees), at the targets and one turn further.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from features.readings.errors import InputError
from models.physics import controller as model
from pipeline.compensation import CONTROLLERS
from pipeline.compensation.common import Options, full_turn
from pipeline.compensation.profile import AxisProfile

LOST_ARCSEC = 20.0
LINEAR_UNITS = re.compile(r"\b(mm|um)\b|\[mm\]|\[um\]")


def rotary(target=None, axis: str = "C") -> AxisProfile:
    x = np.arange(0.0, 360.0, 45.0) if target is None else np.asarray(target, float)
    e = 30.0 * np.sin(np.radians(x)) + 5.0
    u = np.full_like(x, 0.2)
    return AxisProfile("R1", axis, x, e - LOST_ARCSEC / 2, e + LOST_ARCSEC / 2, u, u,
                       "measured", [])


def written(name: str, profile, tmp_path, **options):
    result = CONTROLLERS[name].writer(profile, tmp_path, Options(**options))
    return result, {role: path.read_text() for role, path in result["files"].items()}


def left_arcsec(comp, profile, shift_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """What the axis shows with the compensation applied, moving + and - [arcsec]."""
    x = profile.target + shift_deg
    return (profile.mean_up + 3600 * comp.offset_mm(x, 1),
            profile.mean_down + 3600 * comp.offset_mm(x, -1))


def test_which_profiles_are_a_full_turn():
    assert full_turn(rotary())                                   # 0..315 every 45: closes
    assert full_turn(rotary(np.arange(0.0, 361.0, 45.0)))        # 0..360 measured
    assert full_turn(rotary([0, 43, 91, 137, 178, 226, 271, 318]))  # closing step 42 <= 48
    assert not full_turn(rotary(np.arange(0.0, 181.0, 45.0)))    # half a turn
    assert not full_turn(rotary(np.arange(0.0, 721.0, 45.0)))    # two turns
    x = rotary()
    assert not full_turn(AxisProfile("R1", "X", x.target, x.mean_up, x.mean_down, x.u_up,
                                     x.u_down, "measured", []))


# --------------------------------------------------------------------------- SINUMERIK


def test_sinumerik_full_turn_is_modulo_0_to_360_and_the_model_repeats_it(tmp_path):
    p = rotary()
    result, text = written("siemens", p, tmp_path)
    eec = text["table"]
    values = {int(i): float(v) for i, v in re.findall(r"^\$AA_ENC_COMP\[0,(\d+),AX6\]=(\S+)$",
                                                      eec, re.MULTILINE)}
    assert sorted(values) == list(range(9)) and values[8] == values[0] == 0.0
    for line in ("$AA_ENC_COMP_STEP[0,AX6]=45.000000", "$AA_ENC_COMP_MIN[0,AX6]=0.000000",
                 "$AA_ENC_COMP_MAX[0,AX6]=360.000000", "$AA_ENC_COMP_IS_MODULO[0,AX6]=1"):
        assert line in eec.splitlines()
    assert "the table covers one turn, 0 to 360 deg, and repeats cyclically" in eec
    assert not [line for line in eec.splitlines() if LINEAR_UNITS.search(line)]
    assert result["unconfirmed"][1].startswith("a modulo table whose _MIN differs")
    comp = CONTROLLERS["siemens"].reader(result["files"])
    assert comp.period_mm == 360.0
    constant = p.position_error[0]
    for shift in (0.0, 360.0, -720.0):
        up, down = left_arcsec(comp, p, shift)
        np.testing.assert_allclose((up + down) / 2, constant, atol=0.004)  # 6 decimals of deg
        np.testing.assert_allclose(up - down, 0.0, atol=0.004)


def test_sinumerik_closing_step_is_interpolated_from_the_last_target_to_the_first(tmp_path):
    """Between 315 and 360 deg the modulo table runs from the 315 deg error to the 0 deg one."""
    p = rotary()
    result, _ = written("siemens", p, tmp_path)
    comp = CONTROLLERS["siemens"].reader(result["files"])
    error_deg = (p.position_error - p.position_error[0]) / 3600
    expected = -(error_deg[-1] + (error_deg[0] - error_deg[-1]) / 3)  # 330 deg
    assert comp.offset_mm(330.0, 1) - comp.backlash_mm / 2 == pytest.approx(expected, abs=1e-6)


def test_sinumerik_0_and_360_measured_both_are_averaged(tmp_path):
    """A test over 0-360 deg measures 0 and 360 deg (one position): the modulo table holds the
    mean of both at _MIN and _MAX, and says how far that is from each (interpolation error)."""
    x = np.arange(0.0, 361.0, 45.0)
    p = rotary(x)
    p.mean_up[-1] += 4.0
    p.mean_down[-1] += 4.0  # 360 deg reads 4 arcsec above 0 deg (drift over the turn)
    result, text = written("siemens", p, tmp_path)
    first, last = (float(re.search(rf"^\$AA_ENC_COMP\[0,{i},AX6\]=(\S+)$", text["table"],
                                   re.MULTILINE)[1]) for i in (0, 8))
    assert first == last and "$AA_ENC_COMP_IS_MODULO[0,AX6]=1" in text["table"]
    assert result["points"] == 9 and result["interpolation_error_um"] == pytest.approx(2.0)


def test_sinumerik_partial_turn_and_linear_axis_are_not_modulo(tmp_path):
    p = rotary(np.arange(0.0, 181.0, 45.0))
    result, text = written("siemens", p, tmp_path)
    assert "$AA_ENC_COMP_IS_MODULO[0,AX6]=0" in text["table"].splitlines()
    assert "$AA_ENC_COMP_MAX[0,AX6]=180.000000" in text["table"].splitlines()
    assert "repeats cyclically" not in text["table"]
    assert CONTROLLERS["siemens"].reader(result["files"]).period_mm is None


def test_sinumerik_model_reads_a_modulo_table_as_the_control_applies_it(tmp_path):
    """The value at _MAX is followed at once by the one at _MIN (K3, 4.4.2.2): a table whose two
    ends differ jumps there, and a position one turn on reads the same value."""
    path = tmp_path / "eec.INI"
    path.write_text("%_N_AX_EEC_INI\nCHANDATA(1)\n"
                    "$AA_ENC_COMP[0,0,AX4]=0.001\n$AA_ENC_COMP[0,1,AX4]=0.002\n"
                    "$AA_ENC_COMP[0,2,AX4]=0.003\n$AA_ENC_COMP_STEP[0,AX4]=180.0\n"
                    "$AA_ENC_COMP_MIN[0,AX4]=0.0\n$AA_ENC_COMP_MAX[0,AX4]=360.0\n"
                    "$AA_ENC_COMP_IS_MODULO[0,AX4]=1\nM17\n")
    comp = model.siemens(path)
    offsets = comp.offset_mm(np.array([90.0, 450.0, -270.0, 359.999, 360.0]), 1)
    np.testing.assert_allclose(offsets, [-0.0015, -0.0015, -0.0015, -0.003, -0.001], atol=1e-8)
    assert model.table_flipped(comp).period_mm == 360.0  # --sign keeps the modulo range
    path.write_text(path.read_text().replace("_MAX[0,AX4]=360.0", "_MAX[0,AX4]=0.0")
                    .replace("_STEP[0,AX4]=180.0", "_STEP[0,AX4]=-180.0"))
    with pytest.raises(InputError, match="_MAX > \\$AA_ENC_COMP_MIN"):
        model.siemens(path)


# --------------------------------------------------------------------------- Fanuc


def test_fanuc_rotary_sheet_speaks_degrees_and_is_the_rotary_axis_type(tmp_path):
    _, text = written("fanuc", rotary(), tmp_path)
    lines = text["parameters"].splitlines()
    assert not [line for line in lines if LINEAR_UNITS.search(line)]
    for line in ("DETECTION UNIT = 0.001 deg", "REFERENCE POSITION = 0.0000 deg",
                 "1851 C = 6    ; backlash compensating value [detection units of 0.001 deg]",
                 "3620 C = 1    ; point number of the reference position",
                 "3621 C = 1    ; most negative point number",
                 "3622 C = 9    ; most positive point number",
                 "3624 C = 45000    ; point interval [detection units of 0.001 deg]"):
        assert line in lines
    assert any(line.startswith("3625 C = 360000    ; movement per rotation") for line in lines)
    assert "; detection unit 0.001 deg; interval 45 deg;" in text["parameters"]
    values = [int(v) for v in re.findall(r"^PITCH \d+ = (-?\d+)$", text["parameters"],
                                         re.MULTILINE)]
    assert len(values) == 9 and values[0] == values[-1] and sum(values[1:]) == 0


@pytest.mark.parametrize("reference_deg", [None, 90.0])
def test_fanuc_rotary_table_read_back_compensates_every_turn(tmp_path, reference_deg):
    """From the reference position (0 deg, or 90 deg) over one rotation; read back, the model
    repeats it every 3625: the error is taken out to half a detection unit (1.8 arcsec) around
    a constant, at the targets and a turn on either side; 1851 takes up the lost motion."""
    p = rotary()
    result, text = written("fanuc", p, tmp_path, reference_mm=reference_deg)
    if reference_deg:
        assert "REFERENCE POSITION = 90.0000 deg" in text["parameters"].splitlines()
    comp = CONTROLLERS["fanuc"].reader(result["files"])
    assert comp.period_mm == pytest.approx(360.0) and comp.nominal_mm[0] == (reference_deg or 0)
    assert comp.backlash_mm == pytest.approx(0.006)
    constant = p.position_error[list(p.target).index(reference_deg or 0.0)]  # 0 at the ref
    for shift in (0.0, 360.0, -360.0):
        up, down = left_arcsec(comp, p, shift)
        assert np.max(np.abs((up + down) / 2 - constant)) <= 1.8 + 1e-9
        np.testing.assert_allclose(up - down, 21.6 - LOST_ARCSEC, atol=1e-9)


def test_fanuc_model_refuses_a_rotary_table_that_is_not_one_rotation(tmp_path):
    result, text = written("fanuc", rotary(), tmp_path)
    path = result["files"]["parameters"]
    path.write_text(text["parameters"].replace("3621 C = 1 ", "3621 C = 0 ")
                    .replace("PITCH 1 =", "PITCH 0 = 0\nPITCH 1 ="))
    with pytest.raises(InputError, match="3621 = 3620"):
        model.fanuc(path)


def test_fanuc_partial_turn_is_the_linear_type_in_degrees(tmp_path):
    result, text = written("fanuc", rotary(np.arange(0.0, 181.0, 45.0)), tmp_path)
    assert "3625" not in text["parameters"] and "DETECTION UNIT = 0.001 deg" in text["parameters"]
    assert CONTROLLERS["fanuc"].reader(result["files"]).period_mm is None


def test_fanuc_magnified_values_do_not_drift(tmp_path):
    """Increments beyond 127 detection units need 3623 > 1; the values are increments of the
    correction rounded in magnified units, so the table read back stays within half a
    magnified unit of the correction everywhere (no drift along the axis)."""
    x = np.linspace(0.0, 1000.0, 11)
    e = 3.0 * x + 17.0 * np.sin(x / 37.0)  # 300 um per 100 mm section
    u = np.full_like(x, 0.2)
    p = AxisProfile("G1", "X", x, e - 2, e + 2, u, u, "measured", [])
    result, text = written("fanuc", p, tmp_path)
    magnification = int(re.search(r"^3623 X = (\d+)", text["parameters"], re.MULTILINE)[1])
    values = [int(v) for v in re.findall(r"^PITCH \d+ = (-?\d+)$", text["parameters"],
                                         re.MULTILINE)]
    assert magnification == 3 and max(map(abs, values)) <= 127
    comp = CONTROLLERS["fanuc"].reader(result["files"])
    left = p.position_error + 1000 * comp.offset_mm(x, 1) - comp.backlash_mm / 2 * 1000
    assert np.ptp(left) <= magnification * 1.0 + 1e-9
    assert result["quantisation_error_um"] <= magnification / 2 + 1e-9


# --------------------------------------------------------------------------- Heidenhain


def test_heidenhain_rotary_table_is_in_degrees_and_says_what_is_not_confirmed(tmp_path):
    p = rotary()
    result, text = written("heidenhain", p, tmp_path)
    com = text["table"].splitlines()
    assert "BEGIN R1_C.COM DEG" in com and "NR    C-POS           C-ERROR" in com
    assert ("; NOT CONFIRMED: unit keyword DEG of a rotary axis's .COM table (a linear axis's "
            "is MM)") in com
    rows = [line.split() for line in com if re.match(r"\d+\s", line)]
    assert [float(r[1]) for r in rows] == list(np.arange(0.0, 361.0, 45.0))
    assert rows[0][2] == rows[-1][2] == "+0.00000"
    assert "MP710: backlash with a rotary encoder (outside the control loop) [deg]" in \
        text["parameters"]
    assert not [line for line in [*com, *text["parameters"].splitlines()]
                if LINEAR_UNITS.search(line)]
    comp = CONTROLLERS["heidenhain"].reader(result["files"])
    up, down = left_arcsec(comp, p)
    np.testing.assert_allclose((up + down) / 2, p.position_error[0], atol=0.02)  # 5 decimals
    assert np.max(np.abs(up - down)) < 0.2  # MP710 to 0.0001 deg


# --------------------------------------------------------------------------- LinuxCNC


def test_linuxcnc_rotary_joint_closes_the_turn_in_degrees(tmp_path):
    p = rotary()
    result, text = written("linuxcnc", p, tmp_path)
    table = np.loadtxt(text["table"].splitlines())
    assert len(table) == 9 and table[-1, 0] == 360.0
    np.testing.assert_allclose(table[-1, 1:] - 360.0, table[0, 1:], atol=1e-9)
    ini = text["parameters"]
    assert "[JOINT_5]\nTYPE = ANGULAR\nCOMP_FILE = R1_C.comp\nCOMP_FILE_TYPE = 0\n" in ini
    assert "; the table covers 0 to 360 deg, its last line closing the turn" in ini
    assert not [line for line in ini.splitlines() if LINEAR_UNITS.search(line)]
    assert float(re.search(r"^; BACKLASH = (\S+)", ini, re.MULTILINE)[1]) == pytest.approx(
        LOST_ARCSEC / 3600, abs=1e-6)
    comp = CONTROLLERS["linuxcnc"].reader(result["files"])
    up, down = left_arcsec(comp, p)
    np.testing.assert_allclose(up, 0.0, atol=1e-3)
    np.testing.assert_allclose(down, 0.0, atol=1e-3)
    # between 315 and 360 deg the trim runs towards the 0 deg one instead of holding 315's
    trim = comp.offset_mm(337.5, 1) * 3600
    assert trim == pytest.approx(-(p.mean_up[-1] + p.mean_up[0]) / 2, abs=1e-3)


def test_linuxcnc_partial_turn_covers_the_measured_range_only(tmp_path):
    p = rotary(np.arange(0.0, 181.0, 45.0))
    _, text = written("linuxcnc", p, tmp_path)
    assert len(text["table"].splitlines()) == 5
    assert "; the table covers 0 to 180 deg; LinuxCNC does not wrap it" in text["parameters"]
