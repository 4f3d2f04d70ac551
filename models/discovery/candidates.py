"""Candidate effects: each one fitted with the model over its nuisance family (profile
likelihood), judged by BIC, cross-validation and physical plausibility."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pandas as pd

from models.discovery.design import (
    Design,
    bic,
    cv_rmse,
    lstsq_fit,
    projector,
    rank,
    residualise,
    stack,
)
from models.discovery.system import SYSTEM_P
from models.discovery.terms import (
    EFFECTS,
    PROFILES,
    control_counts,
    nuisance_grid,
    profile_basis,
    quadrature_pairs,
    searched_nuisance,
    signed_by_approach,
)
from models.physics import effects

BIC_THRESHOLD = -10.0
CV_GAIN = 0.02
CHI2_1_95 = 3.84    # profile likelihood: nuisance values within chi2(1, 95 %) of the best
# Lost motion along the axis: its record is a wear bump; the general smooth form is tried too.
LOST_MOTION_PROFILE = "backlash_position"


class Form(NamedTuple):
    """A form a candidate is tried in: ``kind`` 'specific' (the record's shape over its
    nuisance grid) or 'general' (a smooth profile over its complexities), and the nuisance
    values (``family``) tried."""

    kind: str
    family: list[dict]


class BatchFit(NamedTuple):
    """Least squares of one candidate's columns on the model's residual."""

    sse: float            # residual sum of squares [um^2]
    coef: np.ndarray      # the candidate's coefficients
    rank: int             # columns it adds beyond the model


class CandidateFit(NamedTuple):
    """The model plus a candidate at one nuisance value."""

    bic: float
    sse: float            # residual sum of squares [um^2]
    nuisance: dict        # the candidate's nuisance values
    coef: np.ndarray      # the candidate's coefficients
    column: np.ndarray    # its design column(s), runs' offsets projected out
    k: float              # parameters charged (model, candidate and search)


def forms(design: Design, name: str) -> list[Form]:
    """The forms a candidate is tried in, each with its nuisance family."""
    found = []
    if name not in PROFILES:
        key, grid = nuisance_grid(name, design.x)
        found.append(Form("specific", [{}] if key is None else [{key: float(v)} for v in grid]))
    if name in PROFILES or name == LOST_MOTION_PROFILE:
        found.append(Form("general", [{"n_control": k} for k in control_counts(design.x)]))
    return found


def candidates(design: Design, model: dict, skipped: dict, noise: float,
               barred: set = frozenset()) -> pd.DataFrame:
    """Every effect not in the model (nor skipped) in each of its forms: one row with its best
    fit, delta BIC, CV gain, plausibility and whether it passes; sorted by delta BIC."""
    y = design.y0
    base = stack(design, model)
    _, resid0 = lstsq_fit(base, y)
    sse0 = float(np.sum(resid0 ** 2))
    n, k0 = len(y), rank(base)
    cv0 = cv_rmse(base, y, design.fold)
    rows = []
    for name in EFFECTS:
        if name in model or name in skipped:
            continue
        for form in forms(design, name):
            if form.kind == "general" and name in barred:
                continue
            row = evaluate(design, model, base, name, form, sse0, n, k0, noise)
            if row is None:
                continue
            X = np.column_stack([base, design.column(name, row["nuisance"])])
            row["cv_gain"] = 1 - cv_rmse(X, y, design.fold) / cv0
            row["passes"] = bool(row["delta_bic"] < BIC_THRESHOLD and row["cv_gain"] > CV_GAIN
                                 and row["plausible"])
            rows.append(row)
    table = pd.DataFrame(rows)
    return table.sort_values("delta_bic").reset_index(drop=True) if len(table) else \
        pd.DataFrame(columns=["effect", "form", "passes"])


def evaluate(design, model, base, name, form: Form, sse0, n, k0, noise) -> dict | None:
    """Fit the candidate over its nuisance family; keep the best by BIC, and the family of
    values the data cannot tell from it (profile likelihood within chi2(1, 95 %))."""
    family = form.family
    proj = projector(base)
    r0 = residualise(design.y0, proj)[:, 0]
    search = search_penalty(family, n) if form.kind == "specific" else 0.0
    fits = []
    for members in batches(design, name, family):
        cols = np.stack([design.column(name, nz) for nz in members])
        for nuisance, col, fit in zip(members, cols, fit_batch(cols, proj, r0)):
            if fit.rank:
                k = k0 + fit.rank + search
                fits.append(CandidateFit(bic(fit.sse, n, k), fit.sse, nuisance, fit.coef, col,
                                         k))
    if not fits:
        return None
    best = min(fits, key=lambda f: f.bic)
    searched = searched_nuisance(name)
    if (form.kind == "specific" and best.nuisance and searched is not None
            and searched.continuous and family[0] != best.nuisance
            and family[-1] != best.nuisance):
        fits.append(refine(design, name, family, best, k0 + search, proj, r0, n))
        best = min(fits, key=lambda f: f.bic)
    sigma2 = best.sse / max(n - best.k - design.n_runs, 1)
    family_fits = ([f for f in fits if f.sse - best.sse <= CHI2_1_95 * sigma2]
                   if form.kind == "specific" else [best])
    not_identified = _not_identified(name, family, [f.nuisance for f in family_fits])
    not_identified.update(_undersampled(design, name, best.nuisance, family_fits))
    # plausibility over the whole family only when the design cannot fix the nuisance
    judged = [(f, amplitude(design, model, _base_coef(base, design.y0, f), name, f.nuisance,
                            f.coef, noise))
              for f in (family_fits if not_identified else [best])]
    plausible = [(f, a) for f, a in judged if a[1]]
    chosen, (amp, ok) = min(plausible, key=lambda p: p[0].sse) if plausible else judged[0]
    return {"effect": name, "form": form.kind, "nuisance": chosen.nuisance, "coef": amp,
            "amplitude": ("peak_um" if "n_control" in chosen.nuisance
                          else EFFECTS[name].amplitude),
            "delta_bic": chosen.bic - bic(sse0, n, k0), "plausible": ok, "sse": chosen.sse,
            "not_identified": not_identified, "family": len(family_fits)}


def batches(design, name, family) -> list[list[dict]]:
    """Members of a family grouped by their number of columns (stacked and fitted at once)."""
    groups = {}
    for nuisance in family:
        groups.setdefault(design.column(name, nuisance).shape[1], []).append(nuisance)
    return list(groups.values())


def fit_batch(cols: np.ndarray, q: np.ndarray, r0: np.ndarray) -> list[BatchFit]:
    """Least squares of the baseline's residual on each candidate's columns with the model
    projected out (Frisch-Waugh-Lovell), for a stack of candidates (M, n, m) at once."""
    cr = cols - np.einsum("nk,Mkm->Mnm", q, np.einsum("nk,Mnm->Mkm", q, cols))
    scale = np.linalg.norm(cols, axis=1)                       # (M, m)
    scale = np.where(scale > 1e-12, scale, 1.0)
    crs = cr / scale[:, None, :]
    gram = np.einsum("Mnm,Mnp->Mmp", crs, crs)
    rhs = np.einsum("Mnm,n->Mm", crs, r0)
    ranks = np.sum(np.linalg.svd(gram, compute_uv=False) > 1e-10, axis=1)
    coef_s = np.einsum("Mmp,Mp->Mm", np.linalg.pinv(gram, rcond=1e-10, hermitian=True), rhs)
    sse = float(r0 @ r0) - np.einsum("Mm,Mm->M", coef_s, rhs)
    return [BatchFit(max(float(e), 0.0), c / sc, int(k)) for e, c, sc, k in
            zip(sse, coef_s, scale, ranks)]


def _base_coef(base: np.ndarray, y: np.ndarray, fit: CandidateFit) -> np.ndarray:
    """The model's own coefficients with the candidate ``fit`` in it."""
    return lstsq_fit(base, y - fit.column @ fit.coef)[0]


