"""Conditional influence against known truth: the twin's presets and an independently written
generator. No input without a physical path may be called a driver; the true drivers must be
found in at least 9 of 10 seeds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from models import influence

NO_PATH = ("pressure_hpa", "humidity_pct", "ambient_temp_c", "dwell_s", "deviation_down_um",
           "deviation_up_um")
SEEDS = range(10)


# --- an independently written campaign: own plan, own functional forms ----------------------

AXIS_MM = 340.0
NOISE_UM = 0.3


def independent_campaign(seed: int, visits: int = 6):
    """Backlash driven by position (sin^2 wear profile), operating hours (square-root wear),
    feed (logarithmic windup) and machine temperature (saturating preload, 0.6 um over the
    range: about twice the 0.3 um per-point noise). Pressure and humidity are constant within a
    visit, ambient temperature and dwell change from run to run; none of them has a path."""
    rng = np.random.default_rng(seed)
    targets = np.array([12.0, 47.0, 95.0, 138.0, 190.0, 236.0, 281.0, 322.0])
    rows, hours = [], 0.0
    for v in range(visits):
        hours += rng.uniform(300.0, 800.0)
        pressure, humidity = rng.normal(1010.0, 6.0), rng.uniform(30.0, 65.0)
        for feed in (300.0, 800.0, 1500.0, 2500.0):
            for repeat in (1, 2):
                start_c = rng.normal(20.0, 1.0)
                ambient = start_c - 0.5 + rng.normal(0.0, 0.3)
                dwell = float(rng.choice([2.0, 4.0, 6.0]))
                for i, x in enumerate(targets):
                    rows.append({"machine_id": "K7", "axis": "Y", "visit": f"v{v}",
                                 "feed_mm_min": feed, "dwell_s": dwell, "repeat": repeat,
                                 "target": x, "operating_hours": hours,
                                 "machine_temp_c": start_c + 0.6 * feed / 2500.0 + 0.02 * i,
                                 "ambient_temp_c": ambient, "pressure_hpa": pressure,
                                 "humidity_pct": humidity})
    frame = pd.DataFrame(rows)
    parts = {
        "target": 0.9 * np.sin(np.pi * frame["target"] / AXIS_MM) ** 2,
        "operating_hours": 0.7 * np.sqrt(frame["operating_hours"] / 1000.0),
        "feed_mm_min": 0.35 * np.log(frame["feed_mm_min"] / 300.0),
        "machine_temp_c": 0.3 * np.tanh((frame["machine_temp_c"] - 20.0) / 1.2),
    }
    y = 0.8 + sum(parts.values()) + rng.normal(0.0, NOISE_UM, len(frame))
    X = frame[["target", "feed_mm_min", "machine_temp_c", "ambient_temp_c", "pressure_hpa",
               "humidity_pct", "dwell_s", "operating_hours"]]
    meta = frame[["machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target"]]
    return X, y, meta, {k: float(np.ptp(v)) for k, v in parts.items()}


def test_independent_generator_effect_sizes_are_as_stated():
    _, _, _, effect = independent_campaign(0)
    assert 1.5 * NOISE_UM < effect["machine_temp_c"] < 2.5 * NOISE_UM
    assert all(v > 1.5 * NOISE_UM for v in effect.values())  # none hides in the noise


def test_independent_generator_drivers_over_ten_seeds():
    found = {k: 0 for k in ("target", "operating_hours", "feed_mm_min", "machine_temp_c")}
    for seed in SEEDS:
        X, y, meta, effect = independent_campaign(seed)
        table = influence.conditional_influence(X, y, meta, n_boot=20, random_state=seed).table
        for name in NO_PATH:
            if name in table.index:
                assert table.loc[name, "verdict"] != "driver", (seed, name)
        for name in found:
            found[name] += table.loc[name, "verdict"] == "driver"
            if table.loc[name, "verdict"] == "driver":
                low, high = table.loc[name, ["effect_low_um", "effect_high_um"]]
                assert low - 0.35 < effect[name] < high + 0.35, (seed, name, low, high)
        assert table.loc["pressure_hpa", "level"] == "visit"
    assert min(found.values()) >= 9, found


def test_visit_constant_inputs_are_proxies_for_the_visit_not_drivers():
    X, y, meta, _ = independent_campaign(3)
    result = influence.conditional_influence(X, y, meta, association=pd.Series(True, X.columns),
                                             n_boot=10)
    table = result.table
    for name in ("pressure_hpa", "humidity_pct"):
        assert table.loc[name, "verdict"] == "proxy"
        assert table.loc[name, "proxy_for"] in ("visit", "operating_hours")
        assert "changed only between visits" in _tests_for(result, name)
        assert "vary it within a visit" in _tests_for(result, name)


def _tests_for(result, name):
    return " ".join(c["separating_test"] for c in result.design.confounded if name in c["inputs"])


# --- the twin's presets ---------------------------------------------------------------------

def _twin(preset: str, seed: int, overrides: dict | None = None):
    from features.table import feature_table
    from models.physics.campaign import load_config, simulate

    config = load_config(overrides or {}, preset=preset)
    table = feature_table(simulate(config, seed=seed).readings)
    return table


# True drivers per preset: the enabled lost-motion effects' inputs that vary in the data, and
# operating hours where wear grows between visits.
PRESETS = {
    "paper": ({}, ("target", "feed_mm_min", "machine_temp_c")),
    "demo": ({}, ("target", "feed_mm_min", "machine_temp_c", "operating_hours")),
    # indirect axis, ISO target, adjustment and failure; one run per visit leaves the
    # preload effect of machine temperature unresolvable, so it is not asserted
    "drift": ({}, ("target", "operating_hours")),
    # the fleet (4 machines x 3 axes x 8 visits, adjustment at visit 5), one dwell and one
    # repeat per feed to keep the sweep fast
    "fleet": ({"plan": {"repeats": 1, "dwells_s": [5.0]}},
              ("target", "feed_mm_min", "machine_temp_c", "operating_hours")),
}


@pytest.mark.parametrize("preset", list(PRESETS))
def test_twin_presets_over_ten_seeds(preset):
    overrides, drivers = PRESETS[preset]
    found = dict.fromkeys(drivers, 0)
    for seed in SEEDS:
        table = _twin(preset, seed, overrides)
        result = influence.conditional_influence(table.X, table.y, table.meta, n_boot=5,
                                                 random_state=seed).table
        for name in NO_PATH:
            if name in result.index:
                assert result.loc[name, "verdict"] != "driver", (preset, seed, name)
        for name in drivers:
            found[name] += result.loc[name, "verdict"] == "driver"
        for name in ("deviation_down_um", "deviation_up_um"):
            if name in result.index and result.loc[name, "verdict"] == "proxy":
                assert result.loc[name, "proxy_for"] == "backlash_um"
    assert min(found.values()) >= 9, (preset, found)


def test_paper_position_effect_about_twice_the_noise_is_found_with_its_size():
    """The paper preset's position wear bump: 0.49 um peak to peak, per-point noise 0.27 um."""
    table = _twin("paper", 1)
    row = influence.conditional_influence(table.X, table.y, table.meta, n_boot=50).table.loc[
        "target"]
    assert row["verdict"] == "driver"
    assert row["effect_low_um"] < 0.49 < row["effect_high_um"]
    assert row["effect_shape"] == "peaks inside the range"


