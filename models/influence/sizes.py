"""Effect sizes [um] of the tested inputs with their intervals: bootstrap of the stratum's
cells within their blocks, or draws from the coefficients' t distribution."""

from __future__ import annotations

import numpy as np
import pandas as pd

from models.influence.strata import Stratum, demean, fit_stratum, legendre_basis, partial_effect

FEW_CELLS = 12               # below this many cells (beyond blocks) the interval is parametric


def _grid(x: np.ndarray) -> np.ndarray:
    u = np.unique(x)
    return u if u.size <= 200 else np.quantile(x, np.linspace(0, 1, 200))


def _shape(f: np.ndarray) -> str:
    if f.size < 2 or np.ptp(f) == 0:
        return "flat"
    i, j = int(np.argmax(f)), int(np.argmin(f))
    if 0 < i < f.size - 1 and f[i] - max(f[0], f[-1]) > 0.25 * np.ptp(f):
        return "peaks inside the range"
    if 0 < j < f.size - 1 and min(f[0], f[-1]) - f[j] > 0.25 * np.ptp(f):
        return "dips inside the range"
    return "increases" if f[-1] > f[0] else "decreases"


def effect_sizes(table, layers, ranges, X, n_boot, rng) -> pd.DataFrame:
    """Peak-to-peak effect [um] over the observed range at the stratum that tested the input,
    with a percentile interval from resampling that stratum's cells within their blocks (one
    refit per resample serves every input tested with the same model). With fewer than
    ``FEW_CELLS`` cells beyond the blocks a resample repeats the same few cells, so the
    coefficients are drawn from their multivariate t distribution instead (parametric
    bootstrap with the stratum's residual degrees of freedom)."""
    by_level = {s.level: s for s in layers}
    models = {}
    for c, row in table.iterrows():
        if isinstance(row["tested"], str):
            key = (row["tested"], tuple(sorted(row["degrees"].items())))
            models.setdefault(key, []).append(c)
    out = {c: (np.nan, np.nan, np.nan, "") for c in table.index}
    for (level, items), names in models.items():
        s, degrees = by_level[level], dict(items)
        grids = {c: _grid(X[c].to_numpy()) for c in names}

        def effects(cells=None, s=s, degrees=degrees, grids=grids, names=names):
            fit = fit_stratum(s, degrees, ranges, cells)
            return {c: partial_effect(fit.coef[c], degrees[c], grids[c], *ranges[c])
                    for c in names}

        point = effects()
        if s.n - s.n_blocks >= FEW_CELLS:
            boot = [{c: np.ptp(f) for c, f in effects(_resample_within(s.blocks, rng)).items()}
                    for _ in range(n_boot)]
        else:
            boot = [{c: np.ptp(partial_effect(coef[c], degrees[c], grids[c], *ranges[c]))
                     for c in names} for coef in _coef_draws(s, degrees, ranges, n_boot, rng)]
        for c in names:
            lo, hi = (np.percentile([b[c] for b in boot], [2.5, 97.5]) if boot
                      else (np.nan, np.nan))
            out[c] = (float(np.ptp(point[c])), float(lo), float(hi), _shape(point[c]))
    return pd.DataFrame.from_dict(out, orient="index",
                                  columns=["effect_um", "effect_low_um", "effect_high_um",
                                           "effect_shape"])


def _coef_draws(s: Stratum, degrees: dict, ranges: dict, n: int, rng) -> list[dict]:
    """``n`` coefficient sets beta + L z sqrt(df / chi2_df), L L^T = s^2 (A^T A)^-1."""
    fit = fit_stratum(s, degrees, ranges)
    names = list(degrees)
    design = np.hstack([legendre_basis(s.X[c].to_numpy(), *ranges[c], degrees[c])
                        for c in names])
    A = demean(design, s.blocks)
    if fit.df < 1 or not n:
        return []
    cov = fit.rss / fit.df * np.linalg.pinv(A.T @ A)
    beta = np.concatenate([fit.coef[c] for c in names])
    z = rng.multivariate_normal(np.zeros(beta.size), cov, size=n, method="eigh")
    draws = beta + z * np.sqrt(fit.df / rng.chisquare(fit.df, size=(n, 1)))
    edges = np.cumsum([0] + [degrees[c] for c in names])
    return [{c: d[a:b] for c, a, b in zip(names, edges[:-1], edges[1:], strict=True)}
            for d in draws]


def _resample_within(blocks: np.ndarray, rng) -> np.ndarray:
    """Cells drawn with replacement within each block (the block sizes kept)."""
    order = np.argsort(blocks, kind="stable")
    sizes = np.bincount(blocks)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    draw = (starts[blocks[order]] + np.floor(rng.random(len(blocks)) * sizes[blocks[order]])
            .astype(int))
    return order[draw]

