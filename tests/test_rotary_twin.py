"""The twin's rotary table (``rotary`` preset): a worm-driven C axis measured over a full turn,
positions in degrees and errors in arcsec, checked against its own truth; the closed loop of
every table controller on it."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from features import iso230
from features.readings import read_readings
from models.physics.axis import play
from models.physics.campaign import load_config, simulate
from pipeline.cli import main
from pipeline.compensation import CONTROLLERS, read
from pipeline.compensation.common import Options
from pipeline.compensation.profile import measured_profiles

pytestmark = pytest.mark.filterwarnings("ignore::features.readings.errors.BacklashWarning")


def write_files(profile, name: str, folder: Path) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    return CONTROLLERS[name].writer(profile, folder, Options())["files"]


@pytest.fixture(scope="module")
def rotary():
    return simulate("rotary", seed=3)


def test_a_full_turn_in_degrees_with_the_worm_period_not_aliased(rotary):
    r = rotary.readings
    assert set(r["axis"]) == {"C"}
    targets = np.sort(r["target"].unique())
    assert targets[0] == 0.0 and targets[-1] == 360.0 and len(targets) == 13
    # the worm's 5 deg period is sampled at different phases (ISO irregular spacing)
    phases = np.round(np.mod(targets[1:-1], 5.0), 3)
    assert len(set(phases)) >= 8


def test_reversal_value_is_the_worm_lost_motion_in_arcsec(rotary):
    """Indirect system: B_i = -b at every target, b in arcsec (12 arcsec x the machine's factor
    0.8-1.25 plus wear), read against the twin's truth."""
    per = iso230.per_target(rotary.readings)
    truth = rotary.truth.groupby(["test_id", "target"], observed=True)["true_backlash_um"].mean()
    both = per.set_index(["test_id", "target"])["B_i"].to_frame().join(truth.rename("b"))
    assert both["b"].between(9.0, 20.0).all()
    s = float(np.median(np.r_[per["s_up"], per["s_down"]]))
    n = int(rotary.readings["cycle"].max())
    np.testing.assert_allclose(both["B_i"], -both["b"], atol=4 * s * np.sqrt(2 / n))


def test_bidirectional_error_is_eccentricity_plus_worm_error(rotary):
    """The bidirectional mean deviation follows the truth of the periodic error, whose
    once-per-revolution term (8 arcsec) dominates."""
    per = iso230.per_target(rotary.readings)
    mean = ((per["mean_up"] + per["mean_down"]) / 2).groupby(per["target"]).mean()
    truth = rotary.truth.groupby("target")["lead_error_periodic_um"].mean()
    np.testing.assert_allclose(mean.to_numpy(), truth.loc[mean.index].to_numpy(), atol=0.6)
    x = np.deg2rad(mean.index.to_numpy(float))
    design = np.c_[np.sin(x), np.cos(x), np.ones_like(x)]
    coef = np.linalg.lstsq(design, mean.to_numpy(), rcond=None)[0]
    assert np.hypot(*coef[:2]) == pytest.approx(8.0, abs=1.0)


def test_play_takes_its_width_in_arcsec_against_degrees():
    """A reversal of 0.002 deg (7.2 arcsec) is shorter than a 20 arcsec clearance: the table
    does not move. The same numbers read as um against mm would be taken up."""
    path = np.array([[0.0, 1.0, 0.998]])
    width = np.full(path.shape, 20.0)
    rotary_table = play(path, width, per_unit=3600.0)
    assert rotary_table[0, 2] == pytest.approx(rotary_table[0, 1])
    linear_table = play(path, width, per_unit=1000.0)  # 0.002 mm = 2 um < 20 um: also held
    assert linear_table[0, 2] == pytest.approx(linear_table[0, 1])
    short = np.array([[0.0, 1.0, 0.99]])  # 36 arcsec back: taken up, the table moves 16 arcsec
    moved = play(short, width, per_unit=3600.0)
    assert (moved[0, 1] - moved[0, 2]) * 3600 == pytest.approx(36.0 - 20.0)


def test_a_fleet_of_a_linear_and_a_rotary_axis_keeps_each_unit():
    config = load_config({"fleet": {"axes": ["X", "C"], "visits": 1}}, preset="rotary")
    sim = simulate(config, seed=1)
    per = iso230.per_target(sim.readings)
    truth = sim.truth.groupby("axis", observed=True)["true_backlash_um"].mean()
    for axis in ("X", "C"):
        b = -per.loc[per["axis"] == axis, "B_i"].mean()
        assert b == pytest.approx(truth[axis], abs=0.5)


