"""Volumetric error: the machine twin's kinematics and tests, the identification of the 21
errors (checked on an independent generator), the seed paper's finding on every body diagonal,
the circle output's geometry, and the ``volumetric`` job."""

from __future__ import annotations

import json
from dataclasses import replace

import independent_machine as ind
import numpy as np
import pytest

from models.machine import volumetric as vol
from models.physics import machine as twin


@pytest.fixture(scope="module")
def paper():
    return twin.paper_machine()


def bare(paper, **drives) -> twin.Machine:
    """The paper's machine with no geometric error and only the given feed drives."""
    m = twin.without(paper, geometry=True, drives=True)
    return replace(m, drives={**m.drives, **drives})


def with_errors(paper, axis: str, six) -> twin.Machine:
    """No error but ``axis``' six constant error motions (um, urad)."""
    m = bare(paper)
    errors = dict(m.geometry.errors)
    errors[axis] = twin.ErrorTable(np.array(paper.geometry.travel_mm[axis]),
                                   np.tile(np.asarray(six, float), (2, 1)))
    return replace(m, geometry=replace(m.geometry, errors=errors))


# ------------------------------------------------------------------------- kinematics
def test_a_pitch_of_x_moves_the_tool_by_the_angle_times_its_height_above_the_scale(paper):
    # eps_y = 10 urad on X; R_X = (0, -300, -1150), tool (0, 0, -200), z = 0: lever_z = 950 mm,
    # the table tilts the workpiece by +eps_y, the tool moves by -(eps x L)_x = -eps_y L_z
    m = with_errors(paper, "X", [0, 0, 0, 0, 10.0, 0])
    p = np.array([[300.0, -1800.0, 0.0]])
    first = twin.tool_error_um(m.geometry, p, m.tool_mm)
    chain, angles = twin.chain_error(m.geometry, p, m.tool_mm)
    assert first[0] == pytest.approx([-9.5, 0, 0], abs=1e-9)
    assert chain[0] == pytest.approx([-9.5, 0, 0], abs=1e-4)
    assert angles[0] == pytest.approx([0, -10.0, 0], abs=1e-6)  # the spindle against the table


def test_the_chain_of_transforms_agrees_with_the_first_order_sum(paper):
    g = paper.geometry
    lo = np.array([g.travel_mm[a][0] for a in twin.AXES])
    hi = np.array([g.travel_mm[a][1] for a in twin.AXES])
    p = lo + np.random.default_rng(5).uniform(size=(500, 3)) * (hi - lo)
    first = twin.tool_error_um(g, p, paper.tool_mm)
    chain, _ = twin.chain_error(g, p, paper.tool_mm)
    assert np.abs(first).max() > 50  # errors of the paper's size
    assert np.abs(chain - first).max() < 0.02  # second order: eps^2 L, eps delta


def test_squareness_tilts_the_second_axis_towards_the_first(paper):
    m = bare(paper)
    m = replace(m, geometry=replace(m.geometry, squareness_urad={"XY": 20.0, "XZ": -10.0,
                                                                 "YZ": 5.0}))
    error, _ = twin.chain_error(m.geometry, [[0.0, -1000.0, 200.0]], m.tool_mm)
    assert error[0] == pytest.approx([-20.0 - 2.0, 1.0, 0.0], abs=1e-3)


def test_a_line_test_sees_the_play_as_the_reversal_value_and_the_scale_as_a_slope(paper):
    m = bare(paper, X=twin.FeedDrive(backlash_um=6.0))
    scale = twin.ErrorTable(np.array([0.0, 1500.0]), np.array([[0.0] * 6, [15.0] + [0.0] * 5]))
    m = replace(m, geometry=replace(m.geometry, errors={**m.geometry.errors, "X": scale}))
    f = twin.line_test(m, [0, -1800, -350], [1500, -1800, -350], cycles=2)
    means = f.groupby(["target", "direction"])["deviation_um"].mean().unstack()
    assert (means[-1] - means[1]).to_numpy() == pytest.approx(np.full(11, 6.0), abs=1e-3)
    both = (means[-1] + means[1]).to_numpy() / 2
    # the table's positioning error enters the tool's with a minus sign
    assert both - both[0] == pytest.approx(-np.linspace(0, 15, 11), abs=1e-3)


def test_a_line_test_is_a_readings_table_iso_reads(paper, tmp_path):
    import backlash as bl

    m = bare(paper, Y=twin.FeedDrive(backlash_um=4.0))
    test = twin.line_test(m, [750, -2550, -350], [750, -1050, -350], cycles=5, targets=6,
                          noise={"dy_um": 0.05}, rng=np.random.default_rng(0))
    path = tmp_path / "y.csv"
    twin.as_readings(test, machine_id="twin", axis="Y", test_id="Y1",
                     start_mm=-2550.0).to_csv(path, index=False)
    figures = bl.iso(str(path)).figures
    assert figures["B"].iloc[0] == pytest.approx(4.0, abs=0.15)


