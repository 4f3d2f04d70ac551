"""The feed-drive twin against its physics: lost motion, measuring systems, cycles, effects."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features import iso230
from features.targets import backlash_targets
from models.physics import effects
from models.physics.axis import play
from models.physics.campaign import paper_table, simulate
from models.physics.cycles import linear_path, pendulum_path
from pipeline.cli import main

QUIET = {"noise": {"noise_um": 0.0, "resolution_um": 0.0},
         "plan": {"feeds_mm_min": [500.0], "dwells_s": [5.0], "repeats": 1}}


def config(system: str, effect_set: dict, **extra) -> dict:
    return {"system": system, "effects": effect_set, **QUIET, **extra}


def per_target_truth(sim):
    stats = iso230.per_target(sim.readings)
    truth = sim.truth.groupby(["test_id", "target"])["true_backlash_um"].mean()
    return stats.join(truth, on=["test_id", "target"])


def test_indirect_backlash_only_gives_B_i_minus_b_at_every_target():
    sim = simulate(config("indirect", {"backlash": {"b0_um": 3.0}}), seed=1)
    stats = per_target_truth(sim)
    np.testing.assert_allclose(stats["B_i"], -stats["true_backlash_um"], atol=1e-9)
    assert stats["true_backlash_um"].between(2.4, 3.75).all()  # machine factor 0.8-1.25
    points = backlash_targets(sim.readings)  # auto: the evidence says indirect
    assert points.attrs["target_kind"] == "iso" and "indirect" in points.attrs["target_reason"]
    np.testing.assert_allclose(points["backlash_um"], stats["true_backlash_um"].iloc[0],
                               atol=1e-9)
    assert backlash_targets(sim.readings, "paper")["backlash_um"].max() < 1e-9


def test_direct_paper_target_recovers_b_inside_not_at_the_ends():
    sim = simulate(config("direct", {"backlash": {"b0_um": 3.0}}), seed=2)
    stats = iso230.per_target(sim.readings)
    lin = stats[stats["method"] == "linear"].set_index("target")
    pend = stats[stats["method"] == "pendulum"].set_index("target")
    z = (pend["mean_down"] - lin["mean_down"]) - (pend["mean_up"] - lin["mean_up"])
    b = sim.truth["true_backlash_um"].mean()
    interior = z.index[1:-1]
    np.testing.assert_allclose(z.loc[interior], b, atol=1e-9)
    np.testing.assert_allclose(z.iloc[[0, -1]], b / 2, atol=1e-9)  # turn-around targets
    points = backlash_targets(sim.readings)
    assert points.attrs["target_kind"] == "paper"
    np.testing.assert_allclose(points["backlash_um"], b, atol=1e-9)


def test_thermal_change_between_runs_leaks_into_z_and_cancels_in_the_difference():
    sim = simulate(config("direct", {"backlash": {"b0_um": 2.0},
                                     "thermal_expansion": {"alpha_um_per_m_k": 11.5}},
                          environment={"warmup_k": 4.0}), seed=3)
    points = backlash_targets(sim.readings, "paper")
    truth = (sim.truth.groupby(["method", "direction", "target"])["thermal_expansion_um"]
             .mean().unstack(0))
    leak = (truth["pendulum"] - truth["linear"]).unstack(0).loc[points["target"]]
    assert np.abs(leak.to_numpy()).max() > 0.5                        # the runs differ
    b = sim.truth["true_backlash_um"].mean()
    exact = 1e-6  # the truth's contributions are float32: 7 significant digits of ~1 um
    np.testing.assert_allclose(points["z_up_um"], -b / 2 + leak["+"], atol=exact)
    np.testing.assert_allclose(points["z_down_um"], b / 2 + leak["-"], atol=exact)
    # the difference keeps only the warm-up between the two directions' readings: a small
    # fraction of the leak
    differential = (leak["-"] - leak["+"]).to_numpy()
    np.testing.assert_allclose(points["backlash_um"], b + differential, atol=exact)
    assert np.abs(differential).max() < 0.25 * np.abs(leak.to_numpy()).max()


@pytest.mark.parametrize("irregular, visible", [(False, False), (True, True)])
def test_periodic_error_aliases_at_pitch_spacing(irregular, visible):
    plan = {**QUIET["plan"], "start_mm": 0.0, "stop_mm": 350.0, "n_targets": 8,
            "irregular": irregular, "methods": ["linear"]}
    sim = simulate({"system": "indirect", "noise": QUIET["noise"], "plan": plan,
                    "effects": {"lead_error_periodic": {"amplitude_um": 1.5, "pitch_mm": 10.0,
                                                        "phase_rad": 0.7}}}, seed=4)
    spread = iso230.axis_figures(sim.readings)["E"].iloc[0]
    # at 50 mm spacing (5 pitches) every target sits at the same phase: a constant offset
    assert bool(spread > 1.0) is visible
    assert spread < 1e-9 or visible


def test_every_effect_matches_its_formula():
    x = np.array([0.0, 175.0, 350.0])
    d = np.array([1.0, -1.0, 1.0])
    c = {"feed_mm_min": np.full(3, 1200.0), "dwell_s": np.full(3, 4.0),
         "machine_temp_c": np.full(3, 25.0), "ambient_temp_c": np.full(3, 21.0),
         "pressure_hpa": np.full(3, 1023.25), "humidity_pct": np.full(3, 60.0),
         "elapsed_s": np.full(3, 900.0)}
    f = effects.contribution
    np.testing.assert_allclose(f("backlash", x, d, c, b0_um=2.5), 2.5)
    np.testing.assert_allclose(f("backlash_position", x, d, c), [0.6 * 0 + np.exp(-(175 / 80) ** 2), 1.0, np.exp(-(175 / 80) ** 2)])
    np.testing.assert_allclose(f("backlash_feed", x, d, c), 1.2)
    np.testing.assert_allclose(f("backlash_temperature", x, d, c), -1.5)
    np.testing.assert_allclose(f("lead_error_linear", x, d, c), [0, 1.4, 2.8])
    np.testing.assert_allclose(f("lead_error_periodic", x, d, c, pitch_mm=7.0), 0, atol=1e-12)
    np.testing.assert_allclose(f("thermal_expansion", x, d, c), [0, 10.0625, 20.125])
    np.testing.assert_allclose(f("thermal_drift", x, d, c), 2.0 * (1 - np.exp(-1)))
    ppm = -0.93 * 1 + 0.27 * 10 - 0.0085 * 10
    np.testing.assert_allclose(f("air_refraction", x, d, c), ppm * x / 1000)
    np.testing.assert_allclose(f("abbe", x, d, c), [2.25, 0.0, 2.25])
    np.testing.assert_allclose(f("dwell_settling", x, d, c), d * np.exp(-2.0))
    t = x / 350
    bezier = (4 * t * (1 - t) ** 3 * 2.0 - 6 * t ** 2 * (1 - t) ** 2 * 1.5
              + 4 * t ** 3 * (1 - t) * 1.5)
    np.testing.assert_allclose(f("lead_error_profile", x, d, c), bezier)
    np.testing.assert_allclose(f("lead_error_profile", x, d, c, p0_um=1.0, p4_um=3.0)[[0, 2]],
                               [1.0, 3.0])


def test_records_cover_the_public_vocabulary_and_drive_the_twin():
    from features.readings import schema

    assert effects.EFFECT_NAMES == tuple(effects.EFFECTS)  # one list: the records' names
    assert schema.NO_EFFECT not in effects.EFFECTS
    for name, record in effects.EFFECTS.items():
        assert record.name == name and record.kind in ("lost_motion", "position")
        assert record.function.__doc__ and "References" in record.function.__doc__
        assert record.separating_test and record.reading and record.reference
        low, high = record.plausible
        assert low < high
        assert set(record.nuisance) - {"n_control"} <= set(record.defaults)
        if record.amplitude != "peak_um":  # profiles report their largest departure
            assert record.amplitude in record.defaults
    assert effects.LOST_MOTION == ("backlash", "backlash_position", "backlash_feed",
                                   "backlash_temperature")
    # the twin simulates the new profile through the same records: a quiet indirect axis
    # shows the Bezier curve in its mean deviations
    profile = {"p1_um": 3.0, "p2_um": -2.0, "p3_um": 2.5, "stop_mm": 350.0}
    sim = simulate(config("indirect", {"lead_error_profile": profile},
                          plan={**QUIET["plan"], "methods": ["linear"]}), seed=5)
    stats = iso230.per_target(sim.readings)
    expected = effects.contribution("lead_error_profile", stats["target"].to_numpy(), 1, {},
                                    **profile)
    np.testing.assert_allclose(stats["mean_up"], expected, atol=1e-9)


def test_play_operator_ignores_a_reversal_shorter_than_the_clearance():
    commanded = np.array([[0.0, 10.0, 9.999, 10.0, 5.0]])  # 1 um back, clearance 4 um
    table = play(commanded, np.full(commanded.shape, 4.0))
    np.testing.assert_allclose((table - commanded)[0] * 1000, [0, -2, -1, -2, 2], atol=1e-9)


def test_cycles_reverse_where_iso_says():
    targets = np.linspace(0, 350, 8)
    lin, pend = linear_path(targets, 2, 5.0), pendulum_path(targets, 2, 5.0)
    reads = lin.read
    turn = lin.reversal[reads]
    idx, direction = lin.target_index[reads], lin.direction[reads]
    assert set(zip(idx[turn], direction[turn])) == {(0, 1.0), (7, -1.0)}
    assert pend.reversal[pend.read].all() and pend.read.sum() == lin.read.sum() == 32


def test_paper_preset_is_in_the_papers_range_and_has_a_table_2_view():
    sim = simulate("paper", seed=0)
    points = backlash_targets(sim.readings)
    assert len(points) == 162 and points["backlash_um"].between(0.5, 5.5).all()
    assert 0.9 <= points["backlash_um"].median() <= 5.0
    table = paper_table(sim.readings)
    assert len(table) == 3 * 3 * 3 * 8
    assert {"position_mm", "dev_lin_f_mm", "dev_lin_r_mm", "dev_pend_f_mm", "dev_pend_r_mm",
            "speed_mm_min", "t_machine_c", "pressure_hpa", "humidity_pct"} <= set(table)


def test_same_seed_same_numbers_and_wear_resets_at_adjustment():
    a = simulate("demo", seed=7)
    pd.testing.assert_frame_equal(a.readings, simulate("demo", seed=7).readings)
    drift = simulate("drift", seed=1).visits
    one = drift[drift["machine_id"] == "M01"].set_index("visit")
    assert one.loc["09", "operating_hours"] == 0 and one.loc["09", "event"] == "adjustment"
    assert one.loc["08", "b0_um"] > one.loc["09", "b0_um"]
    assert one.loc["15", "b0_um"] - one.loc["14", "b0_um"] > 2.0  # failure


@pytest.mark.parametrize("text, words", [
    ("[effects.gremlins]\n", "unknown effect 'gremlins'"),
    ("[effects.backlash]\nb0_um = -1.0\n", "negative backlash"),
    ("[plan]\nfeeds_mm_min = [500.0, 0.0]\n", "every feed must be > 0"),
    ("[plan]\ntargets_mm = []\n", "empty target list"),
    ("[fleet]\nmachinez = 3\n", "unknown key 'fleet.machinez'"),
    ("system = 'magnetic'\n", "expected one of indirect, direct"),
])
def test_bad_config_one_line_exit_2_nothing_written(tmp_path, capsys, text, words):
    path = tmp_path / "campaign.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["simulate", "--config", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "campaign.toml" in err[0]
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


def test_simulate_writes_readings_that_read_back(tmp_path, capsys):
    assert main(["simulate", "--preset", "demo", "--seed", "3", "--out", str(tmp_path / "d")]) == 0
    names = sorted(p.name for p in (tmp_path / "d").iterdir())
    assert names == ["parameters.json", "readings.csv", "truth.csv", "truth_visits.csv"]
    from features.readings import read_readings

    readings = read_readings(tmp_path / "d" / "readings.csv")
    assert readings["visit"].nunique() == 6 and "operating_hours" in readings


def test_visit_truth_is_the_lost_motion_at_reference_conditions():
    still = {"machine_temp_c": 20.0, "warmup_k": 0.0, "machine_temp_spread_k": 0.0}
    sim = simulate(config("indirect", {"backlash": {"b0_um": 2.0},
                                       "backlash_feed": {"k_um_per_m_min": 1.0},
                                       "backlash_temperature": {}},
                          plan={**QUIET["plan"], "feeds_mm_min": [200.0, 500.0, 1200.0]},
                          environment=still, fleet={"visits": 3}), seed=5)
    visits = sim.visits.set_index("visit")
    np.testing.assert_allclose(visits["reference_backlash_um"], visits["b0_um"] + 0.5)  # 500 mm/min
    at_reference = (sim.truth[sim.truth["feed_mm_min"] == 500.0]
                    .groupby("visit")["true_backlash_um"].mean())
    np.testing.assert_allclose(at_reference, visits["reference_backlash_um"], atol=1e-9)
    assert sim.parameters["reference_conditions"]["feed_mm_min"] == 500.0


def test_screw_cools_in_the_dwell_and_the_air_drifts_along_the_run():
    env = {"machine_temp_c": 24.0, "warmup_k": 0.0, "machine_temp_spread_k": 0.0,
           "ambient_temp_c": 20.0, "ambient_spread_k": 0.0, "ambient_drift_k_per_h": 0.6}
    plan = {**QUIET["plan"], "dwells_s": [60.0], "methods": ["linear"]}
    warm = simulate(config("indirect", {"thermal_expansion": {}}, plan=plan,
                           environment=env), seed=6).readings
    cool = simulate(config("indirect", {"thermal_expansion": {}}, plan=plan,
                           environment={**env, "cooling_tau_s": 600.0}), seed=6).readings
    assert (warm["machine_temp_c"] == 24.0).all()
    # first reading: 5 mm overrun then a 60 s dwell, the air at 20 degC plus its drift
    hours = (cool["measured_at"] - cool["started_at"]).dt.total_seconds() / 3600
    np.testing.assert_allclose(cool["ambient_temp_c"], 20.0 + 0.6 * hours, atol=6e-4)
    air = 20.0 + 0.6 * hours[0]
    first = air + (24.0 - air) * np.exp(-0.6 / 1200.0 - 60.0 / 600.0)  # 5 mm at 500 mm/min
    assert cool["machine_temp_c"].iloc[0] == pytest.approx(first, abs=2e-3)
    gap = (cool["machine_temp_c"] - cool["ambient_temp_c"]).to_numpy()
    # settles on the air, lagging the rising air by at most drift x the slower time constant
    assert gap[0] > 3.0 and -0.6 * 1200 / 3600 < gap[-1] < -0.6 * 600 / 3600 / 2
    # a cooler screw is shorter: the readings follow alpha (T - 20) x
    shrink = (cool["deviation_um"] - warm["deviation_um"]).to_numpy()
    expected = 11.5e-3 * (cool["machine_temp_c"] - 24.0) * cool["target"]
    np.testing.assert_allclose(shrink, expected, atol=2.1e-3)  # temperatures to 1 mK


def test_unknown_preset_and_wrong_types_are_rejected(tmp_path, capsys):
    assert main(["simulate", "--preset", "nope", "--out", str(tmp_path / "o")]) == 2
    assert "unknown preset 'nope'" in capsys.readouterr().err
    path = tmp_path / "c.toml"
    path.write_text("[plan]\nfeeds_mm_min = ['fast']\n")
    assert main(["simulate", "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "plan.feeds_mm_min" in err and "list of numbers" in err
    assert not (tmp_path / "o").exists()


def test_local_wear_grows_with_hours_where_the_axis_works_and_resets_at_adjustment():
    from models.physics.campaign import wear_rate_um_per_1000h

    fleet = {"visits": 5, "adjust_at": [4], "wear_um_per_1000h": 0.2,
             "wear_local_um_per_1000h": 1.5, "wear_center_mm": 100.0, "wear_width_mm": 40.0}
    sim = simulate(config("indirect", {"backlash": {"b0_um": 2.0}}, fleet=fleet), seed=3)
    visits = sim.visits.set_index("visit")
    truth = sim.truth.join(visits[["operating_hours", "wear_local_um_per_1000h", "b0_um"]],
                           on="visit")
    rate = wear_rate_um_per_1000h(truth["target"], sim.parameters["config"]["fleet"],
                                  truth["wear_local_um_per_1000h"])
    np.testing.assert_allclose(truth["wear_um"], rate * truth["operating_hours"] / 1000)
    # the play is b0 (with the uniform wear) plus the local worn zone
    local = truth["wear_um"] - 0.2 * truth["operating_hours"] / 1000
    np.testing.assert_allclose(truth["true_backlash_um"], truth["b0_um"] + local, atol=1e-9)
    at = truth.groupby(["visit", "target"])["wear_um"].mean().unstack()
    assert at.loc["03"].idxmax() == 100.0 and at.loc["03", 100.0] > 5 * at.loc["03", 350.0]
    assert (at.loc["04"] == 0).all() and (at.loc["05"] > 0).all()  # the adjustment resets it
    # the ISO reversal value follows the truth on an indirect axis
    stats = per_target_truth(sim)
    np.testing.assert_allclose(-stats["B_i"], stats["true_backlash_um"], atol=1e-9)


@pytest.mark.parametrize("system", ["indirect", "direct"])
def test_twin_reversal_profile_adds_its_reversal_value_with_either_system(system):
    """The same quiet linear test with and without the reversal profile: ISO's B_i differs by
    r(x) at every target, turn-around targets included, whatever the measuring system (a
    position error, not lost motion), and r(x) changes sign along the axis."""
    profile = {"r0_um": 4.0, "r1_um": 4.0, "r2_um": 0.0, "r3_um": -4.0, "r4_um": -4.0,
               "stop_mm": 350.0}

    def reversal(effect_set):
        sim = simulate(config(system, effect_set, plan={**QUIET["plan"], "methods": ["linear"]}),
                       seed=5)
        return iso230.per_target(sim.readings).sort_values("target")

    plain = reversal({"backlash": {"b0_um": 3.0}})
    shown = reversal({"backlash": {"b0_um": 3.0}, "reversal_profile": profile})
    x = shown["target"].to_numpy()
    r = 2 * effects.contribution("reversal_profile", x, 1, {}, **profile)
    np.testing.assert_allclose(shown["B_i"].to_numpy() - plain["B_i"].to_numpy(), r, atol=1e-9)
    assert (r[:2] > 0).all() and (r[-2:] < 0).all()
