"""Direction-dependent tables of the table controllers: the Fanuc bidirectional pitch-error sheet
(3605#0, 3626, 3627), written when the reversal value varies along the axis, and read back by
the twin's controller model as the sheet's stated assumptions say.

Truth: a hand-made profile whose sheet is worked out by hand, the real ESS test (reversal -43.5
to +11.4 um along the axis), and the twin with the sheet applied by its controller model.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import backlash as bl
from features.readings import read_readings
from features.readings.errors import BacklashWarning, InputError
from models.physics import controller as model
from pipeline.cli import main
from pipeline.compensation import CONTROLLERS, read
from pipeline.compensation.active import read_active
from pipeline.compensation.common import Options
from pipeline.compensation.profile import AxisProfile, measured_profiles

PRESET = Path(__file__).resolve().parents[1] / "experiments" / "presets" / "compensation.toml"
UNIT_UM = 1.0  # the default detection unit


def varying() -> AxisProfile:
    """Targets every 10 mm; position error 0, 1, 2, 3, 4 um; lost motion 4 ... 12 um growing
    along the axis (indirect: mean_up = e - b/2, mean_down = e + b/2), u 0.1 um: the reversal
    varies far beyond its uncertainty."""
    x = np.arange(0.0, 41.0, 10.0)
    e, b = x / 10, 4 + x / 5
    u = np.full_like(x, 0.1)
    return AxisProfile("D1", "X", x, e - b / 2, e + b / 2, u, u, "measured", [])


def sheet(profile, folder: Path, **options) -> tuple[dict, str]:
    folder.mkdir(parents=True, exist_ok=True)
    result = CONTROLLERS["fanuc"].writer(profile, folder, Options(**options))
    return result, result["files"]["parameters"].read_text()


def settings(text: str) -> list[str]:
    """The sheet's setting lines without their comments."""
    lines = (line.split(";")[0].strip() for line in text.splitlines())
    return [line for line in lines if line]


@pytest.fixture
def ess_profile(ess_file):
    return measured_profiles(read_readings(ess_file))[0]


def test_bidirectional_sheet_lines_worked_out_by_hand(tmp_path):
    # corrections (-error, the + table 0 at the reference 0 mm): moving + -(up - up_0) = 0
    # everywhere; moving - -(down - up_0) = -4, -6, -8, -10, -12 um: 3627 = -4, increments -2
    result, text = sheet(varying(), tmp_path)
    assert settings(text) == [
        "DETECTION UNIT = 1 um", "REFERENCE POSITION = 0.0000 mm",
        "3605#0 X = 1", "1851 X = 0", "3620 X = 1", "3621 X = 1", "3622 X = 5",
        "3623 X = 1", "3624 X = 10000", "3626 X = 6", "3627 X = -4",
        *(f"PITCH {n} = 0" for n in range(1, 7)), *(f"PITCH {n} = -2" for n in range(7, 11))]
    assert result["quantisation_error_um"] == pytest.approx(0.0, abs=1e-9)
    for assumed in ("3626 to 3626 + 3622 - 3621", "not multiplied by 3623",
                    "1006#5 ZMI = 0", "applies 1851 with bidirectional tables"):
        assert re.search(rf"^; NOT CONFIRMED: .*{re.escape(assumed)}", text, re.MULTILINE)
        assert any(assumed in u for u in result["unconfirmed"])


def test_the_model_reads_both_tables_as_the_sheet_states(tmp_path):
    comp = CONTROLLERS["fanuc"].reader(sheet(varying(), tmp_path)[0]["files"])
    assert comp.source == "fanuc bidirectional pitch error" and comp.backlash_mm == 0
    assert np.allclose(1000 * comp.plus_mm, 0)
    assert np.allclose(1000 * comp.minus_mm, [-4, -6, -8, -10, -12])