# ------------------------------------------------------------------------- identification
def independent_geometry_error(model, targets=11) -> dict:
    out = {}
    for axis in ind.AXES:
        q = np.linspace(*ind.TRAVEL[axis], 201)
        out[axis] = np.abs(model.errors[axis](q) - ind.truth(axis, q)).max(axis=0)
    return out


@pytest.fixture(scope="module")
def independent_fits():
    tests = ind.axis_tests(np.random.default_rng(11))
    setup = vol.Setup(laser_mm=ind.LASER, origin_mm=ind.ORIGIN)
    fit = {name: vol.identify(tests, setup, ind.TRAVEL, ind.HEADS, at)
           for name, at in (("abbe", ind.LASER), ("traditional", {a: ind.TOOL for a in ind.AXES}))}
    return fit


def test_the_abbe_aware_identification_recovers_the_independent_truth(independent_fits):
    model = independent_fits["abbe"]
    gap = independent_geometry_error(model)
    for axis in ind.AXES:
        assert gap[axis][:3].max() < 1.0, (axis, gap[axis])  # translations [um]
        assert gap[axis][3:].max() < 1.0, (axis, gap[axis])  # angles [urad]
    for pair, true in ind.SQUARENESS.items():
        assert model.squareness_urad[pair] == pytest.approx(true, abs=1.0), pair


def test_the_traditional_identification_keeps_the_abbe_error_in_the_positioning(independent_fits):
    """The paper's eq. (2): measured positioning = positioning at the scale + eps_y L_z -
    eps_z L_y; taken as the tool's, it is off by eps x (h_laser - h_tool)."""
    q = np.linspace(*ind.TRAVEL["X"], 201)
    six = ind.truth("X", q)
    arm = ind.LASER["X"] - ind.TOOL
    abbe = 1e-3 * (six[:, 4] * arm[2] - six[:, 5] * arm[1])
    found = independent_fits["traditional"].errors["X"](q)[:, 0] - six[:, 0]
    assert np.abs(abbe).max() > 5  # a real Abbe error, well above the noise
    assert found == pytest.approx(abbe - abbe[0], abs=1.0)


def test_the_smooth_fit_chooses_its_degree_from_the_data():
    q = np.linspace(0, 1000, 11)
    rng = np.random.default_rng(2)
    line = vol.fit_smooth(q, 0.02 * q + rng.normal(0, 0.3, 11))
    curve = vol.fit_smooth(q, 20 * np.sin(q / 200) + rng.normal(0, 0.3, 11))
    assert line.degree() <= 2 < curve.degree()
    assert np.abs(curve(q) - 20 * np.sin(q / 200)).max() < 1.0


def test_the_twin_identification_recovers_the_twins_errors(paper):
    comparison = vol.compare(paper, vol.Setup(), seed=4)
    gap = vol.identification_error(comparison.models["abbe"], paper.geometry)
    for axis in twin.AXES:
        assert max(gap[axis].values()) < 1.5, (axis, gap[axis])
    assert max(abs(v) for v in gap["squareness_urad"].values()) < 1.5


# ------------------------------------------------------------------------- the paper's finding
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_abbe_aware_leaves_less_than_traditional_on_every_diagonal(paper, seed):
    table = vol.compare(paper, vol.Setup(), seed).extremes()
    assert set(table) == {"PPP", "NPP", "PPN", "NPN"}
    for name, v in table.items():
        assert abs(v["abbe_um"]) < abs(v["traditional_um"]) < abs(v["before_um"]), name
        assert abs(v["abbe_um"]) < 3.0, name  # only noise and fit error are left


# ------------------------------------------------------------------------- circles
def sorted_circle(machine, **kw):
    f = twin.circle_test(machine, radius_mm=150.0, **kw).sort_values("angle_deg")
    return f["angle_deg"].to_numpy(), f["deviation_um"].to_numpy()


def test_the_circle_frame_has_the_schema_columns(paper):
    f = twin.circle_test(paper, plane="ZX", direction="CW", points=90)
    assert tuple(f.columns) == twin.CIRCLE_COLUMNS
    assert len(f) == 90 and set(f["plane"]) == {"ZX"} and set(f["direction"]) == {"CW"}
    assert f["angle_deg"].between(0, 360, inclusive="left").all()


def test_pure_squareness_is_a_two_per_rev_ellipse_along_45_degrees(paper):
    m = bare(paper)
    m = replace(m, geometry=replace(m.geometry, squareness_urad={"XY": 20.0, "XZ": 0.0,
                                                                 "YZ": 0.0}))
    angle, dev = sorted_circle(m)
    # E_x = a y: radial a R sin(t) cos(t) = (a R / 2) sin(2 t)
    assert dev == pytest.approx(20e-3 * 150 / 2 * np.sin(2 * np.radians(angle)), abs=1e-3)
    assert angle[np.argmax(dev)] in (45.0, 225.0)


