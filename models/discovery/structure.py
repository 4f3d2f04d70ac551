"""What the design cannot tell apart (confounded and aliased effects), and what is left when
nothing passes: the size of the gap and the residual's structure, or that it is noise."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from models.discovery.design import Design, max_corr, projector, residualise, stack
from models.discovery.terms import EFFECTS, PROFILES, nuisance_grid, nuisances

COLLINEAR = 0.95
STOP_RATIO = 1.05   # residual within 5 % of the repeatability: nothing measurable left
NOISE_RATIO = 2.0   # a single run whose gap is within twice the repeatability: noise-dominated
STRUCTURE_P = 0.01  # significance of a residual structure (F-test), Bonferroni over factors
# residual structure: factor -> readings column(s) an effect acting along it would need
FACTOR_INPUTS = {"position": "target", "direction": "direction",
                 "position x direction": "target", "run x position": "target",
                 "cycle": "measured_at", "time": "measured_at",
                 "temperature": "machine_temp_c", "feed": "feed_mm_min", "dwell": "dwell_s"}


def confounding_notes(design: Design, model: dict, skipped: dict, result) -> None:
    """Candidates this design cannot see apart from the model, and aliased periodic errors:
    notes and ambiguous groups added to ``result`` (a ``Discovery``)."""
    base = stack(design, model)
    proj = projector(base)
    for name in EFFECTS:
        if name in model or name in skipped or name in PROFILES:
            continue
        key, grid = nuisance_grid(name, design.x)
        nuisance = {} if key is None else {key: float(grid[len(grid) // 2])}
        col = design.column(name, nuisance)
        total = float(np.sum(col ** 2))
        if total < 1e-12:
            continue
        left = float(np.sum(residualise(col, proj) ** 2)) / total
        if left < 1e-3:
            twins = [m for m in model if max_corr(col, design.column(m, model[m])) > COLLINEAR]
            result.notes.append(f"{name} cannot be told apart from {', '.join(twins) or 'the model'}"
                                f" on this design: {EFFECTS[name].separating_test}")
            if twins:
                add_group(result.ambiguous, {name, *twins})
    spacing = np.diff(np.unique(design.x))
    if len(spacing) and "lead_error_periodic" not in model:
        (period,) = [n for n in nuisances("lead_error_periodic") if n.kind == "period"]
        low, high = period.values
        # pitches dividing every spacing: the periodic error has one phase at every target
        pitches = spacing[0] / np.arange(1, int(spacing[0] / low) + 1)
        pitches = pitches[(pitches >= low) & (pitches <= high)]
        aliased = [p for p in pitches if np.allclose(spacing / p, np.round(spacing / p), atol=1e-6)]
        if aliased:
            result.notes.append(
                "lead_error_periodic with a pitch of " + ", ".join(f"{p:g}" for p in aliased)
                + " mm is invisible at this target spacing on this design: "
                + EFFECTS["lead_error_periodic"].separating_test)
            add_group(result.ambiguous, {"lead_error_periodic"})


def add_group(groups: list, members: set) -> None:
    """Add an ambiguous group, merging it with any group it shares an effect with."""
    for group in groups:
        if members & set(group):
            group[:] = sorted(members | set(group))
            return
    groups.append(sorted(members))


def residual_structure(design: Design, resid: np.ndarray) -> list[dict]:
    """How much of the residual each factor explains: the between-group share of the residual's
    sum of squares (adjusted for the number of groups) and its F-test p-value, strongest
    first. Continuous factors (time, temperature) are cut into five quantile bins."""
    from scipy.stats import f as f_dist

    factors = {"position": design.x, "direction": design.d,
               "position x direction": design.x * 10 + design.d,
               "run x position": design.run * 1e6 + design.x, "cycle": design.cycle}
    for name, key in (("time", "elapsed_s"), ("temperature", "machine_temp_c"),
                      ("feed", "feed_mm_min"), ("dwell", "dwell_s")):
        values = design.cond.get(key)
        if values is None or np.ptp(values) <= 0:
            continue
        if name in ("time", "temperature"):
            edges = np.unique(np.quantile(values, np.linspace(0, 1, 6)))
            values = np.digitize(values, edges[1:-1])
        factors[name] = values * 10 + design.d if name in ("feed", "dwell") else values
    n, total = len(resid), float(np.sum(resid ** 2))
    rows = []
    for name, values in factors.items():
        codes, groups = pd.factorize(values)
        g = len(groups)
        if g < 2 or g >= n - 1 or total <= 0:
            continue
        means = np.bincount(codes, resid) / np.bincount(codes)
        between = float(np.sum(np.bincount(codes) * means ** 2))
        within = total - between
        share = between / total
        adjusted = 1 - (1 - share) * (n - 1) / (n - g)
        p = float(f_dist.sf((between / (g - 1)) / max(within / (n - g), 1e-300), g - 1, n - g))
        rows.append({"against": name, "share": round(share, 4), "adjusted_share":
                     round(adjusted, 4), "p_value": p,
                     "rms_um": round(math.sqrt(between / n), 4)})
    return sorted(rows, key=lambda r: -r["adjusted_share"])


def significant_structure(design: Design, resid: np.ndarray) -> list[dict]:
    """The rows of ``residual_structure`` significant at ``STRUCTURE_P`` (Bonferroni over the
    factors tested), strongest first."""
    structure = residual_structure(design, resid)
    level = STRUCTURE_P / max(len(structure), 1)
    return [s for s in structure if s["p_value"] < level]


def acts_along(name: str) -> set[str]:
    """The residual factors an effect acts along: those whose input (``FACTOR_INPUTS``) it
    reads, the direction for lost motion, and run x position when it reads the target and a
    condition that changes from run to run."""
    record = EFFECTS[name]
    inputs = set(record.inputs) | ({"direction"} if record.kind == "lost_motion" else set())
    factors = {f for f, column in FACTOR_INPUTS.items()
               if column in inputs and f != "run x position"}
    if "target" in inputs and inputs - {"target", "direction"}:
        factors.add("run x position")
    return factors


def structured_beyond(design: Design, resid: np.ndarray, model: dict) -> bool:
    """Whether the residual varies significantly along a factor no effect of the model acts
    along: what a floor inflated by a slow drift would hide, unlike the small shape difference
    of an effect already named."""
    acts = set().union(*(acts_along(name) for name in model))
    return any(s["against"] not in acts for s in significant_structure(design, resid))


def structured(design: Design, resid: np.ndarray) -> bool:
    """Whether the residual holds structure its own F-test finds significant: a file that
    does is never called noise-dominated."""
    return bool(significant_structure(design, resid))


def unexplained(design: Design, resid: np.ndarray, result, single_noise: bool) -> dict | None:
    """The remaining gap when it stays above the repeatability: its size and the residual's
    strongest structure, or the reason it is noise (its reason is added to ``result.notes``)."""
    gap, noise, unit = result.rmse_after_um, result.repeatability_um, result.unit
    if not np.isfinite(noise) or noise <= 0 or gap <= STOP_RATIO * noise:
        return None
    structure = residual_structure(design, resid)
    level = STRUCTURE_P / max(len(structure), 1)
    significant = [s for s in structure if s["p_value"] < level]
    out = {"gap_um": gap, "repeatability_um": noise, "ratio": gap / noise,
           "structure": structure, "strongest": None, "verdict": "", "candidates": []}
    if single_noise or not significant:
        out["verdict"] = "noise-dominated"
        why = (f"the gap ({gap:.3g} {unit}) is within {NOISE_RATIO:g}x the repeatability "
               f"({noise:.3g} {unit}) of a single run" if single_noise else
               f"the residual shows no significant structure (F-test, p >= {level:.2g}) against "
               + ", ".join(s["against"] for s in structure))
        out["reason"] = (f"noise-dominated: {why}; "
                         + ("nothing more to name after " + ", ".join(result.named)
                            if result.named else "nothing to name"))
    else:
        top = significant[0]
        column = FACTOR_INPUTS[top["against"]]
        out["strongest"] = top["against"]
        out["verdict"] = "structure"
        out["candidates"] = [n for n, r in EFFECTS.items()
                             if (column in r.inputs or (column == "direction"
                                                        and r.kind == "lost_motion"))
                             and n not in result.named]
        out["reason"] = (f"the gap ({gap:.3g} {unit}, {gap / noise:.1f}x the repeatability) is "
                         f"not explained: the residual varies most with {top['against']} "
                         f"({100 * top['share']:.0f} % of it, rms {top['rms_um']:.3g} {unit}), and no "
                         "candidate passes")
    result.notes.append(out["reason"])
    return out