def test_paper_machine_temperature_is_found_with_its_size_over_ten_seeds():
    """Preload change with screw temperature, -0.3 um/K: 0.5-0.8 um over the observed range,
    about twice the per-point noise, and moving with feed through warm-up. Only the run-to-run
    scatter of the pendulum test's start temperature (0.5 K) separates it from feed; the
    conditions are those of the pendulum test, whose reversals the paper target measures."""
    found, covered = 0, 0
    for seed in SEEDS:
        table = _twin("paper", seed)
        true_um = 0.3 * np.ptp(table.X["machine_temp_c"])
        row = influence.conditional_influence(table.X, table.y, table.meta, n_boot=20,
                                              random_state=seed).table.loc["machine_temp_c"]
        found += row["verdict"] == "driver"
        covered += bool(row["effect_low_um"] <= true_um <= row["effect_high_um"])
        assert row["tested"] == "run"  # between runs, against the run-to-run error
    assert found >= 9, found
    assert covered >= 9, covered


def test_a_path_input_without_its_effect_is_not_a_driver():
    """Preload effect switched off: machine temperature still moves with feed (warm-up), so it
    may be a proxy for feed, never a driver (at most one false call in ten seeds)."""
    effects = {"backlash": {"b0_um": 1.5}, "backlash_position": {"amplitude_um": 0.6},
               "backlash_feed": {"k_um_per_m_min": 1.2}, "lead_error_linear": {},
               "thermal_expansion": {}}
    calls = 0
    for seed in SEEDS:
        table = _twin("paper", seed, {"effects": effects})
        row = influence.conditional_influence(table.X, table.y, table.meta,
                                              n_boot=0).table.loc["machine_temp_c"]
        calls += row["verdict"] == "driver"
        if row["verdict"] == "proxy":
            assert row["proxy_for"] in ("feed_mm_min", "run")
    assert calls <= 1


