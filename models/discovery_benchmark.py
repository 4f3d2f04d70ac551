"""Benchmark of the discovery workflow: scenarios in which effects are hidden from the
baseline, nulls in which nothing is, and designs that cannot tell effects apart.

Scenarios are data (``experiments/hidden_effect_scenarios.toml``, read by the pipeline): a
specification names the baseline, the truth every scenario carries, the hidden effects and
their parameters, the designs (plan, measuring system, noise, environment, which effects each
hides, nulls) and special scenarios (confounded, aliased, several effects at once).
``expand`` turns it into scenario dicts; ``run`` generates readings for each (the twin by
default, or any ``generate(scenario) -> readings`` function, e.g. an independently written
simulator) and runs ``discover``; ``score`` and ``score_by_design`` summarise.

Outcomes: ``correct`` (exactly the hidden effects named), ``ambiguous`` (nothing wrong named,
the hidden effects not named are in ambiguous groups), ``missed``, ``wrong`` (an effect named
that was not hidden); on nulls ``false name`` for any name.
"""

from __future__ import annotations

import copy
import time

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from models.discovery import DEFAULT_BASELINE, discover
from models.physics import effects

KINDS = ("hidden", "null", "confounded", "aliased")


def expand(spec: dict, seeds=None) -> list[dict]:
    """Scenario dicts from a specification (see the module docstring); ``seeds`` overrides the
    specification's seeds."""
    seeds = list(seeds if seeds is not None else spec.get("seeds", [1]))
    designs = spec.get("designs", {})
    hidden_params = spec.get("hidden", {})
    for name in hidden_params:
        _check_effect(name, "hidden")
    out = []
    for design_name, design in designs.items():
        names = design.get("hidden", "all")
        names = list(hidden_params) if names == "all" else list(names)
        for seed in seeds:
            for name in names:
                out.append(_scenario(spec, design_name, design, f"{name}/{design_name}/{seed}",
                                     "hidden", [name], seed))
            for k in range(int(design.get("nulls", 1))):
                out.append(_scenario(spec, design_name, design,
                                     f"null/{design_name}/{seed}" + (f"/{k + 1}" if k else ""),
                                     "null", [], seed * 100 + k))
    for special in spec.get("special", []):
        kind = special.get("kind", "hidden")
        if kind not in KINDS:
            raise InputError(f"unknown scenario kind {kind!r}; expected one of "
                             f"{', '.join(KINDS)}", column="special.kind")
        design_name = special.get("design")
        if "name" not in special:
            raise InputError("every [[special]] needs a name", column="special.name")
        if design_name not in designs:
            raise InputError(f"unknown design {design_name!r}", column="special.design")
        design = _merge(designs[design_name], {k: special[k] for k in
                                               ("plan", "environment", "system", "noise_um")
                                               if k in special})
        for seed in special.get("seeds", seeds):
            out.append(_scenario(spec, design_name, design, f"{special['name']}/{seed}", kind,
                                 list(special.get("hidden", [])), seed,
                                 special.get("params", {})))
    return out


def _check_effect(name: str, where: str) -> None:
    if name not in effects.RECORDS:
        raise InputError(f"unknown effect {name!r}; expected one of "
                         f"{', '.join(effects.RECORDS)}", column=where)