def _undersampled(design: Design, name: str, nuisance: dict,
                  family_fits: list[CandidateFit]) -> dict:
    """A period shorter than twice the closest target spacing: the targets cannot resolve it
    (its aliases fit as well wherever the spacing is regular)."""
    searched = searched_nuisance(name)
    key = next(iter(nuisance), None)
    if searched is None or searched.kind != "period" or key != searched.key:
        return {}
    spacing = float(np.min(np.diff(np.unique(design.x)))) if len(np.unique(design.x)) > 1 else 0
    if spacing <= nuisance[key] / 2:
        return {}
    values = sorted({round(f.nuisance[key], 3) for f in family_fits})
    return {key: {"range": [values[0], values[-1]], "values": values[:12],
                  "test": EFFECTS[name].separating_test}}


def search_penalty(family: list, n: int) -> float:
    """Parameters charged for a nuisance searched over a grid: one for the value, plus the
    look-elsewhere cost of picking the best of M values (2 ln M, as a Bonferroni bound), in
    units of BIC's ln(n) per parameter."""
    if len(family) < 2:
        return 0.0
    return 1.0 + 2.0 * math.log(len(family)) / math.log(n)


def refine(design, name, family, best: CandidateFit, k_base, proj, r0, n) -> CandidateFit:
    """Refine a continuous nuisance between the best grid value's neighbours (a pitch or time
    constant off the grid), by bounded scalar minimisation of the residual sum of squares."""
    from scipy.optimize import minimize_scalar

    key = next(iter(best.nuisance))
    grid = [f[key] for f in family]
    i = grid.index(best.nuisance[key])
    lo, hi = sorted((grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]))

    def fit(value):
        col = design.column(name, {key: float(value)})
        return col, fit_batch(col[None], proj, r0)[0]

    found = minimize_scalar(lambda v: fit(v)[1].sse, bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-3 * (hi - lo)})
    col, batch = fit(found.x)
    k = k_base + batch.rank
    return CandidateFit(bic(batch.sse, n, k), batch.sse, {key: float(found.x)}, batch.coef, col,
                        k)


