"""Which passing candidate is named: the winner and its ambiguity group, nesting of the
general smooth forms, the bootstrap that checks the winner is stable, and its parameters."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from models.discovery.candidates import BIC_THRESHOLD, amplitude, column_start, fit_batch
from models.discovery.design import (
    Design,
    bic,
    cv_rmse,
    lstsq_fit,
    projector,
    residualise,
    stack,
)
from models.discovery.terms import EFFECTS, data_value, quadrature_pairs, signed_by_approach

BOOT_SAMPLES = 40
BOOT_AGREEMENT = 0.8
BOOT_MIN_RUNS = 8   # fewer runs: resample cycles within runs instead of whole runs
NESTED_SHARE = 0.9  # a specific effect with this share of a general form's gain stands in
CLOSE_BIC = 10.0    # candidates whose BIC differ by less than this cannot be told apart


class Choice(NamedTuple):
    """The candidate to name, the candidates it cannot be told apart from (itself included)
    and the general smooth form it stood in for (or None)."""

    winner: pd.Series
    group: set
    stand_in: str | None


def choose(design: Design, model: dict, passing: pd.DataFrame, sse0: float) -> Choice:
    """The winner among the passing candidates and its ambiguity group. A general smooth form
    nests the specific effects along the same input, so it wins only by a decisive BIC margin,
    is never grouped with them, and yields to a nested specific effect that gives at least
    ``NESTED_SHARE`` of its gain with an identified shape, or predicts held-out targets at
    least as well (leave one target out): then the general form only describes the specific
    effect's shape a little better, not another effect."""
    specific = passing[passing["form"] == "specific"]
    general = passing[passing["form"] == "general"]
    if len(general) and (specific.empty or general["delta_bic"].iloc[0]
                         < specific["delta_bic"].iloc[0] + BIC_THRESHOLD):
        winner = general.iloc[0]
        nested_ = specific[[nested(e, winner["effect"]) for e in specific["effect"]]]
        if len(nested_):
            rival = nested_.iloc[0]
            # most of the gain with a fixed shape, unless an unresolved pitch lets it alias
            share = (sse0 - rival["sse"]) / max(sse0 - winner["sse"], 1e-300)
            if ((share >= NESTED_SHARE and not rival["not_identified"])
                    or target_cv(design, model, rival) <= target_cv(design, model, winner)):
                return Choice(rival, ambiguous_group(rival, nested_), winner["effect"])
        return Choice(winner, ambiguous_group(winner, general.drop_duplicates("effect")), None)
    winner = specific.iloc[0]
    return Choice(winner, ambiguous_group(winner, specific.drop_duplicates("effect")), None)


def clearance_first(passing: pd.DataFrame) -> pd.DataFrame:
    """A direction-dependent profile (``reversal_profile``) is named only where a clearance
    cannot explain it: a lost-motion candidate passes only when b(x) >= 0 holds along the axis
    (a reversal value of one sign at every target), and then the profile yields to it unless
    its BIC is lower by more than ``CLOSE_BIC`` (with an indirect system the two general forms
    are the same columns)."""
    if passing.empty:
        return passing
    lost = [EFFECTS[e].kind == "lost_motion" for e in passing["effect"]]
    if not any(lost):
        return passing
    best = float(passing.loc[lost, "delta_bic"].min())
    keep = [not (signed_by_approach(row["effect"]) and row["delta_bic"] > best - CLOSE_BIC)
            for _, row in passing.iterrows()]
    return passing[keep]


def target_cv(design: Design, model: dict, candidate) -> float:
    """Held-out RMSE of model + candidate, leaving out one target position at a time: how
    well the candidate's shape predicts the error where it was not fitted."""
    X = np.column_stack([stack(design, model),
                         design.column(candidate["effect"], candidate["nuisance"])])
    return cv_rmse(X, design.y0, pd.factorize(design.x)[0])


def nested(specific: str, general: str) -> bool:
    """A specific effect the general smooth form can represent: same kind, same inputs."""
    a, b = EFFECTS[specific], EFFECTS[general]
    return a.kind == b.kind and set(a.inputs) == set(b.inputs)


def ambiguous_group(winner, pool: pd.DataFrame) -> set:
    """The winner and every candidate of its pool it cannot be told apart from here: BIC
    within ``CLOSE_BIC`` (columns collinear on this design fit equally well and land here)."""
    group = {winner["effect"]}
    for _, other in pool.iterrows():
        if other["delta_bic"] - winner["delta_bic"] < CLOSE_BIC:
            group.add(other["effect"])
    return group