def test_a_pure_x_play_steps_the_radius_at_0_and_180_degrees(paper):
    angle, dev = sorted_circle(bare(paper, X=twin.FeedDrive(backlash_um=8.0)))
    steps = np.diff(np.r_[dev, dev[0]])  # from each angle to the next
    big = set(angle[np.abs(steps) > 4.0])
    assert big == {0.0, 180.0} or big == {359.0, 179.0}
    assert np.abs(steps[np.abs(steps) > 4.0]) == pytest.approx([8.0, 8.0], abs=0.2)
    assert np.abs(dev).max() == pytest.approx(4.0, abs=1e-6)  # b/2 along X, none along Y


def test_a_friction_spike_is_an_outward_peak_decaying_after_the_reversal(paper):
    _, dev = sorted_circle(bare(paper, Y=twin.FeedDrive(spike_um=5.0, spike_mm=2.0)))
    # Y reverses at 90 and 270 deg (CCW): a peak just after, gone within some degrees
    assert dev[91] == pytest.approx(5.0, abs=0.2) and dev[271] == pytest.approx(5.0, abs=0.2)
    assert dev[120] < 0.5 and abs(dev[60]) < 1e-9


def test_a_servo_mismatch_turns_the_ellipse_with_the_direction(paper):
    m = bare(paper, X=twin.FeedDrive(servo_ms=30.0), Y=twin.FeedDrive(servo_ms=31.0))
    peaks = {}
    for direction in ("CCW", "CW"):
        angle, dev = sorted_circle(m, direction=direction, feed_mm_min=2000.0)
        peaks[direction] = angle[np.argmax(dev)] % 180
    # lag x trails y's: the ellipse's long axis at 135 deg one way and 45 deg the other
    assert {round(v / 45) * 45 for v in peaks.values()} == {45, 135}


# ------------------------------------------------------------------------- the job
@pytest.fixture
def cli(monkeypatch, tmp_path):
    from pipeline import cli as cli_module

    monkeypatch.chdir(tmp_path)
    return cli_module.main


