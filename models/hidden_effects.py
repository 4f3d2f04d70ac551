"""Hidden-effect benchmark of the discovery workflow: twin data in which one effect is hidden
from the baseline (``backlash, lead_error_linear``), over seeds and test designs, plus null,
confounded and aliased scenarios.

Scores: ``correct`` (exactly the hidden effect named), ``ambiguous`` (nothing named, the hidden
effect in an ambiguous group), ``wrong`` (anything else); nulls count false names; confounded
and aliased designs must not name a wrong effect with confidence.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from models.discovery import DEFAULT_BASELINE, discover
from models.physics.campaign import simulate

# Linear tests, indirect system, irregular targets; conditions vary between runs so that
# every effect a linear test can show is identifiable.
DESIGNS = {
    "A": {"plan": {"start_mm": 0.0, "stop_mm": 350.0, "n_targets": 11, "irregular": True,
                   "feeds_mm_min": [200.0, 500.0, 1200.0], "dwells_s": [1.0, 3.0, 8.0]}},
    "B": {"plan": {"start_mm": 0.0, "stop_mm": 300.0, "n_targets": 9, "irregular": True,
                   "feeds_mm_min": [300.0, 800.0, 1500.0], "dwells_s": [2.0, 4.0, 10.0]}},
}
COMMON = {"system": "indirect", "noise": {"noise_um": 0.3, "resolution_um": 0.1},
          "environment": {"machine_temp_spread_k": 2.5, "ambient_spread_k": 1.5,
                          "pressure_spread_hpa": 12.0, "humidity_spread_pct": 15.0}}
BASELINE_TRUTH = {"backlash": {"b0_um": 3.0}, "lead_error_linear": {"k_um_per_m": 8.0}}
HIDDEN = {
    "backlash_position": {"amplitude_um": 2.0, "center_mm": 120.0},
    "backlash_feed": {"k_um_per_m_min": 2.0},
    "backlash_temperature": {"k_um_per_k": -0.5},
    "lead_error_periodic": {"amplitude_um": 1.0, "pitch_mm": 10.0},
    "thermal_expansion": {},
    "thermal_drift": {"amplitude_um": 2.0},
    "air_refraction": {},
    "abbe": {},
    "dwell_settling": {"amplitude_um": 1.5},
}
CONSTANT_CONDITIONS = {"environment": {"machine_temp_spread_k": 0.0, "warmup_k": 0.0,
                                       "ambient_spread_k": 0.0, "pressure_spread_hpa": 0.0,
                                       "humidity_spread_pct": 0.0}}


@dataclass
class Scenario:
    name: str
    kind: str            # hidden, null, confounded, aliased
    hidden: str          # effect name or "none"
    config: dict
    seed: int


def _config(design: dict, effect: str | None, params: dict | None, extra: dict | None = None):
    config = {**COMMON, **design, "effects": dict(BASELINE_TRUTH)}
    config["plan"] = {**design["plan"], "repeats": 1, "methods": ["linear"]}
    if effect:
        config["effects"][effect] = params
    for key, value in (extra or {}).items():
        config[key] = {**config.get(key, {}), **value}
    return config


def scenarios(seeds=(1, 2)) -> list[Scenario]:
    out = []
    for design_name, design in DESIGNS.items():
        for seed in seeds:
            for effect, params in HIDDEN.items():
                out.append(Scenario(f"{effect}/{design_name}/{seed}", "hidden", effect,
                                    _config(design, effect, params), seed))
            out.append(Scenario(f"null/{design_name}/{seed}", "null", "none",
                                _config(design, None, None), seed))
    design = DESIGNS["A"]
    for seed in seeds:
        out.append(Scenario(f"confounded thermal_expansion/{seed}", "confounded",
                            "thermal_expansion",
                            _config(design, "thermal_expansion", {}, CONSTANT_CONDITIONS), seed))
        aliased = {"plan": {**design["plan"], "n_targets": 8, "irregular": False}}
        out.append(Scenario(f"aliased lead_error_periodic/{seed}", "aliased",
                            "lead_error_periodic",
                            _config(aliased, "lead_error_periodic", HIDDEN["lead_error_periodic"]),
                            seed))
    out.append(Scenario("confounded air_refraction/1", "confounded", "air_refraction",
                        _config(design, "air_refraction", {}, CONSTANT_CONDITIONS), 1))
    return out


def outcome(scenario: Scenario, named: list, ambiguous: list) -> str:
    in_group = any(scenario.hidden in group for group in ambiguous)
    if scenario.kind == "null":
        return "false name" if named else "correct"
    if named == [scenario.hidden]:
        return "correct"
    if any(n != scenario.hidden for n in named):
        return "wrong"
    return "ambiguous" if in_group else "missed"


def run(scenario_list: list[Scenario], progress=None) -> pd.DataFrame:
    rows = []
    for sc in (progress(scenario_list) if progress else scenario_list):
        start = time.perf_counter()
        readings = simulate(sc.config, sc.seed).readings
        result = discover(readings, DEFAULT_BASELINE, random_state=sc.seed)
        rows.append({"scenario": sc.name, "kind": sc.kind, "hidden": sc.hidden,
                     "named": ",".join(result.named),
                     "ambiguous": ";".join(",".join(g) for g in result.ambiguous),
                     "outcome": outcome(sc, result.named, result.ambiguous),
                     "rmse_before_um": result.rmse_before_um,
                     "rmse_after_um": result.rmse_after_um,
                     "repeatability_um": result.repeatability_um,
                     "seconds": time.perf_counter() - start})
    return pd.DataFrame(rows)


def score(table: pd.DataFrame) -> dict:
    hidden = table[table["kind"] == "hidden"]
    nulls = table[table["kind"] == "null"]
    hard = table[table["kind"].isin(["confounded", "aliased"])]
    shrink = hidden["rmse_before_um"] / hidden["rmse_after_um"]
    return {
        "scenarios": len(table),
        "hidden_scenarios": len(hidden),
        "named_correctly": int((hidden["outcome"] == "correct").sum()),
        "named_correctly_pct": float(100 * (hidden["outcome"] == "correct").mean()),
        "ambiguous": int((table["outcome"] == "ambiguous").sum()),
        "wrong": int((hidden["outcome"] == "wrong").sum()),
        "false_names_on_nulls": int((nulls["outcome"] == "false name").sum()),
        "confident_wrong_on_confounded_or_aliased": int((hard["outcome"] == "wrong").sum()),
        "mean_gap_shrink": float(np.mean(shrink)),
        "max_gap_after_over_noise": float((hidden["rmse_after_um"]
                                           / hidden["repeatability_um"]).max()),
        "max_seconds_per_scenario": float(table["seconds"].max()),
    }