def test_read_back_offsets_are_each_directions_correction(ess_profile, tmp_path):
    """At the targets, moving + and moving -, the offsets are the profile's corrections
    (-deviation, relative to the + deviation at the reference point) within half a detection
    unit: nothing of the reversal is left but the rounding."""
    p = ess_profile
    result, text = sheet(p, tmp_path)
    comp = CONTROLLERS["fanuc"].reader(result["files"])
    ref = int(np.argmin(np.abs(p.target - float(re.search(
        r"^REFERENCE POSITION = (\S+)", text, re.MULTILINE)[1]))))
    tolerance = UNIT_UM / 2 + result["interpolation_error_um"] + 1e-9
    for d, mean in ((1, p.mean_up), (-1, p.mean_down)):
        assert np.max(np.abs(1000 * comp.offset_mm(p.target, d)
                             + (mean - p.mean_up[ref]))) <= tolerance
    assert result["quantisation_error_um"] <= UNIT_UM / 2


def test_a_reversal_that_does_not_vary_keeps_the_one_table_sheet(tmp_path):
    p = varying()
    flat = replace(p, mean_up=p.position_error - 4, mean_down=p.position_error + 4)
    assert flat.reversal_variation()["direction_dependent"] is False
    _, text = sheet(flat, tmp_path / "flat")
    assert "3605#0" not in text and "3626" not in text and "1851 X = 8" in text
    predicted = replace(p, source="predicted")  # no test of the reversal: one table
    _, text = sheet(predicted, tmp_path / "predicted")
    assert "3605#0" not in text and "1851 X = 8" in text


def test_real_ess_sheet_leaves_no_reversal(ess_file):
    with pytest.warns(BacklashWarning, match="a table per direction for fanuc"):
        result = bl.compensate(ess_file, controller="fanuc,siemens")
    left = {w["controller"]: w["reversal_left_um"] for w in result.written}
    assert left["siemens"] == pytest.approx(29.768, abs=0.05)  # the scalar's
    assert left["fanuc"] < UNIT_UM  # two tables, each rounded to whole detection units
    text = next(v for k, v in result.contents.items() if k.endswith("_fanuc.txt")).decode()
    assert "3605#0 X = 1" in text and "1851 X = 0" in text


@pytest.mark.parametrize("other", ["error"])
def test_sign_flips_both_tables_and_3627(other, ess_profile, tmp_path):
    default = sheet(ess_profile, tmp_path / "default")[0]["files"]
    site = sheet(ess_profile, tmp_path / "site", sign=other)[0]["files"]
    numbers = {}
    for which, files in (("default", default), ("site", site)):
        lines = settings(files["parameters"].read_text())
        numbers[which] = np.array([float(line.split("=")[1]) for line in lines
                                   if line.startswith(("PITCH", "3627"))])
    assert len(numbers["default"]) == 11 and np.any(numbers["default"] != 0)
    assert np.array_equal(numbers["site"], -numbers["default"])
    x = ess_profile.target
    as_documented, as_site = read("fanuc", default), read("fanuc", site, other)
    for d in (1, -1):
        assert np.allclose(as_site.offset_mm(x, d), as_documented.offset_mm(x, d))
    assert not np.allclose(read("fanuc", site).offset_mm(x, -1), as_documented.offset_mm(x, -1))