# --- design diagnostics ---------------------------------------------------------------------

def test_design_levels_and_confounded_pairs():
    X, _, meta, _ = independent_campaign(1)
    labels = influence._nested(influence.design_groups(meta, len(X)), len(X))
    design = influence.design_diagnostics(X, labels)
    assert design.level["target"] == "point"
    assert design.level["feed_mm_min"] == "run"
    assert design.level["operating_hours"] == "visit"
    assert design.shares.loc["pressure_hpa", "visit"] == pytest.approx(1.0)
    assert design.counts == {"points": len(X), "runs": 48, "visits": 6, "units": 1}
    pairs = {frozenset(c["inputs"]) for c in design.confounded}
    assert frozenset({"machine_temp_c", "ambient_temp_c"}) in pairs  # air follows the machine
    assert frozenset({"pressure_hpa", "visit"}) in pairs


def test_dropcolumn_importance_sees_the_drivers():
    X, y, meta, _ = independent_campaign(2)
    X = X[["target", "feed_mm_min", "dwell_s", "pressure_hpa"]]
    drop = influence.dropcolumn_importance(X, y, meta, n_splits=3)
    assert drop.loc["target", "dropcolumn_um"] > 2 * drop.loc["target", "dropcolumn_std_um"]
    assert drop.loc["target", "dropcolumn_um"] > drop.loc["dwell_s", "dropcolumn_um"]


def test_effect_paths_come_from_the_effect_records():
    paths = influence.effect_paths(["target", "feed_mm_min", "machine_temp_c", "pressure_hpa",
                                    "humidity_pct", "operating_hours", "dwell_s"])
    assert {n for n, _ in paths["feed_mm_min"].paths} == {"backlash_feed"}
    assert "backlash_temperature" in {n for n, _ in paths["machine_temp_c"].paths}
    assert "backlash_position" in {n for n, _ in paths["target"].paths}
    assert paths["operating_hours"].paths
    for name in ("pressure_hpa", "humidity_pct", "dwell_s"):
        assert not paths[name].paths
    assert "air_refraction" in {n for n, _ in paths["humidity_pct"].position}


def test_bad_inputs():
    from features.readings.errors import InputError

    X, y, meta, _ = independent_campaign(0)
    with pytest.raises(InputError, match="backlash values"):
        influence.conditional_influence(X, y[:-1], meta)
    bad = X.copy()
    bad.iloc[3, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        influence.conditional_influence(bad, y, meta)


def test_an_input_the_design_cannot_test_is_undecided():
    """Two visits: operating hours change once, with no visit left to estimate the error of
    a between-visit effect: the verdict is undecided, not none and not driver."""
    X, y, meta, _ = independent_campaign(4, visits=2)
    result = influence.conditional_influence(X, y, meta, n_boot=0)
    row = result.table.loc["operating_hours"]
    assert row["verdict"] == "undecided"
    assert "cannot be decided" in row["physical_reading"]
    assert "vary it within a visit" in row["physical_reading"]
