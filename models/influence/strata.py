"""The effect model in split-plot strata: Legendre bases per input, block fixed effects,
degrees by BIC and the partial F-test of each input given the others."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.statistics import MIN_LEVEL_SHARE, bic
from models.influence.design import group_mean

# share of an input's variance a stratum needs to test it there (the one threshold of
# ``features.statistics``; its reason is given there)
MIN_SHARE = MIN_LEVEL_SHARE
MAX_DEGREE = 4               # largest polynomial degree of one input's partial effect
MIN_RESIDUAL_DF = 3          # a higher degree needs this many and twice its parameters left


def legendre_basis(x: np.ndarray, lo: float, hi: float, degree: int) -> np.ndarray:
    """Legendre polynomials P_1..P_degree of x mapped from [lo, hi] to [-1, 1]."""
    t = 2.0 * (np.asarray(x, float) - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros(len(x))
    return np.polynomial.legendre.legvander(t, degree)[:, 1:]


@dataclass
class Stratum:
    """Cell means of one level with their blocks (the next level up, as fixed effects)."""

    level: str
    y: np.ndarray                # cell means of backlash [um]
    X: pd.DataFrame              # cell means of the inputs
    blocks: np.ndarray           # block label of each cell
    inputs: tuple[str, ...]      # inputs holding >= MIN_SHARE of their variance here

    @property
    def n(self) -> int:
        return len(self.y)

    @property
    def n_blocks(self) -> int:
        return int(np.unique(self.blocks).size)


def strata(X: pd.DataFrame, y: np.ndarray, labels: dict, shares: pd.DataFrame) -> list[Stratum]:
    """One ``Stratum`` per level with more cells than blocks."""
    chain = ("point", "run", "visit", "unit", "all")
    out = []
    for level, up in itertools.pairwise(chain):
        cells = labels[level]
        n_cells = int(cells.max() + 1)
        first = np.unique(cells, return_index=True)[1]
        blocks = pd.factorize(labels[up][first])[0]
        if n_cells - np.unique(blocks).size < 1:
            continue
        frame = pd.DataFrame(X.to_numpy(float), columns=X.columns).groupby(cells).mean()
        ymean = pd.Series(y).groupby(cells).mean().to_numpy()
        name = "point" if n_cells == len(X) else level
        inputs = tuple(c for c in X.columns if shares.loc[c, name] >= MIN_SHARE)
        out.append(Stratum(name, ymean, frame.reset_index(drop=True), blocks, inputs))
    return out


def demean(A: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    return A - group_mean(A, blocks) if A.size else A


@dataclass
class StratumFit:
    rss: float
    df: int
    coef: dict                   # input -> coefficients of its basis
    degree: dict                 # input -> degree


def fit_stratum(s: Stratum, degrees: dict, ranges: dict, rows=None) -> StratumFit:
    """Least squares of the cell means on the inputs' bases with block fixed effects."""
    rows = np.arange(s.n) if rows is None else rows
    names = list(degrees)
    parts = [legendre_basis(s.X[c].to_numpy()[rows], *ranges[c], degrees[c]) for c in names]
    design = np.hstack(parts) if parts else np.empty((len(rows), 0))
    blocks = s.blocks[rows]
    yd = demean(s.y[rows, None], blocks)[:, 0]
    Ad = demean(design, blocks)
    n_blocks = int(np.unique(blocks).size)
    if Ad.shape[1]:
        # normal equations: the design is tall and narrow, its columns bounded on [-1, 1]
        beta, _, rank, _ = np.linalg.lstsq(Ad.T @ Ad, Ad.T @ yd, rcond=1e-10)
        resid = yd - Ad @ beta
    else:
        beta, rank, resid = np.empty(0), 0, yd
    coef, start = {}, 0
    for c in names:
        coef[c] = beta[start:start + degrees[c]]
        start += degrees[c]
    return StratumFit(float(resid @ resid), len(rows) - n_blocks - rank, coef, dict(degrees))


def max_degree(s: Stratum, name: str) -> int:
    return int(max(1, min(MAX_DEGREE, s.X[name].round(9).nunique() - 1)))


def choose_degrees(s: Stratum, names, ranges, fixed: dict | None = None) -> dict:
    """Degree per input by BIC, coordinate-wise (two passes), starting from straight lines."""
    degrees = {**(fixed or {}), **{c: 1 for c in names}}
    for _ in range(2):
        for c in names:
            best = None
            for d in range(1, max_degree(s, c) + 1):
                trial = {**degrees, c: d}
                fit = fit_stratum(s, trial, ranges)
                if fit.df < max(MIN_RESIDUAL_DF, 2 * (s.n - s.n_blocks - fit.df)):
                    break  # too few cells for this many parameters: BIC would overfit
                score = bic(fit.rss, s.n, s.n - fit.df)  # parameters: blocks and columns
                if best is None or score < best[0] - 1e-9:
                    best = (score, d)
            if best is not None:
                degrees[c] = best[1]
    return degrees


def partial_f(s: Stratum, degrees: dict, name: str, ranges: dict) -> tuple[float, float, int]:
    """Partial F-test of ``name`` in the stratum model: (F, p, residual df). p is NaN when the
    design leaves no residual degree of freedom or the input adds no column of its own."""
    from scipy import stats

    full = fit_stratum(s, degrees, ranges)
    reduced = fit_stratum(s, {k: v for k, v in degrees.items() if k != name}, ranges)
    d = reduced.df - full.df
    if full.df < 1 or d < 1:
        return np.nan, np.nan, full.df
    if full.rss <= 1e-24:
        return np.inf, 0.0, full.df
    F = ((reduced.rss - full.rss) / d) / (full.rss / full.df)
    return float(F), float(stats.f.sf(F, d, full.df)), full.df


def partial_effect(coef: np.ndarray, degree: int, values: np.ndarray, lo: float,
                   hi: float) -> np.ndarray:
    """f_j at ``values`` [um] (zero mean is not imposed: only differences matter)."""
    return legendre_basis(values, lo, hi, degree) @ coef


def stratum_tests(layers, inputs, physics, ranges) -> tuple[dict, dict]:
    """Per input and stratum: (p given the others, level, residual df, degrees) and the
    marginal p (block fixed effects only). Inputs with a path are tested in the physics model,
    the others by adding them to it. Also returns the physics degrees per level."""
    rows = {c: {"p": [], "p_marg": []} for c in inputs}
    fits = {}
    for s in layers:
        phys = [c for c in physics if c in s.inputs]
        degrees = choose_degrees(s, phys, ranges)
        fits[s.level] = degrees
        for c in s.inputs:
            model = degrees if c in phys else choose_degrees(s, [c], ranges, fixed=degrees)
            _, p, df = partial_f(s, model, c, ranges)
            rows[c]["p"].append((p, s.level, df, model))
            alone = choose_degrees(s, [c], ranges)
            rows[c]["p_marg"].append(partial_f(s, alone, c, ranges)[1])
    return rows, fits


def combine_strata(row: dict) -> dict:
    """Smallest p over the strata that could test the input, times their number
    (Bonferroni), and the stratum that gave it."""
    tested = [t for t in row["p"] if np.isfinite(t[0])]
    best = min(tested, key=lambda t: t[0]) if tested else None
    marg = [p for p in row["p_marg"] if np.isfinite(p)]
    return {"p_value": min(1.0, best[0] * len(tested)) if best else np.nan,
            "p_marginal": min(1.0, min(marg) * len(marg)) if marg else np.nan,
            "tested": best[1] if best else None, "df": best[2] if best else 0,
            "degrees": best[3] if best else None}

