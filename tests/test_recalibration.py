"""Recalibration (``--active``), reversal values varying along the axis, and ``--sign``.

Truth: the real ecmc tests (a half-strength file made from them and taken off their readings
must give the raw test's file back), hand-computed chi-square values, and the twin with a
compensation applied by its controller model.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings import read_readings
from features.readings.errors import BacklashWarning
from pipeline.cli import main
from pipeline.compensation import CONTROLLERS, read
from pipeline.compensation.common import Options
from pipeline.compensation.profile import AxisProfile, measured_profiles

PRESET = Path(__file__).resolve().parents[1] / "experiments" / "presets" / "compensation.toml"


def _write(profile, name: str, folder: Path, **options) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    return CONTROLLERS[name].writer(profile, folder, Options(**options))["files"]


def _measured_with(readings: pd.DataFrame, comp, scale: float) -> pd.DataFrame:
    """The readings a test gives with ``comp`` active: the controller adds its offset to the
    command at each reading's target and direction, so the axis lands shifted by it."""
    d = np.where(readings["direction"] == "+", 1.0, -1.0)
    shift = scale * comp.offset_mm(readings["target"].to_numpy(float), d)
    return readings.assign(deviation_um=readings["deviation_um"] + shift,
                           measured=readings["measured"] + shift / scale)


def _read_written(result, name: str, folder: Path):
    w = next(w for w in result.written if w["controller"] == name)
    return read(name, {r: folder / f for r, f in w["files"].items() if r != "changes"})


@pytest.fixture(params=["ess_file", "psi_file"])
def real(request):
    path = request.getfixturevalue(request.param)
    readings = read_readings(path)
    return readings, measured_profiles(readings)[0]


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_half_strength_active_file_gives_the_raw_tests_file_back(name, real, tmp_path):
    readings, p = real
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        raw = bl.compensate(readings, controller=name)
        raw.write(tmp_path / "raw")
        half = _write(replace(p, mean_up=p.mean_up / 2, mean_down=p.mean_down / 2), name,
                      tmp_path / "half")
        active = read(name, half)
        new = bl.compensate(_measured_with(readings, active, p.scale), controller=name,
                            active=list(half.values()))
    new.write(tmp_path / "new")
    want = _read_written(raw, name, tmp_path / "raw")
    got = _read_written(new, name, tmp_path / "new")
    for d in (1, -1):
        expected = 1000 * want.offset_mm(p.target, d)
        assert np.all(np.abs(1000 * got.offset_mm(p.target, d) - expected)
                      <= np.maximum(0.1, 0.02 * np.abs(expected)))
    # the change per target is what the new file adds beyond the active one
    changes = new.written[0]["changes"]
    assert np.allclose(changes["change_plus_um"],
                       1000 * (got.offset_mm(p.target, 1) - active.offset_mm(p.target, 1)))
    assert np.allclose(changes["target_mm"], p.target)


def test_recalibration_on_the_command_line_reports_the_change(ess_file, tmp_path, capsys):
    readings = read_readings(ess_file)
    p = measured_profiles(readings)[0]
    half = _write(replace(p, mean_up=p.mean_up / 2, mean_down=p.mean_down / 2), "siemens",
                  tmp_path / "half")
    data = tmp_path / "measured_with_half.csv"
    _measured_with(readings, read("siemens", half), p.scale).to_csv(data, index=False)
    out = tmp_path / "out"
    assert main(["compensate", str(data), "--controller", "840d", "--active",
                 str(half["table"]), "--active", str(half["parameters"]), "--out", str(out),
                 "--json"]) == 0
    captured = capsys.readouterr()
    files = json.loads(captured.out)["files"][0]
    changes = pd.read_csv(files["files"]["changes"])
    pd.testing.assert_frame_equal(changes, pd.DataFrame(files["changes"]), atol=1e-6)
    # one table + scalar: the new file doubles the half-strength one at every target
    assert np.allclose(changes["new_plus_um"], 2 * changes["active_plus_um"], atol=1e-3)
    assert np.allclose(changes["change_minus_um"], changes["active_minus_um"], atol=1e-3)
    assert "change from the active file [um]: moving +" in captured.err
    assert files["backlash"] == pytest.approx(p.backlash, abs=1e-4)