def _merge(base: dict, override: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in override.items():
        out[key] = _merge(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


def _scenario(spec, design_name, design, name, kind, hidden, seed, params=None) -> dict:
    truth = copy.deepcopy(spec.get("truth", {}))
    for effect in hidden:
        _check_effect(effect, "hidden")
        truth[effect] = {**spec.get("hidden", {}).get(effect, {}),
                         **design.get("params", {}).get(effect, {}),
                         **(params or {}).get(effect, {})}
    return {"name": name, "kind": kind, "design": design_name, "hidden": hidden, "seed": seed,
            "baseline": list(spec.get("baseline", DEFAULT_BASELINE)),
            "system": design.get("system", "indirect"),
            "noise_um": float(design.get("noise_um", 0.3)),
            "resolution_um": float(spec.get("resolution_um", 0.1)),
            "plan": copy.deepcopy(design.get("plan", {})),
            "environment": copy.deepcopy(design.get("environment", {})),
            "effects": truth}


def twin_readings(scenario: dict) -> pd.DataFrame:
    """Readings of the scenario from the feed-drive twin."""
    from models.physics.campaign import simulate

    plan = {"repeats": 1, "methods": ["linear"], **scenario["plan"]}
    stop = plan.get("stop_mm", 350.0)
    truth = copy.deepcopy(scenario["effects"])
    if "lead_error_profile" in truth:  # the profile spans the design's travel
        truth["lead_error_profile"] = {"start_mm": plan.get("start_mm", 0.0), "stop_mm": stop,
                                       **truth["lead_error_profile"]}
    config = {"system": scenario["system"], "plan": plan,
              "environment": scenario["environment"],
              "noise": {"noise_um": scenario["noise_um"],
                        "resolution_um": scenario["resolution_um"]},
              "effects": truth}
    return simulate(config, scenario["seed"]).readings


def outcome(scenario: dict, named: list, ambiguous: list) -> str:
    hidden = set(scenario["hidden"])
    if scenario["kind"] == "null" or not hidden:
        return "false name" if named else "correct"
    if set(named) - hidden:
        return "wrong"
    if set(named) == hidden:
        return "correct"
    grouped = set().union(*map(set, ambiguous)) if ambiguous else set()
    return "ambiguous" if (hidden - set(named)) <= grouped else "missed"


def run(scenarios: list[dict], generate=twin_readings, progress=None,
        generator: str = "twin") -> pd.DataFrame:
    """One row per scenario: what was named, the outcome, the gap and the CPU time
    ``discover`` took."""
    from threadpoolctl import threadpool_limits

    rows = []
    for sc in (progress(scenarios) if progress else scenarios):
        readings = generate(sc)
        # small matrices: one BLAS thread is fastest, and CPU time stays honest
        with threadpool_limits(limits=1):
            start = time.process_time()  # CPU time: the machine may be shared
            result = discover(readings, sc["baseline"], random_state=sc["seed"])
            seconds = time.process_time() - start
        not_identified = sorted({f"{s.effect}.{k}" for s in result.steps
                                 for k in s.not_identified})
        rows.append({"generator": generator, "scenario": sc["name"], "design": sc["design"],
                     "kind": sc["kind"], "hidden": ",".join(sc["hidden"]) or "none",
                     "named": ",".join(result.named),
                     "ambiguous": ";".join(",".join(g) for g in result.ambiguous),
                     "not_identified": ",".join(not_identified),
                     "outcome": outcome(sc, result.named, result.ambiguous),
                     "separating_test": any(effects.RECORDS[h].separating_test in note
                                            for h in sc["hidden"] for note in result.notes),
                     "rmse_before_um": result.rmse_before_um,
                     "rmse_after_um": result.rmse_after_um,
                     "repeatability_um": result.repeatability_um,
                     "seconds": seconds})
    return pd.DataFrame(rows)


def score(table: pd.DataFrame) -> dict:
    """Summary figures of a scenario table."""
    hidden = table[table["kind"] == "hidden"]
    nulls = table[table["kind"] == "null"]
    hard = table[table["kind"].isin(["confounded", "aliased"])]
    correct = hidden["outcome"] == "correct"
    shrink = (hidden["rmse_before_um"] / hidden["rmse_after_um"])[correct]
    gap = (hidden["rmse_after_um"] / hidden["repeatability_um"])[correct]
    return {
        "scenarios": len(table),
        "hidden_scenarios": len(hidden),
        "named_correctly": int(correct.sum()),
        "named_correctly_pct": float(100 * correct.mean()) if len(hidden) else float("nan"),
        "ambiguous": int((table["outcome"] == "ambiguous").sum()),
        "wrong": int((hidden["outcome"] == "wrong").sum()),
        "missed": int((hidden["outcome"] == "missed").sum()),
        "null_scenarios": len(nulls),
        "false_names_on_nulls": int((nulls["outcome"] == "false name").sum()),
        "hard_scenarios": len(hard),
        "hard_answered_ambiguous_with_test": int(((hard["outcome"] == "ambiguous")
                                                  & hard["separating_test"]).sum()),
        "confident_wrong_on_confounded_or_aliased": int((hard["outcome"] == "wrong").sum()),
        "mean_gap_shrink": float(np.mean(shrink)) if len(shrink) else float("nan"),
        "max_gap_after_over_noise": float(gap.max()) if len(gap) else float("nan"),
        "max_seconds_per_scenario": float(table["seconds"].max()),
    }


def score_by_design(table: pd.DataFrame) -> pd.DataFrame:
    """Per generator and design: hidden effects named, nulls clean, hard designs ambiguous."""
    rows = []
    for (generator, design), part in table.groupby(["generator", "design"], sort=False):
        s = score(part)
        rows.append({"generator": generator, "design": design,
                     "named": f"{s['named_correctly']}/{s['hidden_scenarios']}",
                     "false names on nulls": f"{s['false_names_on_nulls']}/{s['null_scenarios']}",
                     "ambiguous with test (hard)":
                         f"{s['hard_answered_ambiguous_with_test']}/{s['hard_scenarios']}",
                     "wrong": s["wrong"], "max gap after / noise":
                         round(s["max_gap_after_over_noise"], 2),
                     "max s": round(s["max_seconds_per_scenario"], 2)})
    return pd.DataFrame(rows)