def amplitude(design, model, base_coef, name, nuisance, coef, noise) -> tuple[float, bool]:
    """The fitted amplitude and whether it is physically plausible. Profiles report their
    largest departure from a straight line over the targets (a straight line is the lead error
    and the offsets); lost motion must stay >= 0 along the axis."""
    record = EFFECTS[name]
    if "n_control" in nuisance:
        targets = np.unique(design.x)
        profile = profile_basis(targets, nuisance["n_control"]) @ coef
        # a constant reversal value is the backlash, a straight line the lead error
        trend = (np.full_like(profile, profile.mean()) if signed_by_approach(name)
                 else np.polyval(np.polyfit(targets, profile, 1), targets))
        amp = float(np.max(np.abs(profile - trend)))
        ok = amp <= record.plausible[1] if record.kind == "position" else amp <= 50.0
    elif quadrature_pairs(name):
        amp = float(np.hypot(*coef[:2]))
        ok = record.plausible[0] <= amp <= record.plausible[1]
    else:
        amp = float(coef[0])
        ok = record.plausible[0] <= amp <= record.plausible[1]
    if ok and signed_by_approach(name) and design.reversal is None:
        ok = reversal_changes_sign(design, noise)
    if ok and record.kind == "lost_motion" and "backlash" in model:
        b0 = float(base_coef[column_start(design, model, "backlash")])
        shape = _lost_motion_shape(design, name, nuisance, coef)
        ok = b0 + float(np.percentile(shape, 5)) >= -noise
    return amp, ok


def reversal_changes_sign(design: Design, noise: float) -> bool:
    """Whether the measured reversal value B(x) = mean(+) - mean(-) [um] changes sign along
    the axis: some target significantly above zero and some below (z-test with the reading
    repeatability ``noise`` [um], Bonferroni over the targets at ``SYSTEM_P``). With an
    indirect measuring system a clearance b(x) >= 0 gives B(x) = -b(x), one sign at every
    target; only a reversal value that changes sign is not a clearance."""
    from scipy.stats import norm

    if not np.isfinite(noise) or noise <= 0:
        return False
    frame = pd.DataFrame({"x": design.x, "up": design.d > 0, "y": design.y0})
    stats = frame.groupby(["x", "up"])["y"].agg(["mean", "count"]).unstack("up").dropna()
    if stats.empty:
        return False
    b = stats[("mean", True)] - stats[("mean", False)]
    se = noise * np.sqrt(1 / stats[("count", True)] + 1 / stats[("count", False)])
    z = b / se
    level = norm.isf(SYSTEM_P / len(z))
    return bool(z.max() > level and z.min() < -level)


def column_start(design: Design, model: dict, name: str) -> int:
    """Index of the effect's first column in the model's design matrix."""
    before = list(model)[:list(model).index(name)]
    return int(sum(design.column(m, model[m]).shape[1] for m in before))


def _lost_motion_shape(design, name, nuisance, coef) -> np.ndarray:
    """The candidate's lost motion at the measured targets and conditions [um]."""
    if "n_control" in nuisance:
        return profile_basis(np.unique(design.x), nuisance["n_control"]) @ coef
    record = EFFECTS[name]
    params = {**nuisance, record.amplitude: float(coef[0])}
    return effects.contribution(name, design.x, 0, design.cond, **params)


def _not_identified(name: str, family: list[dict], equivalent: list[dict]) -> dict:
    """A nuisance parameter the design cannot fix: its equally good values span the whole grid
    or fall apart into separate groups (aliases)."""
    if len(equivalent) < 2 or len(family) < 3:
        return {}
    key = next(iter(family[0]))
    grid = [f[key] for f in family]
    idx = sorted({int(np.argmin(np.abs(np.asarray(grid) - e[key]))) for e in equivalent})
    spans = idx[0] == 0 and idx[-1] == len(grid) - 1
    split = bool(np.any(np.diff(idx) > 1))
    if not (spans or split):
        return {}
    values = [grid[i] for i in idx]
    return {key: {"range": [float(min(values)), float(max(values))],
                  "values": [float(v) for v in values][:12],
                  "test": EFFECTS[name].separating_test}}