@pytest.fixture(scope="module")
def twin_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("rotary")
    assert main(["simulate", "--preset", "rotary", "--seed", "5", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("controller", ["linuxcnc", "csv", "siemens", "heidenhain", "fanuc"])
def test_closed_loop_on_the_rotary_table(twin_dir, tmp_path, capsys, controller):
    """Every table controller's file, read back as the controller applies it (offsets in
    degrees), takes the worm's lost motion and the eccentricity out of the re-measured table."""
    assert main(["compensate", str(twin_dir / "readings.csv"), "--controller", controller,
                 "--out", str(tmp_path), "--verify", "--json"]) == 0
    (check,) = json.loads(capsys.readouterr().out)["verify"]
    assert check["passed"] and check["axis"] == "C"
    assert check["before"]["B"] > 9 and check["before"]["E"] > 15  # arcsec
    assert check["ratio_B"] <= 0.15 and check["ratio_E"] <= 0.1


# --------------------------------------------------------------------------- recalibration
@pytest.fixture(scope="module")
def one_visit():
    return load_config({"fleet": {"visits": 1}}, preset="rotary")


@pytest.mark.parametrize("controller", ["linuxcnc", "siemens", "heidenhain", "fanuc"])
def test_recalibration_of_the_rotary_table(one_visit, tmp_path, capsys, controller):
    """The table measured with a half-strength file active: the new file is the active one
    plus the residual, the raw test's full table up to the play, the noise and (Fanuc) the
    0.001 deg detection unit; --verify re-measures with the active file and with the new one."""
    from pipeline.workflows.simulate import simulate as simulate_result

    raw = simulate_result(one_visit, seed=2)
    raw.write(tmp_path / "raw")
    p = measured_profiles(read_readings(tmp_path / "raw" / "readings.csv"))[0]
    half = write_files(replace(p, mean_up=p.mean_up / 2, mean_down=p.mean_down / 2),
                       controller, tmp_path / "half")
    active = read(controller, half)
    simulate_result(one_visit, seed=2, compensation={(p.machine_id, p.axis): active}).write(
        tmp_path / "with_half")
    argv = ["compensate", str(tmp_path / "with_half" / "readings.csv"), "--controller",
            controller, "--verify", "--json", "--out", str(tmp_path / "out")]
    for path in half.values():
        argv += ["--active", str(path)]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    (check,) = result["verify"]
    assert check["before"]["B"] > 4 and check["before"]["E"] > 8  # arcsec: half left
    assert check["passed"] and check["ratio_B"] < 0.3 and check["ratio_E"] < 0.35
    new = read(controller, {r: Path(f) for r, f in result["files"][0]["files"].items()
                            if r != "changes"})
    full = read(controller, write_files(p, controller, tmp_path / "full"))
    tolerance_arcsec = 4.0 if controller == "fanuc" else 1.0
    for d in (1, -1):
        gap = 3600 * (new.offset_mm(p.target, d) - full.offset_mm(p.target, d))
        assert np.max(np.abs(gap - np.median(gap))) < tolerance_arcsec


def test_an_active_table_in_mm_is_refused_for_a_rotary_axis(twin_dir, tmp_path, capsys):
    table = tmp_path / "T.COM"
    table.write_text("BEGIN T.COM MM\nNR C-POS C-ERROR\n0 +0.0000 +0.00000\n[END]\n")
    assert main(["compensate", str(twin_dir / "readings.csv"), "--controller", "heidenhain",
                 "--active", str(table), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("a table in MM; expected DEG for axis C") and "\n" not in err
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- units everywhere
LINEAR_UNIT = re.compile(r"\b(um|mm|µm)\b")


@pytest.mark.parametrize("command", [
    ["iso", "--plot", "{out}/iso.png", "--json"],
    ["report", "--out", "{out}"],
    ["targets", "--out", "{out}", "--json"],
    ["discover", "--out", "{out}", "--json"],
    ["rank", "--out", "{out}", "--boot", "20"],
    ["compensate", "--controller", "all", "--out", "{out}"],
])
def test_every_output_of_the_rotary_table_speaks_degrees_and_arcsec(
        command, twin_dir, tmp_path, capsys, monkeypatch):
    """Messages, tables, reports and files of a rotary axis never label a value um or mm
    (column names such as deviation_um stay: a rotary axis's holds arcsec)."""
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    out = tmp_path / "out"
    argv = [command[0], str(twin_dir / "readings.csv"),
            *(a.format(out=out) for a in command[1:])]
    assert main(argv) in (0, 3)
    captured = capsys.readouterr()
    texts = {"stdout": captured.out, "stderr": captured.err}
    texts |= {str(p): p.read_text(encoding="utf-8") for p in out.rglob("*")
              if p.suffix.lower() in (".html", ".csv", ".txt", ".ini", ".com", ".comp", ".json",
                                      ".gcode")}
    assert len(texts) > 2 or command[0] == "iso"
    for where, text in texts.items():
        text = re.sub(r"data:image/[^\"')]+", "", text)  # embedded pictures are not words
        assert not LINEAR_UNIT.search(text), (where, LINEAR_UNIT.search(text))
    assert "arcsec" in captured.err + "".join(texts.values())