def bootstrap(design: Design, model: dict, winner, passing: pd.DataFrame, rng):
    """Resample runs (cycles of a single run) with replacement: the winner must hold among the
    passing candidates of its kind, and its amplitude's 95 % interval must exclude zero.
    Returns (stable, [low, high]).

    The winner holds in a resample when it is the best by BIC, or when it still lowers BIC by
    more than ``-BIC_THRESHOLD`` with the resample's best candidate in the model: a rival
    that replaces it is an alternative explanation, one that does not is a second effect
    (both members of a pair are then named, one per step)."""
    y = design.y0
    base = stack(design, model)
    rivals = passing[passing["form"] == winner["form"]].drop_duplicates("effect")
    cols = {row["effect"]: design.column(row["effect"], row["nuisance"])
            for _, row in rivals.iterrows()}
    wins, amps = 0, []
    for _ in range(BOOT_SAMPLES):
        rows = resample(design, rng)
        score = {}
        q = projector(base[rows])
        r0 = residualise(y[rows], q)[:, 0]
        for name, col in cols.items():
            # the candidate's coefficients as ``evaluate`` found them (model projected out,
            # least norm where the design leaves a direction of them unidentified)
            fit = fit_batch(col[rows][None], q, r0)[0]
            score[name] = bic(fit.sse, len(rows), col.shape[1])
            if name == winner["effect"]:
                base_coef = lstsq_fit(base[rows], y[rows] - col[rows] @ fit.coef)[0]
                amp, _ = amplitude(design, model, base_coef, name, winner["nuisance"],
                                   fit.coef, 0.0)
                amps.append(amp)
        best = min(score, key=score.get)
        wins += best == winner["effect"] or _complements(
            base[rows], cols[best][rows], cols[winner["effect"]][rows], y[rows])
    low, high = np.percentile(amps, [2.5, 97.5])
    stable = wins / BOOT_SAMPLES >= BOOT_AGREEMENT and (low > 0 or high < 0)
    return stable, [float(low), float(high)]


def _complements(base: np.ndarray, rival: np.ndarray, own: np.ndarray, y: np.ndarray) -> bool:
    """Whether ``own`` columns lower BIC by more than ``-BIC_THRESHOLD`` when added to the
    model with the ``rival``'s columns in it: both are needed, not one or the other."""
    with_rival = np.column_stack([base, rival])
    sse_rival = float(np.sum(lstsq_fit(with_rival, y)[1] ** 2))
    q = projector(with_rival)
    fit = fit_batch(own[None], q, residualise(y, q)[:, 0])[0]
    n, k = len(y), q.shape[1]
    return fit.rank > 0 and bic(fit.sse, n, k + fit.rank) - bic(sse_rival, n, k) < BIC_THRESHOLD


def resample(design: Design, rng) -> np.ndarray:
    """Rows of one bootstrap sample: whole runs drawn with replacement when there are enough
    runs to resample, else cycles drawn with replacement within each run (keeps the design's
    levels of feed, dwell and temperature)."""
    if design.n_runs >= BOOT_MIN_RUNS:
        units = [np.flatnonzero(design.run == r) for r in range(design.n_runs)]
        return np.concatenate([units[r] for r in rng.integers(0, design.n_runs, design.n_runs)])
    rows = []
    for r in range(design.n_runs):
        in_run = design.run == r
        cycles = np.unique(design.cycle[in_run])
        for c in rng.choice(cycles, len(cycles)):
            rows.append(np.flatnonzero(in_run & (design.cycle == c)))
    return np.concatenate(rows)


def parameters(design: Design, model: dict, name: str, coef: np.ndarray, winner) -> dict:
    """The named effect's fitted parameters: its nuisance values, its amplitude, and for a
    general smooth form the control points [um] at their positions [mm]."""
    start = column_start(design, model, name)
    own = coef[start:start + design.column(name, model[name]).shape[1]]
    nuisance = dict(winner["nuisance"])
    params = {**nuisance, winner["amplitude"]: float(winner["coef"])}
    if "n_control" in nuisance:
        lo, hi = float(design.x.min()), data_value("stop", design.x)
        params["form"] = "B-spline degree 2"
        params["control_um"] = [round(float(c), 4) for c in own]
        params["control_mm"] = [round(float(p), 3) for p in
                                np.linspace(lo, hi, int(nuisance["n_control"]))]
    elif quadrature_pairs(name):
        for i, (phase, amp) in enumerate(quadrature_pairs(name)):
            sin_c, cos_c = own[2 * i], own[2 * i + 1]
            params[phase] = float(np.arctan2(cos_c, sin_c))
            params[amp] = float(np.hypot(sin_c, cos_c))
    return params
