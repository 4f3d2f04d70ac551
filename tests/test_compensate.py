"""`backlash compensate`: controller files, their conventions read back, and the closed loop.

Golden files: ``BACKLASH_UPDATE_GOLDEN=1 pytest tests/test_compensate.py`` rewrites them from a
hand-made profile; a change to any writer then shows up as a diff to review.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features import iso230
from features.readings import read_readings
from models.physics import controller as ctl
from pipeline.cli import main
from pipeline.compensation import CONTROLLERS
from pipeline.compensation.common import Options
from pipeline.compensation.profile import AxisProfile, grid, resample
from pipeline.compensation.verify import closed_loop

GOLDEN = Path(__file__).parent / "golden"
PRESET = Path(__file__).resolve().parents[1] / "experiments" / "presets" / "compensation.toml"


def golden_profile() -> AxisProfile:
    """Irregular targets; lead error 10 um/m plus a 1.5 um wave; backlash 4 um with a 1 um
    wear bump at 150 mm (indirect axis: mean_up = e - b/2, mean_down = e + b/2)."""
    x = np.array([0.0, 48.7, 101.3, 150.0, 203.9, 250.0])
    e = 0.01 * x + 1.5 * np.sin(x / 40)
    b = 4 + np.exp(-((x - 150) / 60) ** 2)
    u = np.full_like(x, 0.2)
    return AxisProfile("G1", "X", x, e - b / 2, e + b / 2, u, u, "measured", [])


def written_files(name: str, out: Path, profile=None) -> dict:
    return CONTROLLERS[name].writer(profile or golden_profile(), out, Options())


# The controllers pinned by a golden folder: the exact bytes of a format whose manual the
# writer follows. A controller added later needs none: the record's own tests
# (tests/test_controllers.py: read back, axis kinds, recognised, for every record) and the
# closed-loop check below cover it.
PINNED = sorted(p.name for p in GOLDEN.iterdir() if p.is_dir())


def test_every_golden_folder_is_a_controller():
    assert set(PINNED) <= set(CONTROLLERS)


@pytest.mark.parametrize("name", PINNED)
def test_golden_file_per_controller(name, tmp_path):
    result = written_files(name, tmp_path)
    folder = GOLDEN / name
    if os.environ.get("BACKLASH_UPDATE_GOLDEN"):
        folder.mkdir(parents=True, exist_ok=True)
        for path in result["files"].values():
            (folder / path.name).write_bytes(path.read_bytes())
    for path in result["files"].values():
        assert path.read_bytes() == (folder / path.name).read_bytes(), path.name


@pytest.mark.parametrize("name", PINNED)
def test_golden_files_read_back_with_the_controllers_semantics(name):
    """Each golden file, parsed as its controller reads it and applied to the profile, leaves
    only what that format cannot carry: nothing for per-direction tables; the reversal's
    variation along the axis (and interpolation/rounding) for one-table formats; the whole
    position error for scalar-only ones."""
    p = golden_profile()
    folder = GOLDEN / name
    roles = {"linuxcnc": {"table": "G1_X.comp", "parameters": "G1_X_linuxcnc.ini"},
             "siemens": {"table": "G1_X_AX_EEC.INI", "parameters": "G1_X_MD32450.INI"},
             "fanuc": {"parameters": "G1_X_fanuc.txt"},
             "heidenhain": {"table": "G1_X.COM", "parameters": "G1_X_heidenhain_MP.txt"},
             "marlin": {"parameters": "G1_X_marlin.gcode"},
             "reprap": {"parameters": "G1_X_reprap.gcode"},
             "grblhal": {"parameters": "G1_X_grblhal.txt"},
             "csv": {"table": "G1_X_compensation.csv"}}[name]
    comp = ctl.load(name, {k: folder / v for k, v in roles.items()})
    up = p.mean_up + 1000 * comp.offset_mm(p.target, 1)
    down = p.mean_down + 1000 * comp.offset_mm(p.target, -1)
    reversal_after = up - down
    if name in ("linuxcnc", "csv"):
        assert np.max(np.abs(up)) < 1e-3 and np.max(np.abs(down)) < 1e-3
        return
    # the scalar takes off the mean lost motion; its variation along the axis remains
    # written to 1 nm (SINUMERIK), 0.1 um (others) or whole detection units of 1 um (Fanuc)
    rounding_b = {"fanuc": 0.5, "siemens": 1e-3}.get(name, 0.05)
    assert np.allclose(reversal_after, p.reversal - p.reversal.mean(), atol=rounding_b)
    assert np.max(np.abs(reversal_after)) <= np.ptp(p.reversal) + rounding_b
    position_after = (up + down) / 2
    if name in ("siemens", "heidenhain", "fanuc"):
        points = grid(p.target, None, 10_000)
        _, interp = resample(p.target, p.position_error, points)
        rounding = 0.5 if name == "fanuc" else 1e-3  # 1 um detection unit
        assert np.ptp(position_after) <= 2 * (interp + rounding)
        assert np.ptp(position_after) < 0.2 * np.ptp(p.position_error) + 2 * rounding
    else:  # scalar only: the position error is untouched
        assert np.allclose(position_after, p.position_error, atol=1e-3)


def test_linuxcnc_table_layout_and_reading_rules(tmp_path):
    p = golden_profile()
    comp_path = written_files("linuxcnc", tmp_path)["files"]["table"]
    rows = [line.split() for line in comp_path.read_text().splitlines()]
    assert all(len(r) == 3 for r in rows) and len(rows) == len(p.target)  # no header
    nominal = np.array([float(r[0]) for r in rows])
    assert np.all(np.diff(nominal) > 0)
    # actual moving + = nominal + deviation: a lost-motion axis is short going up
    assert float(rows[2][1]) == pytest.approx(p.target[2] + p.mean_up[2] / 1000, abs=1e-7)
    # LinuxCNC stops at the first line that is not three numbers
    comp_path.write_text(comp_path.read_text() + "# comment\n999 1000 1001\n")
    assert len(ctl.linuxcnc(comp_path).nominal_mm) == len(p.target)
    comp_path.write_text("".join(f"{i} {i} {i}\n" for i in range(257)))
    with pytest.raises(Exception, match="at most 256"):
        ctl.linuxcnc(comp_path)


def _apply(readings: pd.DataFrame, comp) -> pd.DataFrame:
    """Re-apply a controller's offsets to the readings: the axis lands shifted by the offset
    the controller adds to the commanded position at that target and direction."""
    d = np.where(readings["direction"] == "+", 1.0, -1.0)
    shift = 1000 * comp.offset_mm(readings["target"].to_numpy(float), d)
    return readings.assign(deviation_um=readings["deviation_um"] + shift)


@pytest.mark.parametrize("fixture", ["ess_file", "psi_file"])
def test_linuxcnc_table_shrinks_reversal_and_E_on_real_tests(fixture, request, tmp_path, capsys):
    path = request.getfixturevalue(fixture)
    assert main(["compensate", str(path), "--controller", "linuxcnc", "--out",
                 str(tmp_path / "out"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    files = result["files"][0]["files"]
    comp = ctl.linuxcnc(files["table"], files["parameters"])
    readings = read_readings(path)
    clean = readings.loc[~iso230.outliers(readings)]  # the means the table was made from
    before, after = iso230.per_target(clean), iso230.per_target(_apply(clean, comp))
    u_b = np.sqrt(after["s_up"] ** 2 / after["n_up"] + after["s_down"] ** 2 / after["n_down"])
    ok = (after["B_i"].abs() <= 2 * u_b) | (after["B_i"].abs() <= 0.2 * before["B_i"].abs())
    assert ok.all()
    e_before = iso230.axis_figures(clean, before)["E"].iloc[0]
    e_after = iso230.axis_figures(clean, after)["E"].iloc[0]
    u_mean = np.sqrt(np.r_[after["s_up"] ** 2 / after["n_up"],
                           after["s_down"] ** 2 / after["n_down"]]).max()
    assert e_after <= max(0.2 * e_before, 2 * u_mean)
    # the same check catches a flipped sign: the reversal values double
    flipped = iso230.per_target(_apply(clean, ctl.flipped(comp)))
    assert not ((flipped["B_i"].abs() <= 2 * u_b)
                | (flipped["B_i"].abs() <= 0.2 * before["B_i"].abs())).all()
    assert np.allclose(flipped["B_i"], 2 * before["B_i"], rtol=1e-3, atol=1e-3)


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """The compensation preset: indirect axis, backlash with a wear bump growing with hours,
    linear + periodic lead error and an Abbe bow, irregular targets."""
    out = tmp_path_factory.mktemp("twin")
    assert main(["simulate", "--config", str(PRESET), "--seed", "11", "--out", str(out)]) == 0
    return out / "readings.csv"


def test_twin_closed_loop_linuxcnc(twin, tmp_path, capsys):
    code = main(["compensate", str(twin), "--controller", "linuxcnc,siemens",
                 "--out", str(tmp_path), "--verify", "--json"])
    assert code == 0
    checks = json.loads(capsys.readouterr().out)["verify"]
    assert len(checks) == 4 and all(c["passed"] for c in checks)
    for c in checks:
        assert c["before"]["B"] > 8  # backlash 6 um + wear + bump
        if c["controller"] == "linuxcnc":
            assert c["ratio_B"] <= 0.2 and c["ratio_E"] <= 0.3
        else:  # one position table + scalar backlash: the wear bump's variation remains
            assert c["ratio_B"] <= 0.35 and c["ratio_E"] <= 0.35
    assert (tmp_path / "verify" / "linuxcnc" / "verify.html").is_file()


def test_twin_closed_loop_catches_a_flipped_sign(twin, tmp_path):
    assert main(["compensate", str(twin), "--controller", "linuxcnc", "--out",
                 str(tmp_path)]) == 0
    files = {}
    for comp_path in sorted(tmp_path.glob("*.comp")):
        table = np.loadtxt(comp_path, ndmin=2)
        table[:, 1:] = 2 * table[:, [0]] - table[:, 1:]  # actual mirrored: the sign mistake
        np.savetxt(comp_path, table, fmt="%.7f")
        machine = comp_path.stem.rsplit("_", 1)[0]
        ini = comp_path.with_name(f"{comp_path.stem}_linuxcnc.ini")
        files[(machine, "X")] = {"table": comp_path, "parameters": ini}
    from pipeline.compensation.profile import measured_profiles

    profiles = measured_profiles(read_readings(twin))
    results = closed_loop(twin, profiles, "linuxcnc", files)
    assert results and not any(r["passed"] for r in results)
    assert all(r["ratio_B"] > 1.8 for r in results)  # a wrong sign doubles the error


def test_predictor_source(tmp_path, capsys):
    """A trained predictor's backlash at the given conditions becomes the reversal; no
    position error is claimed."""
    from models.serving.registry import TrainedModel, make, save_model

    X = pd.DataFrame({"target": [0.0, 100.0, 200.0, 300.0], "feed_mm_min": [500.0] * 4})
    y = np.array([3.0, 3.2, 2.8, 3.0])
    model = TrainedModel("constant", make("constant").fit(X, y), ["target", "feed_mm_min"],
                         "iso", 0.2, {"target": (0.0, 300.0), "feed_mm_min": (500.0, 500.0)},
                         X)
    save_model(model, tmp_path / "model")
    assert main(["compensate", str(tmp_path / "model"), "--controller", "linuxcnc", "--out",
                 str(tmp_path / "out"), "--conditions", "feed_mm_min=800", "--json"]) == 0
    axis = json.loads(capsys.readouterr().out)["axes"][0]
    assert axis["source"] == "predicted" and axis["reversal_compensation_um"] == pytest.approx(3.0)
    assert np.allclose(axis["reversal_um"], -3.0)
    comp = ctl.linuxcnc(next((tmp_path / "out").glob("*.comp")))
    assert comp.offset_mm(150.0, 1) - comp.offset_mm(150.0, -1) == pytest.approx(0.003)


@pytest.mark.parametrize("extra, message", [
    (["--controller", "okuma"], "unknown controller 'okuma'"),
    (["--controller", "linuxcnc", "--conditions", "feed_mm_min=500"],
     "--conditions: applies to a model directory"),
    (["--controller", "heidenhain", "--spacing", "0.01"], "at most 256"),
    (["--controller", "siemens", "--spacing", "-1"],
     "--spacing: '-1': expected a float in the range (0.0, inf)"),
    (["--controller", "linuxcnc", "--verify"], "--verify: needs twin data"),
    (["--controller", ","], "unknown controller"),
    (["--controller", "fanuc", "--fanuc-unit-um", "0"], "--fanuc-unit-um"),
])
def test_bad_input_is_one_line_and_writes_nothing(extra, message, ess_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compensate", str(ess_file), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


def test_bad_conditions_and_model_dir(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["compensate", str(tmp_path / "empty"), "--controller", "csv", "--out",
                 str(tmp_path / "o")]) == 2
    assert "no model.json" in capsys.readouterr().err
    assert main(["compensate", str(tmp_path / "empty"), "--controller", "csv", "--out",
                 str(tmp_path / "o"), "--conditions", "speed=3"]) == 2
    assert "unknown condition 'speed'" in capsys.readouterr().err


@pytest.mark.parametrize("conditions, message", [
    ("feed_mm_min", "expected NAME=VALUE"),
    ("feed_mm_min=fast", "is not a number"),
])
def test_bad_condition_values(conditions, message, tmp_path, capsys):
    (tmp_path / "m").mkdir()
    assert main(["compensate", str(tmp_path / "m"), "--controller", "csv", "--out",
                 str(tmp_path / "o"), "--conditions", conditions]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_broken_twin_parameters(ess_file, tmp_path, capsys):
    data = tmp_path / "readings.dat"
    data.write_bytes(ess_file.read_bytes())
    (tmp_path / "parameters.json").write_text("{not json")
    assert main(["compensate", str(data), "--controller", "csv", "--out", str(tmp_path / "o"),
                 "--verify"]) == 2
    assert "not a twin parameters file" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_latest_visit_follows_dates_then_numbers():
    from pipeline.compensation.profile import latest_visit

    frame = pd.DataFrame({"visit": ["9", "10", "10"]})
    assert latest_visit(frame) == "10"
    dated = frame.assign(started_at=pd.to_datetime(["2026-03-01", "2026-01-01", "2026-01-02"]))
    assert latest_visit(dated) == "9"
    assert latest_visit(pd.DataFrame({"visit": ["a", "b"]})) == "b"


def test_scalar_controllers_refuse_rotary_axes(tmp_path):
    p = golden_profile()
    p.axis = "A"
    with pytest.raises(Exception, match="X, Y and Z only"):
        written_files("grblhal", tmp_path, p)


def test_zero_compensation_leaves_the_twin_unchanged_and_backlash_alone_is_taken_up():
    """The hook is backwards compatible, and on an indirect axis with backlash only a scalar
    equal to the clearance, added at reversal, is taken up by the play: B_i -> 0."""
    from models.physics.campaign import simulate

    config = {"system": "indirect", "effects": {"backlash": {"b0_um": 5.0}},
              "plan": {"feeds_mm_min": [500.0], "dwells_s": [3.0], "repeats": 1,
                       "methods": ["linear", "pendulum"]},
              "noise": {"noise_um": 0.0, "resolution_um": 0.0}}
    plain = simulate(config, 4).readings
    zero = simulate(config, 4, compensation={("M01", "X"): ctl.Compensation()}).readings
    pd.testing.assert_frame_equal(plain, zero)
    b = -iso230.per_target(plain)["B_i"].mean() / 1000
    taken = simulate(config, 4, compensation={("M01", "X"): ctl.Compensation(backlash_mm=b)})
    per = iso230.per_target(taken.readings)
    assert per["B_i"].abs().max() < 1e-9 and iso230.per_target(plain)["B_i"].abs().min() > 4
    wrong = simulate(config, 4, compensation={("M01", "X"): ctl.Compensation(backlash_mm=-b)})
    assert iso230.per_target(wrong.readings)["B_i"].abs().min() > 1.9 * 4


# --------------------------------------------------------------------------- Python API


def test_python_api_writes_what_the_cli_writes(ess_file, tmp_path, capsys):
    import backlash as bl

    result = bl.compensate(ess_file, controller="linuxcnc,sinumerik")
    assert result.controllers == ["linuxcnc", "siemens"] and result.files == {}
    assert result.notes[0] == "ess_mcu1025 X: 2 flagged outlier reading(s) not used"
    assert result.notes[1].startswith("ess_mcu1025 X: the reversal value varies along the axis")
    assert result.notes[1].endswith("; a table per direction for linuxcnc; the scalar 13.692 um "
                                    "for siemens, which leaves reversal values up to 29.768 um")
    assert capsys.readouterr() == ("", "")  # the library never prints
    files = result.write(tmp_path / "api")
    assert sorted(p.name for p in (tmp_path / "api").iterdir()) == sorted(files)
    assert main(["compensate", str(ess_file), "--controller", "linuxcnc,siemens", "--out",
                 str(tmp_path / "cli"), "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    api = json.loads(json.dumps(result.to_dict()))
    assert api["axes"] == cli["axes"] and api["verify"] == cli["verify"] == []
    for a, c in zip(api["files"], cli["files"]):
        assert {k: Path(v).name for k, v in a.pop("files").items()} == {
            k: Path(v).name for k, v in c.pop("files").items()}
        assert a == c
    for name in files:
        assert (tmp_path / "api" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()


def test_python_api_takes_a_readings_frame_or_a_loaded_model(ess_file, tmp_path):
    import backlash as bl
    from models.serving.registry import TrainedModel, make

    readings = bl.read(ess_file)
    from_frame = bl.compensate(readings, controller="csv")
    assert from_frame.contents == bl.compensate(ess_file, controller="csv").contents
    X = pd.DataFrame({"target": [0.0, 100.0, 200.0], "feed_mm_min": [500.0] * 3})
    model = TrainedModel("constant", make("constant").fit(X, np.array([3.0, 3.0, 3.0])),
                         ["target", "feed_mm_min"], "iso", 0.2,
                         {"target": (0.0, 200.0), "feed_mm_min": (500.0, 500.0)}, X)
    predicted = bl.compensate(model, controller="marlin", conditions={"feed_mm_min": 800})
    assert predicted.profiles[0].backlash == pytest.approx(3.0)
    assert "M425 X0.0030" in next(iter(predicted.contents.values())).decode()


@pytest.mark.parametrize("kwargs, parameter, message", [
    ({"controller": "okuma"}, "controller",
     ("unknown controller 'okuma'; expected linuxcnc, siemens, fanuc, heidenhain, marlin, "
      "reprap, grblhal, csv or all")),
    ({"controller": 3}, "controller", "must be an instance of"),
    ({"spacing": -1.0}, "spacing", r"must be None or a float in the range \(0.0, inf\)"),
    ({"fanuc_unit_um": 0.0}, "fanuc_unit_um", "must be a float in the range"),
    ({"conditions": {"feed_mm_min": 500}}, "conditions", "applies to a model directory"),
    ({"conditions": {"speed": 3}}, "conditions", "unknown condition 'speed'"),
    ({"verify": True}, "verify", "needs twin data"),
    ({"controller": "heidenhain", "spacing": 0.01}, "spacing", "at most 256"),
])
def test_python_api_errors_name_the_parameter(kwargs, parameter, message, ess_file):
    import backlash as bl

    with pytest.raises(bl.InputError, match=message) as err:
        bl.compensate(ess_file, **kwargs)
    assert err.value.parameter == parameter


def test_python_api_refuses_a_hand_made_frame_and_verify_on_a_frame(ess_file):
    import backlash as bl

    with pytest.raises(bl.InputError) as err:
        bl.compensate(pd.DataFrame({"x": [1.0]}), controller="csv")
    assert err.value.parameter == "data"
    with pytest.raises(bl.InputError, match="not a frame") as err:
        bl.compensate(bl.read(ess_file), controller="csv", verify=True)
    assert err.value.parameter == "verify"


# --------------------------------------------------------------------------- residual vs U(B)

BUDGET = Path(__file__).resolve().parents[1] / "experiments" / "data" / "paper_uncertainty.toml"


def test_residual_against_the_measurement_uncertainty(ess_file, tmp_path, capsys):
    """The ESS axis's per-direction table leaves no reversal (within U(B)); the scalar of a
    one-table format leaves 29.77 um (beyond it). U(B) is the budget's at the axis's own
    measuring length and runs per direction."""
    from features.uncertainty import expanded_at_length_um, read_budget

    readings = read_readings(ess_file)
    length = float(readings["target"].max() - readings["target"].min())
    kept = readings[~iso230.outliers(readings)]  # the 2 flagged readings lower n
    cycles = int(iso230.per_target(kept)[["n_up", "n_down"]].min().min())
    u_b = expanded_at_length_um(read_budget(BUDGET), length, cycles)["B"]
    assert main(["compensate", str(ess_file), "--controller", "linuxcnc,sinumerik", "--out",
                 str(tmp_path / "out"), "--uncertainty", str(BUDGET), "--json"]) == 0
    out = capsys.readouterr()
    found = {f["controller"]: f["resolution"] for f in json.loads(out.out)["files"]}
    assert found["linuxcnc"]["U_B_um"] == pytest.approx(u_b, abs=1e-4)
    assert found["linuxcnc"]["resolvable"] is False and found["linuxcnc"]["residual_um"] < 1e-3
    assert found["siemens"]["resolvable"] is True
    assert found["siemens"]["residual_um"] == pytest.approx(29.767, abs=2e-3)
    assert "29.767 um (reversal left at the targets) beyond what the measurement can resolve" \
        in out.err


def test_bad_budget_writes_nothing(ess_file, tmp_path, capsys):
    bad = tmp_path / "budget.toml"
    bad.write_text(BUDGET.read_text().replace("laser_accuracy_ppm", "laser_accuracy_um"))
    for budget in (bad, tmp_path / "missing.toml"):
        assert main(["compensate", str(ess_file), "--controller", "csv", "--out",
                     str(tmp_path / "out"), "--uncertainty", str(budget)]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
        assert not (tmp_path / "out").exists()
