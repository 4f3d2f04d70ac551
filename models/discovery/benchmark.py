"""Benchmark of the discovery workflow: scenarios in which effects are hidden from the
baseline, nulls in which nothing is, and designs that cannot tell effects apart.

Scenarios are data (``experiments/hidden_effect_scenarios.toml``, read by ``read_scenarios``
into a ``Scenarios``): a specification names the baseline, the truth every scenario carries, the hidden effects and
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
import dataclasses
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pandas as pd

from features.readings.config import from_table, read_config
from features.readings.errors import InputError
from models.discovery import DEFAULT_BASELINE, discover
from models.physics import effects

KINDS = ("hidden", "null", "confounded", "aliased")
Effects = dict[str, dict[str, float]]  # effect name -> its parameters


@dataclass
class Design:
    """How a test was run: measuring system, noise [um], plan and environment (overrides of the
    twin's campaign tables), which effects it hides (``"all"``: every ``[hidden]`` one), null
    scenarios per seed and effect parameters of this design."""

    system: Literal["indirect", "direct"] = "indirect"
    noise_um: float = 0.3
    hidden: list[str] | Literal["all"] = "all"
    nulls: int = 1
    plan: dict = field(default_factory=dict)
    environment: dict = field(default_factory=dict)
    params: Effects = field(default_factory=dict)


@dataclass
class Special:
    """A scenario of its own on a design: several hidden effects, a confounded or aliased
    design (its ``plan``, ``environment``, ``system`` and ``noise_um`` override the design's)."""

    name: str
    design: str
    kind: Literal["hidden", "null", "confounded", "aliased"] = "hidden"
    hidden: list[str] = field(default_factory=list)
    seeds: list[int] | None = None
    plan: dict = field(default_factory=dict)
    environment: dict = field(default_factory=dict)
    system: Literal["indirect", "direct"] | None = None
    noise_um: float | None = None
    params: Effects = field(default_factory=dict)


@dataclass
class Scenarios:
    """A benchmark specification (``experiments/hidden_effect_scenarios.toml``)."""

    designs: dict[str, Design] = field(default_factory=dict)
    baseline: list[str] = field(default_factory=lambda: list(DEFAULT_BASELINE))
    seeds: list[int] = field(default_factory=lambda: [1])
    resolution_um: float = 0.1
    truth: Effects = field(default_factory=dict)
    hidden: Effects = field(default_factory=dict)
    special: list[Special] = field(default_factory=list)

    def check(self, file) -> None:
        """Known effects and designs, plans and environments the twin can run."""
        _check(self, file)


def read_scenarios(source) -> Scenarios:
    """A benchmark specification from a TOML file or a dict of the same shape; unknown keys,
    effects and designs are one ``InputError`` naming the file and the key."""
    if isinstance(source, Scenarios):
        return source
    return read_config(source, Scenarios, what="scenarios")


def _check(spec: Scenarios, file) -> None:
    from models.physics.campaign import Environment, Plan

    def known(names, column):
        for name in names:
            if name not in effects.EFFECTS:
                raise InputError(f"unknown effect {name!r}; expected one of "
                                 f"{', '.join(effects.EFFECTS)}", file=file, column=column)

    if not spec.designs:
        raise InputError("no [designs.*]: a benchmark needs at least one design", file=file)
    known(spec.baseline, "baseline")
    known(spec.truth, "truth")
    known(spec.hidden, "hidden")
    if any(s < 0 for s in spec.seeds):
        raise InputError(f"a seed is a whole number >= 0, got {min(spec.seeds)}", file=file,
                         column="seeds")
    parts = [(f"designs.{k}", d) for k, d in spec.designs.items()]
    parts += [(f"special[{i}]", s) for i, s in enumerate(spec.special, start=1)]
    for key, part in parts:
        known([] if part.hidden == "all" else part.hidden, f"{key}.hidden")
        known(part.params, f"{key}.params")
        # the twin's own tables: unknown keys and wrong kinds are named here, not mid-run
        from_table(part.plan, Plan, file=file, prefix=f"{key}.plan.")
        from_table(part.environment, Environment, file=file, prefix=f"{key}.environment.")
        if (part.noise_um or 0) < 0:
            raise InputError("noise must be >= 0 um", file=file, column=f"{key}.noise_um")
        if isinstance(part, Design) and part.nulls < 0:
            raise InputError(f"nulls must be >= 0, got {part.nulls}", file=file,
                             column=f"{key}.nulls")
        if isinstance(part, Special) and part.design not in spec.designs:
            raise InputError(f"unknown design {part.design!r}; expected one of "
                             f"{', '.join(spec.designs)}", file=file, column=f"{key}.design")


def expand(spec, seeds=None) -> list[dict]:
    """Scenario dicts from a specification (a ``Scenarios``, or a TOML file or dict read by
    ``read_scenarios``); ``seeds`` overrides the specification's seeds."""
    spec = read_scenarios(spec)
    seeds = list(seeds if seeds is not None else spec.seeds)
    out = []
    for design_name, design in spec.designs.items():
        names = list(spec.hidden) if design.hidden == "all" else list(design.hidden)
        for seed in seeds:
            for name in names:
                out.append(_scenario(spec, design_name, design, f"{name}/{design_name}/{seed}",
                                     "hidden", [name], seed))
            for k in range(design.nulls):
                out.append(_scenario(spec, design_name, design,
                                     f"null/{design_name}/{seed}" + (f"/{k + 1}" if k else ""),
                                     "null", [], seed * 100 + k))
    for special in spec.special:
        base = spec.designs[special.design]
        design = dataclasses.replace(
            base, plan=_merge(base.plan, special.plan),
            environment=_merge(base.environment, special.environment),
            system=special.system or base.system,
            noise_um=base.noise_um if special.noise_um is None else special.noise_um)
        for seed in (special.seeds if special.seeds is not None else seeds):
            out.append(_scenario(spec, special.design, design, f"{special.name}/{seed}",
                                 special.kind, list(special.hidden), seed, special.params))
    return out


def _merge(base: dict, override: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in override.items():
        out[key] = _merge(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


def _scenario(spec: Scenarios, design_name, design: Design, name, kind, hidden, seed,
              params=None) -> dict:
    truth = copy.deepcopy(spec.truth)
    for effect in hidden:
        truth[effect] = {**spec.hidden.get(effect, {}), **design.params.get(effect, {}),
                         **(params or {}).get(effect, {})}
    return {"name": name, "kind": kind, "design": design_name, "hidden": hidden, "seed": seed,
            "baseline": list(spec.baseline), "system": design.system,
            "noise_um": float(design.noise_um), "resolution_um": float(spec.resolution_um),
            "plan": copy.deepcopy(design.plan), "environment": copy.deepcopy(design.environment),
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
                     "separating_test": any(effects.EFFECTS[h].separating_test in note
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