@pytest.fixture
def ess_profile(ess_file):
    return measured_profiles(read_readings(ess_file))[0]


def _other_axis(p, name, folder):
    return list(_write(replace(p, axis="Y"), name, folder).values())


def _inches(p, name, folder):
    comp = _write(p, name, folder)["table"]
    table = np.loadtxt(comp, ndmin=2) / 25.4
    np.savetxt(comp, table, fmt="%.7f")
    return [comp]


def _text_file(text: str):
    def make(p, name, folder):
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "active.txt"
        path.write_text(text)
        return [path]
    return make


def _bad_csv(p, name, folder):
    path = _write(p, "csv", folder)["table"]
    frame = pd.read_csv(path).astype({"correction_plus_um": object})
    frame.loc[2, "correction_plus_um"] = "n/a"
    frame.to_csv(path, index=False)
    return [path]


def _ini_without_table(p, name, folder):
    return [_write(p, "linuxcnc", folder)["parameters"]]


@pytest.mark.parametrize("controller, make, extra, message", [  # extra: more controllers
    ("linuxcnc", _other_axis, [], "a compensation of axis Y; the tests are of axis X"),
    ("siemens", _other_axis, [], "a compensation of axis Y; the tests are of axis X"),
    ("fanuc", _other_axis, [], "a compensation of axis Y; the tests are of axis X"),
    ("csv", _other_axis, [], "a compensation of axis Y; the tests are of axis X"),
    ("linuxcnc", lambda p, n, f: list(_write(p, "siemens", f).values()), [],
     "a Siemens SINUMERIK file; the new file is for LinuxCNC: give --controller siemens"),
    ("marlin", lambda p, n, f: list(_write(p, "grblhal", f).values()), [],
     "a grblHAL file; the new file is for Marlin"),
    ("fanuc", lambda p, n, f: list(_write(p, n, f, fanuc_unit_um=0.1).values()), [],
     "detection unit 0.1 um; the new sheet is written in 1 um"),
    ("linuxcnc", _inches, [], "the table covers 0.590551 to 2.19685, the tests 15 to 55.8 mm"),
    ("linuxcnc", _text_file("hello\n"), [], "not a compensation file of a supported controller"),
    ("linuxcnc", _text_file(""), [], "not a compensation file of a supported controller"),
    ("heidenhain", _text_file("BEGIN T.COM INCH\nNR X-POS X-ERROR\n0 0 0\n[END]\n"), [],
     "a table in INCH; expected MM"),
    ("csv", _bad_csv, [], ("row 4, column 'correction_plus_um', --active: expected a finite "
     "number")),
    ("linuxcnc", _ini_without_table, [], "COMP_FILE ess_mcu1025_X.comp is set but not given"),
    ("linuxcnc", lambda p, n, f: [f / "missing.comp"], [], "cannot read compensation file"),
    ("linuxcnc", lambda p, n, f: list(_write(p, n, f).values()), ["csv"],
     ("--controller: the new file is the active file plus the residual: give its one "
     "controller, not 2")),
    ("siemens", lambda p, n, f: [_write(p, n, f / "1")["table"], _write(p, n, f / "2")["table"]],
     [], "--active: a second table file"),
])
def test_bad_active_file_is_one_line_and_writes_nothing(controller, make, extra, message,
                                                        ess_file, ess_profile, tmp_path, capsys):
    files = make(ess_profile, controller, tmp_path / "active")
    out = tmp_path / "out"
    argv = ["compensate", str(ess_file), "--controller", ",".join([controller, *extra]),
            "--out", str(out)]
    for path in files:
        argv += ["--active", str(path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists() or not any(out.iterdir())


# Per controller: the line of its written file whose number becomes NaN or infinity.
NON_FINITE = {"linuxcnc": r"^(25\.2000000 )\S+", "siemens": r"^(\$AA_ENC_COMP\[0,1,AX1\]=)\S+",
              "fanuc": r"^(PITCH \d+ = )\S+", "heidenhain": r"^(1 +\+25\.2000 +)\S+",
              "marlin": r"^(M425 X)\S+", "reprap": r"^(M425 X)\S+", "grblhal": r"^(\$160=)\S+",
              "csv": r"^(ess_mcu1025,X,measured,25\.200000,(?:[^,]*,){6})[^,]+"}


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("controller", list(CONTROLLERS))
def test_active_file_holding_a_non_finite_value_is_refused(controller, value, ess_file,
                                                           ess_profile, tmp_path, capsys):
    """Every --active reader refuses NaN and infinity: LinuxCNC's own sscanf reads them, and
    a new table built on them would be NaN where the controller moves the axis."""
    import re

    files = _write(ess_profile, controller, tmp_path / "active")
    changed = 0
    for path in files.values():
        text = path.read_text()
        new, n = re.subn(NON_FINITE[controller], rf"\g<1>{value}", text, count=1,
                         flags=re.MULTILINE)
        path.write_text(new)
        changed += n
    assert changed == 1, controller
    out = tmp_path / "out"
    argv = ["compensate", str(ess_file), "--controller", controller, "--out", str(out)]
    for path in files.values():
        argv += ["--active", str(path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--active" in err, err
    assert "finite number" in err and f"{value!r}" in err or controller == "csv", err
    assert not out.exists() or not any(out.iterdir())


def test_active_needs_one_machine_axis_of_measured_tests(ess_file, ess_profile, tmp_path):
    files = list(_write(ess_profile, "csv", tmp_path / "a").values())
    readings = read_readings(ess_file)
    two = tmp_path / "two.csv"
    pd.concat([readings, readings.assign(machine_id="other")]).to_csv(two, index=False)
    with pytest.raises(bl.InputError, match="the data hold ess_mcu1025 X, other X") as err:
        bl.compensate(two, controller="csv", active=files)
    assert err.value.parameter == "active"
    from models.serving.registry import TrainedModel, make

    X = pd.DataFrame({"target": [15.0, 55.8], "feed_mm_min": [500.0] * 2})
    model = TrainedModel("constant", make("constant").fit(X, np.array([3.0, 3.0])),
                         ["target", "feed_mm_min"], "iso", 0.2,
                         {"target": (15.0, 55.8), "feed_mm_min": (500.0, 500.0)}, X)
    with pytest.raises(bl.InputError, match="applies to measured tests") as err:
        bl.compensate(model, controller="csv", active=files)
    assert err.value.parameter == "active"


def test_active_file_without_an_axis_name_is_noted(ess_file, ess_profile, tmp_path):
    comp = _write(ess_profile, "linuxcnc", tmp_path / "a")["table"]  # the .comp alone
    with pytest.warns(BacklashWarning, match="do not name their axis: taken as axis X"):
        result = bl.compensate(ess_file, controller="linuxcnc", active=comp)
    assert result.active[("ess_mcu1025", "X")].nominal_mm.tolist() == ess_profile.target.tolist()


# --------------------------------------------------------------------------- twin closed loop


@pytest.fixture(scope="module")
def one_machine(tmp_path_factory):
    """The compensation preset on one machine and one visit (seed 11)."""
    folder = tmp_path_factory.mktemp("campaign")
    text = PRESET.read_text().replace("machines = 2", "machines = 1").replace(
        "visits = 3", "visits = 1")
    (folder / "campaign.toml").write_text(text)
    return folder / "campaign.toml"


def test_twin_recalibration_closes_the_loop(one_machine, tmp_path, capsys):
    """The twin measured with a half-strength LinuxCNC table active; the new file is the
    active one plus the residual, and --verify re-measures with the active file ('before')
    and with the new one ('after')."""
    from pipeline.workflows.simulate import simulate

    raw = simulate(one_machine, seed=11)
    raw.write(tmp_path / "raw")
    p = measured_profiles(read_readings(tmp_path / "raw" / "readings.csv"))[0]
    half = _write(replace(p, mean_up=p.mean_up / 2, mean_down=p.mean_down / 2), "linuxcnc",
                  tmp_path / "half")
    active = read("linuxcnc", half)
    simulate(one_machine, seed=11,
             compensation={(p.machine_id, p.axis): active}).write(tmp_path / "with_half")
    code = main(["compensate", str(tmp_path / "with_half" / "readings.csv"), "--controller",
                 "linuxcnc", "--active", str(half["table"]), "--active", str(half["parameters"]),
                 "--verify", "--json", "--out", str(tmp_path / "out")])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    check = result["verify"][0]
    # before: the axis with the half-strength table, about half its raw errors left
    assert check["before"]["B"] > 0.35 * -p.reversal.min() and check["before"]["E"] > 5
    assert check["passed"] and check["ratio_B"] < 0.15 and check["ratio_E"] < 0.15
    # the new file is the raw tests' full table, up to the twin's play and noise
    new = read("linuxcnc", {r: Path(f) for r, f in result["files"][0]["files"].items()
                            if r != "changes"})
    full = read("linuxcnc", _write(p, "linuxcnc", tmp_path / "full"))
    for d in (1, -1):
        assert np.max(np.abs(new.offset_mm(p.target, d) - full.offset_mm(p.target, d))) < 0.5e-3


# --------------------------------------------------------------------------- reversal test


def _profile(reversal, u_reversal) -> AxisProfile:
    x = np.linspace(0.0, 100.0, len(reversal))
    b = np.asarray(reversal, float)
    u = np.full_like(x, u_reversal / np.sqrt(2))  # u(B_i)^2 = u_up^2 + u_down^2
    return AxisProfile("M", "X", x, b / 2, -b / 2, u, u, "measured", [])


def test_reversal_test_against_hand_computed_chi_square():
    # B = -4, -6, -5 around their mean -5: chi2 = (1 + 1 + 0) / u^2; 2 dof: p = exp(-chi2 / 2)
    loose = _profile([-4.0, -6.0, -5.0], 0.5).reversal_variation()
    assert loose["chi2"] == pytest.approx(8.0) and loose["dof"] == 2
    assert loose["p"] == pytest.approx(np.exp(-4.0)) and loose["direction_dependent"] is False
    tight = _profile([-4.0, -6.0, -5.0], 0.25).reversal_variation()
    assert tight["chi2"] == pytest.approx(32.0) and tight["p"] == pytest.approx(np.exp(-16.0))
    assert tight["direction_dependent"] is True
    assert tight["scalar_um"] == pytest.approx(5.0) and tight["scalar_leaves_um"] == 1.0
    untestable = _profile([-4.0, -6.0], 0.0).reversal_variation()
    assert untestable["direction_dependent"] is None and untestable["p"] is None


def test_real_ess_reversal_varies_and_psi_does_not(ess_file, psi_file, capsys):
    with pytest.warns(BacklashWarning, match="a scalar backlash cannot compensate it"):
        ess = bl.compensate(ess_file, controller="all")
    r = ess.reversal[0]
    assert r["direction_dependent"] and r["p"] < 1e-100
    assert r["scalar_um"] == pytest.approx(13.6916, abs=1e-4)
    # the scalar leaves B_i + b at the ends of the range: -43.459 + 13.692 and 11.374 + 13.692
    assert r["scalar_leaves_um"] == pytest.approx(29.768, abs=1e-3)
    left = {w["controller"]: w["reversal_left_um"] for w in ess.written}
    assert left["linuxcnc"] < 1e-3 and left["csv"] < 1e-3  # a table per direction
    for name in ("siemens", "heidenhain", "marlin", "reprap", "grblhal"):
        assert left[name] == pytest.approx(29.768, abs=0.05)
    # bidirectional pitch error tables in whole 1 um detection units
    assert left["fanuc"] < 1.0
    per_direction = {w["controller"]: w["per_direction"] for w in ess.written}
    assert per_direction == {**dict.fromkeys(("linuxcnc", "csv", "fanuc"), True),
                             **dict.fromkeys(("siemens", "heidenhain", "marlin", "reprap",
                                              "grblhal"), False)}
    axis = ess.to_dict()["axes"][0]["reversal_variation"]
    assert axis["direction_dependent"] is True and axis["dof"] == 4
    with warnings.catch_warnings():  # no note of a varying reversal (the axis's name is noted)
        warnings.simplefilter("error", BacklashWarning)
        warnings.filterwarnings("ignore", "(?s).*the file states no axis", BacklashWarning)
        psi = bl.compensate(psi_file, controller="siemens")
    assert psi.reversal[0]["direction_dependent"] is False and psi.reversal[0]["p"] > 0.05


def test_linuxcnc_columns_carry_each_directions_error(ess_file, ess_profile, tmp_path):
    comp = _write(ess_profile, "linuxcnc", tmp_path)["table"]
    table = np.loadtxt(comp)
    assert np.allclose(1000 * (table[:, 1] - table[:, 0]), ess_profile.mean_up, atol=1e-4)
    assert np.allclose(1000 * (table[:, 2] - table[:, 0]), ess_profile.mean_down, atol=1e-4)


# --------------------------------------------------------------------------- sign convention


@pytest.mark.parametrize("name, documented", [("siemens", "error"), ("fanuc", "correction"),
                                              ("heidenhain", "error")])
def test_sign_option_writes_the_other_convention_and_reads_it_back(name, documented,
                                                                   ess_profile, tmp_path):
    other = "correction" if documented == "error" else "error"
    default = _write(ess_profile, name, tmp_path / "default")
    site = _write(ess_profile, name, tmp_path / "site", sign=other)
    role = "parameters" if name == "fanuc" else "table"
    numbers = {}
    for which, files in (("default", default), ("site", site)):
        text = files[role].read_text()
        lines = [ln for ln in text.splitlines()
                 if ln.startswith(("$AA_ENC_COMP[", "PITCH")) or ln[:1].isdigit()
                 and name == "heidenhain"]
        numbers[which] = np.array([float(ln.split("=")[-1] if "=" in ln else ln.split()[-1])
                                   for ln in lines])
    assert len(numbers["default"]) > 3 and np.any(numbers["default"] != 0)
    assert np.array_equal(numbers["site"], -numbers["default"])
    assert documented in default[role].read_text() or name == "fanuc"
    x = ess_profile.target
    as_documented = read(name, default)
    as_site = read(name, site, other)
    misread = read(name, site)  # the site's file read with the manual's convention
    for d in (1, -1):
        assert np.allclose(as_site.offset_mm(x, d), as_documented.offset_mm(x, d))
    assert as_site.backlash_mm == misread.backlash_mm == as_documented.backlash_mm
    assert not np.allclose(misread.offset_mm(x, 1), as_documented.offset_mm(x, 1))


def test_active_file_in_the_sites_convention_is_read_with_it(ess_file, ess_profile, tmp_path):
    """A SINUMERIK table written as corrections (``--sign correction``) and active: read with
    the same convention, the recalibration gives the raw test's table back; read with the
    manual's, the active table counts twice the wrong way."""
    readings = read_readings(ess_file)
    p = ess_profile
    half = _write(replace(p, mean_up=p.mean_up / 2, mean_down=p.mean_down / 2), "siemens",
                  tmp_path / "half", sign="correction")
    measured = _measured_with(readings, read("siemens", half, "correction"), p.scale)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        raw = bl.compensate(readings, controller="siemens", sign="correction")
        new = bl.compensate(measured, controller="siemens", sign="correction",
                            active=list(half.values()))
        misread = bl.compensate(measured, controller="siemens", active=list(half.values()))
    def values(result, name):  # the settings, without the comment header
        return [ln for ln in result.contents[name].decode().splitlines() if ln.startswith("$")]

    for name in ("ess_mcu1025_X_AX_EEC.INI", "ess_mcu1025_X_MD32450.INI"):
        assert values(new, name) == values(raw, name)
    assert values(misread, "ess_mcu1025_X_AX_EEC.INI") != values(raw, "ess_mcu1025_X_AX_EEC.INI")


def test_sign_is_fixed_by_the_format_for_positions_and_named_columns(ess_file, tmp_path):
    with pytest.warns(BacklashWarning, match="--sign does not apply to linuxcnc, csv"):
        signed = bl.compensate(ess_file, controller="linuxcnc,csv,siemens", sign="correction")
    plain = bl.compensate(ess_file, controller="linuxcnc,csv,siemens")
    for name, content in plain.contents.items():
        assert (signed.contents[name] == content) != ("EEC" in name), name
    assert [w["sign"] for w in signed.written] == [None, None, "correction"]


def test_bad_sign_names_the_option(ess_file, tmp_path, capsys):
    with pytest.raises(bl.InputError, match="must be None or a str among") as err:
        bl.compensate(ess_file, controller="siemens", sign="minus")
    assert err.value.parameter == "sign"
    assert main(["compensate", str(ess_file), "--controller", "siemens", "--sign", "minus",
                 "--out", str(tmp_path / "o")]) == 2
    assert "invalid choice: 'minus'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