def test_the_job_prints_every_diagonal_and_is_deterministic(cli, capsys, tmp_path):
    assert cli(["volumetric", "--seed", "1", "--json", "--out", str(tmp_path / "v")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["diagonals"]) == {"PPP", "NPP", "PPN", "NPN"}
    assert all(set(v) == {"before_um", "traditional_um", "abbe_um"}
               for v in out["diagonals"].values())
    assert out["finding"]["holds"] is True
    assert cli(["volumetric", "--seed", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == out
    assert cli(["volumetric", "--seed", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["diagonals"] != out["diagonals"]
    import pandas as pd

    circles = pd.read_csv(tmp_path / "v" / "circles.csv")
    assert tuple(circles.columns) == twin.CIRCLE_COLUMNS
    assert set(circles["plane"]) == {"XY", "YZ", "ZX"}


def test_bad_parameters_in_python_name_the_parameter():
    import backlash as bl

    with pytest.raises(bl.InputError) as err:
        bl.volumetric(targets=3)
    assert err.value.parameter == "targets"
    with pytest.raises(bl.InputError):
        bl.volumetric(seed=1.5)


@pytest.mark.parametrize("argv, says", [
    (["--targets", "3"], "--targets"), (["--seed", "-1"], "--seed"),
    (["--targets", "many"], "--targets"), (["--radius-mm", "0"], "--radius-mm")])
def test_bad_options_are_one_line_exit_2(cli, capsys, argv, says, tmp_path):
    try:
        code = cli(["volumetric", *argv, "--out", str(tmp_path / "v")])
    except SystemExit as stop:
        code = stop.code
    assert code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "v").exists()


def test_the_circles_are_written_at_the_radius_given(cli, tmp_path):
    import pandas as pd

    assert cli(["volumetric", "--targets", "5", "--radius-mm", "80", "--out",
                str(tmp_path / "v")]) == 0
    circles = pd.read_csv(tmp_path / "v" / "circles.csv")
    assert set(circles["radius_mm"]) == {80.0} and set(circles["plane"]) == {"XY", "YZ", "ZX"}


# ------------------------------------------------------------------------- the path under load
def pocket_path():
    """A rectangular pocket at two depths, the cutting force 400 N against the feed."""
    import itertools

    import pandas as pd

    corners = np.array([[400, -2200], [1100, -2200], [1100, -1400], [400, -1400],
                        [400, -2200]], float)
    s = np.linspace(0.0, 1.0, 21)[:-1]
    xyz = np.array([(*(a + (b - a) * t), z) for z in (-300.0, -700.0)
                    for a, b in itertools.pairwise(corners) for t in s])
    step = np.diff(xyz[:, :2], axis=0, prepend=xyz[:1, :2])
    step[0] = step[1]
    force = -400.0 * step / np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-9)
    return pd.DataFrame({"x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
                         "fx_n": force[:, 0], "fy_n": force[:, 1]})


@pytest.fixture(scope="module")
def path_result():
    import warnings

    import backlash as bl

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bl.volumetric(path=pocket_path(), targets=11, track=False)


def test_each_part_of_the_error_along_a_path_matches_the_twins(paper, path_result):
    from models.machine import path_error as pe
    from models.physics import loaded_circles as lc

    frame = path_result.path
    xyz = frame[["x_mm", "y_mm", "z_mm"]].to_numpy()
    force = np.column_stack([frame["fx_n"], frame["fy_n"], np.zeros(len(frame))])
    truth = {"geometric": twin.tool_error_um(paper.geometry, xyz, paper.tool_mm),
             "backlash": pe.backlash_error_um(xyz, {a: paper.drives[a].backlash_um
                                                    for a in twin.AXES}),
             "load": lc.paper_stiffness(paper).deflection_um(xyz, force)}
    got = {name: frame[[f"{name}_{a}_um" for a in "xyz"]].to_numpy() for name in truth}
    # the Abbe-aware identification is within about 1 um of every error function
    assert np.abs(got["geometric"] - truth["geometric"]).max() < 2.0
    # the play found by the circles' diagnosis, half of it against the direction of motion
    assert np.abs(got["backlash"] - truth["backlash"]).max() < 0.5
    # the deflection in X and Y from the map of the twin's own loaded circles
    load, true_load = got["load"][:, :2], truth["load"][:, :2]
    assert np.all(np.abs(load - true_load) <= 0.05 * np.abs(true_load) + 0.3)
    assert np.abs(true_load).max() > 10  # the load is not negligible on this path
    assert np.isnan(got["load"][:, 2]).all()  # XY circles say nothing of Z
    total = frame[[f"total_{a}_um" for a in "xyz"]].to_numpy()
    assert total == pytest.approx(got["geometric"] + got["backlash"]
                                  + np.nan_to_num(got["load"]))
    summary = path_result.path_summary
    assert summary["stiffness_map"] == "cubic"
    assert summary["error_vs_twin_um"]["load"] < 0.5


def test_the_backlash_follows_the_direction_each_axis_last_moved():
    from models.machine import path_error as pe

    path = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 1, 0]], float)
    sense = pe.motion_sense(path)
    assert sense[:, 0].tolist() == [1, 1, 1, 1, -1, -1]  # held through the stop at row 3
    assert sense[:, 1].tolist() == [1, 1, 1, 1, 1, 1]  # before its first move: that move's
    assert sense[:, 2].tolist() == [0] * 6
    e = pe.backlash_error_um(path, {"X": 6.0, "Y": 4.0})
    assert e[:, 0].tolist() == [-3, -3, -3, -3, 3, 3] and set(e[:, 1]) == {-2.0}


def test_a_saved_stiffness_and_its_loaded_circles_give_the_same_load(tmp_path):
    import warnings

    import backlash as bl

    ldbb = "experiments/data/stiffness/ldbb.csv"
    from pathlib import Path

    ldbb = str(Path(__file__).resolve().parents[1] / ldbb)
    path = pocket_path().iloc[::4]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.stiffness(ldbb, ram_top_mm=200.0, out=str(tmp_path / "s"), track=False)
        a = bl.volumetric(path=path, stiffness=ldbb, targets=5, track=False)
        b = bl.volumetric(path=path, stiffness=str(tmp_path / "s" / "stiffness.json"),
                          targets=5, track=False)
    assert a.path["load_x_um"].to_numpy() == pytest.approx(b.path["load_x_um"].to_numpy())
    assert b.path_summary["stiffness_source"].endswith("stiffness.json")


def test_without_a_path_the_job_is_unchanged(cli, capsys):
    assert cli(["volumetric", "--targets", "5", "--json"]) == 0
    assert "path" not in json.loads(capsys.readouterr().out)


def test_a_stiffness_without_a_path_or_a_path_without_forces_is_refused(cli, capsys, tmp_path):
    ldbb = tmp_path / "points.csv"
    pocket_path().drop(columns="fy_n").to_csv(ldbb, index=False)
    assert cli(["volumetric", "--path", str(ldbb), "--out", str(tmp_path / "v")]) == 2
    err = capsys.readouterr().err.strip()
    assert "column 'fy_n': missing required column" in err and "\n" not in err
    assert cli(["volumetric", "--stiffness", str(ldbb)]) == 2
    assert "--stiffness" in capsys.readouterr().err and not (tmp_path / "v").exists()