def test_active_bidirectional_sheet_is_recognised_and_read_back(ess_file, ess_profile,
                                                                 tmp_path):
    files = sheet(ess_profile, tmp_path / "active")[0]["files"]
    comp = read_active(files["parameters"], "fanuc", ess_profile, Options())
    assert comp.source == "fanuc bidirectional pitch error"
    assert not np.allclose(comp.plus_mm, comp.minus_mm)
    # the test measured with that sheet active shows what it leaves (the rounding); the new
    # sheet is the active one again, within a detection unit at every target and direction
    readings = read_readings(ess_file)
    d = np.where(readings["direction"] == "+", 1.0, -1.0)
    shift = 1000 * comp.offset_mm(readings["target"].to_numpy(float), d)
    measured_with = readings.assign(deviation_um=readings["deviation_um"] + shift,
                                    measured=readings["measured"] + shift / 1000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        again = bl.compensate(measured_with, controller="fanuc", active=files["parameters"])
    changes = again.written[0]["changes"]
    assert np.max(np.abs(changes[["change_plus_um", "change_minus_um"]].to_numpy())) <= UNIT_UM


def test_active_bidirectional_sheet_of_another_axis_is_refused(ess_profile, tmp_path):
    files = sheet(replace(ess_profile, axis="Y"), tmp_path)[0]["files"]
    text = files["parameters"].read_text()
    assert "3605#0 Y = 1" in text
    with pytest.raises(InputError, match="a compensation of axis Y"):
        read_active(files["parameters"], "fanuc", ess_profile, Options())


def test_model_refuses_a_bidirectional_sheet_without_its_minus_table(tmp_path):
    path = sheet(varying(), tmp_path)[0]["files"]["parameters"]
    text = path.read_text()
    path.write_text(re.sub(r"^3626 .*\n", "", text, flags=re.MULTILINE))
    with pytest.raises(InputError, match="missing parameter 3626"):
        model.fanuc(path)
    path.write_text(re.sub(r"^PITCH 10 = .*\n", "", text, flags=re.MULTILINE))
    with pytest.raises(InputError, match=r"and 6\.\.10 \(3626, travel in the - direction\)"):
        model.fanuc(path)
    path.write_text(text.replace("3626 X = 6", "3626 X = 5"))  # overlaps the + table
    with pytest.raises(InputError, match="expected pitch error values"):
        model.fanuc(path)


def test_full_turn_rotary_axis_gets_two_rotary_type_tables(tmp_path):
    x = np.arange(0.0, 360.0, 45.0)
    e, b = 30.0 * np.sin(np.radians(x)) + 5.0, 20.0 + 10.0 * np.cos(np.radians(x))
    u = np.full_like(x, 0.2)
    p = AxisProfile("R1", "C", x, e - b / 2, e + b / 2, u, u, "measured", [])
    result, text = sheet(p, tmp_path)
    lines = settings(text)
    assert "3605#0 C = 1" in lines and "3625 C = 360000" in lines and "3626 C = 10" in lines
    values = {int(m[1]): int(m[2]) for m in re.finditer(r"^PITCH (\d+) = (\S+)", text,
                                                          re.MULTILINE)}
    for first in (1, 10):  # each table: one rotation, its first point holds its last's value
        table = [values[n] for n in range(first, first + 9)]
        assert sum(table[1:]) == 0 and table[0] == table[-1]
    comp = CONTROLLERS["fanuc"].reader(result["files"])
    assert comp.period_mm == pytest.approx(360.0)
    half_unit = 3600 * 0.001 / 2  # [arcsec] half the 0.001 deg detection unit
    for shift in (0.0, 360.0):  # every turn: each direction lands on the + error at 0 deg
        for d, mean in ((1, p.mean_up), (-1, p.mean_down)):
            left = mean + 3600 * comp.offset_mm(x + shift, d)
            assert np.max(np.abs(left - p.mean_up[0])) <= half_unit + 1e-6


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """The compensation preset on one machine and one visit (seed 11): backlash with a wear
    bump along the screw, so the reversal varies along the axis."""
    folder = tmp_path_factory.mktemp("twin")
    text = PRESET.read_text().replace("machines = 2", "machines = 1").replace(
        "visits = 3", "visits = 1")
    (folder / "campaign.toml").write_text(text)
    assert main(["simulate", "--config", str(folder / "campaign.toml"), "--seed", "11",
                 "--out", str(folder / "out")]) == 0
    return folder / "out" / "readings.csv"


def test_twin_closed_loop_beats_the_one_table_sheet(twin, tmp_path, capsys, monkeypatch):
    from pipeline.compensation import fanuc

    figures = {}
    for kind in ("bidirectional", "one table"):
        if kind == "one table":
            monkeypatch.setattr(fanuc, "direction_dependent", lambda profile: False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BacklashWarning)
            code = main(["compensate", str(twin), "--controller", "fanuc", "--verify",
                         "--json", "--out", str(tmp_path / kind)])
        assert code == 0
        result = json.loads(capsys.readouterr().out)
        assert result["axes"][0]["reversal_variation"]["direction_dependent"]
        (check,) = result["verify"]
        assert check["passed"]
        figures[kind] = check["after"]
        text = Path(result["files"][0]["files"]["parameters"]).read_text()
        assert ("3605#0 X = 1" in text) == (kind == "bidirectional")
    assert figures["bidirectional"]["B"] < figures["one table"]["B"]
    assert figures["bidirectional"]["E"] < figures["one table"]["E"]
