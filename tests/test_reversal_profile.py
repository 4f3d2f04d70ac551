"""A reversal value that changes along the axis: the ``reversal_profile`` effect, the
measuring-system decision from the interior reversal values, real-like cases written by hand
(``reversal_cases``), the twin, and pairs of effects from a third generator
(``independent_pairs``)."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd
import pytest
from independent_pairs import PAIRS
from independent_pairs import generate as pair_readings
from reversal_cases import indirect_stage, iso_test, sign_changing

from models.discovery import benchmark as bench
from models.discovery import discover
from models.discovery.design import Design, lstsq_fit, stack
from models.discovery.system import measuring_system
from models.physics import effects
from pipeline.workflows.hidden_effects import SCENARIOS


def test_reversal_profile_is_half_the_reversal_value_of_either_sign():
    x = np.array([0.0, 175.0, 350.0, 350.0])
    d = np.array([1.0, 1.0, 1.0, -1.0])
    # defaults R = (4, 4, 0, -4, -4): r(0) = 4, r(175) = (4 + 16 + 0 - 16 - 4) / 16 = 0, r(350) = -4
    np.testing.assert_allclose(effects.contribution("reversal_profile", x, d, {}),
                               [2.0, 0.0, -2.0, 2.0], atol=1e-12)
    record = effects.EFFECTS["reversal_profile"]
    assert record.kind == "position" and "b(x) >= 0" in record.separating_test


def test_sign_changing_five_target_file_gets_reversal_profile():
    """Reversal value +18, -14, -24, +10, +20 um, 5 um noise: a clearance b(x) >= 0 cannot
    make it, the general lost-motion forms are refused, and the half-difference between the
    directions closes the gap (without the effect it stays at 2x its floor)."""
    result = discover(sign_changing(seed=0))
    assert result.named == ["reversal_profile"]
    assert result.rmse_before_um > 1.8 * result.repeatability_um
    assert result.rmse_after_um <= 1.5 * result.repeatability_um
    (step,) = result.steps
    assert step.parameters["n_control"] == 5 and len(step.parameters["control_um"]) == 5
    low, high = step.interval["peak_um"]
    assert low <= step.parameters["peak_um"] <= high
    assert any("reversal_profile varies along the axis" in n for n in result.notes)


def test_indirect_stage_is_decided_from_its_interior_reversal_values():
    """9 targets over +-20 mm, reversal value -16 to -34 um at every target: lost motion at
    the interior targets means an indirect system, although the baseline fits better as a
    direct one (a large cubic lead error leaves its residual at the turn-around targets);
    the reversal keeps one sign, so it is a clearance varying along the axis, not a reversal
    profile. Fitted as direct it stayed ambiguous with its gap at 5x the floor."""
    readings = indirect_stage(seed=0)
    design, sse = Design(readings), {}
    for system in ("indirect", "direct"):
        design.system = system
        X = stack(design, {"backlash": {}, "lead_error_linear": {}})
        sse[system] = float(np.sum(lstsq_fit(X, design.y0)[1] ** 2))
    assert sse["direct"] < sse["indirect"]
    test = measuring_system(readings)
    assert test.system == "indirect" and test.n == 7
    # the 7 interior values -19 ... -21 average -185 / 7 = -26.4 um
    assert test.mean_um == pytest.approx(-185 / 7, abs=1.5)
    assert test.statistic < -5 and test.p_value < 1e-3
    result = discover(readings)
    assert result.measuring_system["system"] == "indirect"
    assert any("indirect measuring system" in n and "p = " in n for n in result.notes)
    assert sorted(result.named) == ["backlash_position", "lead_error_profile"]
    assert result.rmse_before_um > 9 * result.repeatability_um
    assert result.rmse_after_um <= 1.5 * result.repeatability_um


def test_direct_system_shows_lost_motion_only_after_a_reversal():
    x = np.linspace(0.0, 300.0, 7)
    readings = iso_test(x, 0.01 * x, np.zeros(7), 0.3, "direct", clearance_um=8.0)
    test = measuring_system(readings)
    assert test.system == "direct" and test.p_value > 0.01
    result = discover(readings)
    assert result.measuring_system["system"] == "direct"
    assert result.named == [] and result.rmse_after_um <= 1.2 * result.repeatability_um


def test_pendulum_tests_tell_a_settling_offset_from_lost_motion():
    """Direct system, 6 um clearance, and a +1.2 um direction-dependent settling offset at
    every target: the interior reversal values are not zero, but they are far from the
    pendulum tests' -4.8 um, which an indirect system would show there too."""
    x = np.linspace(0.0, 300.0, 7)
    mean, settle = 0.01 * x, np.full(7, 1.2)
    readings = pd.concat([
        iso_test(x, mean, settle, 0.3, "direct", clearance_um=6.0, seed=1),
        iso_test(x, mean, settle, 0.3, "direct", clearance_um=6.0, seed=2,
                 method="pendulum", test_id="pen-1")], ignore_index=True)
    test = measuring_system(readings)
    assert test.p_value < 1e-3                              # not zero inside ...
    assert test.pendulum_mean_um == pytest.approx(-4.8, abs=0.3)
    assert abs(test.pendulum_statistic) > abs(test.statistic)  # ... but not lost motion
    assert test.system == "direct"
    assert "pendulum_statistic" in test.to_dict()


def test_a_profile_in_the_baseline_is_its_finest_general_form():
    result = discover(sign_changing(seed=0), ["backlash", "lead_error_linear",
                                              "reversal_profile"])
    assert "reversal_profile" not in result.named
    assert result.rmse_before_um <= 1.5 * result.repeatability_um


@pytest.fixture(scope="module")
def twin_scenarios():
    """The benchmark's designs A (indirect, linear) and D (direct, linear and pendulum) with
    the twin's reversal profile hidden, alone and with a lead profile or a clearance along
    the axis."""
    spec = tomllib.loads(SCENARIOS.read_text())
    hidden = spec["hidden"]
    spec["hidden"] = {"reversal_profile": {}, "lead_error_profile": hidden["lead_error_profile"],
                      "backlash_position": hidden["backlash_position"]}
    spec["designs"] = {k: dict(spec["designs"][k], hidden=["reversal_profile"], nulls=0)
                       for k in ("A", "D")}
    spec["special"] = [
        {"name": "reversal and lead profile", "design": "A",
         "hidden": ["reversal_profile", "lead_error_profile"]},
        {"name": "reversal and clearance along the axis", "design": "D",
         "hidden": ["reversal_profile", "backlash_position"]}]
    return bench.expand(bench.read_scenarios(spec), seeds=[1])


def test_twin_reversal_profile_is_named_with_either_measuring_system(twin_scenarios):
    table = bench.run(twin_scenarios)
    assert len(table) == 4 and (table["outcome"] == "correct").all(), table
    assert (table["rmse_after_um"] <= 1.2 * table["repeatability_um"]).all()


@pytest.mark.parametrize("pair", PAIRS, ids=["+".join(p) for p in PAIRS])
def test_both_members_of_a_pair_are_named(pair):
    """Forms of their own (raised-cosine wear, a hysteresis changing sign, a hyperbolic
    warm-up, refraction from a logged air state...): both effects named, nothing else, the
    gap down to the floor (3 seeds: 24 of 24)."""
    result = discover(pair_readings(pair, seed=1), random_state=1)
    assert sorted(result.named) == sorted(pair)
    assert result.rmse_after_um <= 1.3 * result.repeatability_um


def test_pair_generator_without_effects_names_nothing():
    result = discover(pair_readings((), seed=1), random_state=1)
    assert result.named == [] and result.unexplained is None
