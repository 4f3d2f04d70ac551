"""The readings as a least-squares design: effect columns with the runs' offsets projected
out, and the linear algebra every stage of the search shares."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from features.statistics import bic, grouped_cv_rmse
from models.discovery.terms import conditions_of, effect_column, reversal_flags

__all__ = ["Design", "bic", "cv_rmse", "lstsq_fit", "max_corr", "projector", "rank",
           "residualise", "rmse", "stack"]


class Design:
    """Design columns with per-run offsets projected out (within-run demeaning)."""

    def __init__(self, readings: pd.DataFrame):
        self.y = readings["deviation_um"].to_numpy(float)
        self.x = readings["target"].to_numpy(float)
        self.d = np.where(readings["direction"].to_numpy() == "+", 1.0, -1.0)
        self.cond = conditions_of(readings)
        self.run = pd.factorize(readings["test_id"])[0]
        self.n_runs = self.run.max() + 1
        self.counts = np.bincount(self.run)
        self._onehot = np.eye(self.n_runs)[self.run]
        self._means = self._onehot / self.counts
        self.cycle = readings["cycle"].to_numpy(int)
        self.reversal_flags = reversal_flags(readings)
        self.system = "indirect"
        # cross-validation and bootstrap units: runs, or cycles of a single run
        self.fold = self.run if self.n_runs >= 2 else pd.factorize(self.cycle)[0]
        self.n_folds = self.fold.max() + 1
        self.y0 = self.demean(self.y)[:, 0]
        self._cache = {}

    @property
    def reversal(self):
        return self.reversal_flags if self.system == "direct" else None

    def demean(self, a: np.ndarray) -> np.ndarray:
        a = a.reshape(len(self.y), -1)
        return a - self._means @ (self._onehot.T @ a)

    def column(self, name: str, nuisance: dict | None = None) -> np.ndarray:
        key = (name, self.system, tuple(sorted((nuisance or {}).items())))
        if key not in self._cache:
            self._cache[key] = self.demean(effect_column(name, self.x, self.d, self.cond,
                                                         nuisance, self.reversal))
        return self._cache[key]


def lstsq_fit(X: np.ndarray, y: np.ndarray):
    """Least-squares coefficients and residual."""
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    return coef, resid


def rank(X: np.ndarray) -> int:
    return int(np.linalg.matrix_rank(X)) if X.size else 0


def cv_rmse(X: np.ndarray, y: np.ndarray, fold: np.ndarray, n_folds: int | None = None) -> float:
    """Held-out RMSE: fit on the other runs (cycles), predict the left-out one (its offset is
    already removed by the demeaning). ``n_folds`` is implied by ``fold``; kept for callers."""
    return grouped_cv_rmse(X, y, fold)


def rmse(resid: np.ndarray, design: Design, X: np.ndarray) -> float:
    """Residual RMSE [um] with the model's columns and the runs' offsets as parameters."""
    dof = len(resid) - X.shape[1] - design.n_runs
    return math.sqrt(float(np.sum(resid ** 2)) / max(dof, 1))


def stack(design: Design, model: dict) -> np.ndarray:
    """The model's design matrix: each effect's columns at its nuisance values."""
    return np.column_stack([design.column(name, nuisance) for name, nuisance in model.items()])


def projector(base: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the model's column space."""
    u, sv, _ = np.linalg.svd(base, full_matrices=False)
    return u[:, sv > 1e-10 * max(float(sv.max(initial=0.0)), 1e-300)]


def residualise(col: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``col`` with the column space of ``q`` projected out."""
    col = col.reshape(len(q), -1)
    return col - q @ (q.T @ col)


def max_corr(a: np.ndarray, b: np.ndarray) -> float:
    """Largest absolute correlation (cosine) between a column of ``a`` and one of ``b``."""
    na, nb = np.linalg.norm(a, axis=0), np.linalg.norm(b, axis=0)
    keep_a, keep_b = na > 1e-12, nb > 1e-12
    if not keep_a.any() or not keep_b.any():
        return 0.0
    corr = (a[:, keep_a] / na[keep_a]).T @ (b[:, keep_b] / nb[keep_b])
    return float(np.abs(corr).max())
