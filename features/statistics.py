"""Statistics shared by the feature views and the models: one definition per idea.

- ``bic``: the Bayesian information criterion of a least-squares fit;
- ``grouped_cv_sse`` / ``grouped_cv_rmse``: least squares cross-validated by leaving out one
  group (a visit, a run, a cycle) at a time;
- ``bspline_basis``: the B-spline basis on a uniform clamped knot vector ([Mechta2022], eqs. 4-5);
- ``within_share`` and ``MIN_LEVEL_SHARE``: where an input varies in a nested design, and when
  it counts as varying only between visits (or runs).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pandas as pd

# Share of an input's variance (its sum of squares about the mean) that a level of the design
# (within visits, between runs, ...) must hold for the input to count as varying there. Below
# it the input varies only at the other levels, e.g. only between visits, and its effect cannot
# be told from whatever else changed with them (wear, adjustments, the day's conditions).
# Why a tenth: the information on a slope at one level is its sum of squares there, so below
# a tenth the slope's standard error is more than sqrt(10) ~ 3 times that of a design that
# varies the input at that level; and the chance scatter of run-level values leaves a few
# percent of the variance in visit means (about 1 / runs per visit), which must not count as
# variation between visits.
MIN_LEVEL_SHARE = 0.1


def bic(sse: float, n: int, k: float) -> float:
    """Bayesian information criterion of a least-squares fit with Gaussian errors.

    Parameters
    ----------
    sse : float
        Residual sum of squares [unit^2].
    n : int
        Number of observations.
    k : float
        Number of fitted parameters (may be fractional: a search penalty).

    Returns
    -------
    float
        ``n ln(sse / n) + k ln(n)``; ``sse`` is floored at 1e-300 so an exact fit stays finite.
    """
    return n * math.log(max(sse, 1e-300) / n) + k * math.log(n)


def lstsq(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of ``y`` on the columns of ``X`` (minimum norm)."""
    return np.linalg.lstsq(X, y, rcond=None)[0]


def grouped_cv_sse(X: np.ndarray, y: np.ndarray, groups,
                   solve: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> float:
    """Held-out sum of squared errors of least squares, leaving out one group at a time.

    Parameters
    ----------
    X : (n, p) array
        Design matrix.
    y : (n,) array
        Observations [unit].
    groups : (n,) array
        Group label of each observation; groups are left out in sorted label order.
    solve : callable, optional
        ``solve(X_train, y_train) -> coef``; default plain least squares (``lstsq``).

    Returns
    -------
    float
        Sum over the groups of the squared errors of the fit on the other groups [unit^2].
    """
    solve = solve or lstsq
    groups = np.asarray(groups)
    sse = 0.0
    for label in np.unique(groups):
        out = groups == label
        coef = solve(X[~out], y[~out])
        sse += float(np.sum((y[out] - X[out] @ coef) ** 2))
    return sse


def grouped_cv_rmse(X: np.ndarray, y: np.ndarray, groups,
                    solve: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> float:
    """Held-out RMSE [unit] of ``grouped_cv_sse``: sqrt(sse / n)."""
    return math.sqrt(grouped_cv_sse(X, y, groups, solve) / len(y))


def bspline_basis(t, n_control: int, degree: int = 2, sparse: bool = False):
    """B-spline basis N_i,k(t) on a uniform clamped (non-periodic) knot vector ([Mechta2022],
    eqs. 4-5).

    Parameters
    ----------
    t : array-like
        Parametric coordinate in [0, 1] [-] (flattened).
    n_control : int
        Number of control points (columns), at least 1.
    degree : int
        Spline degree k; ``min(degree, n_control - 1)`` is used, so one control point gives
        the constant 1.

    sparse : bool
        Return the scipy sparse (CSR) matrix: each row has at most ``degree + 1`` non-zeros,
        which long series (controller traces) need.

    Returns
    -------
    (len(t), n_control) array (CSR matrix with ``sparse``)
        The basis; each row sums to 1 (partition of unity) on [0, 1].
    """
    t = np.ravel(np.asarray(t, float))
    if sparse:
        from scipy.sparse import csr_array

        first, values = bspline_rows(t, n_control, degree)
        width = values.shape[1]
        return csr_array((values.ravel(), (first[:, None] + np.arange(width)).ravel(),
                          np.arange(0, width * t.size + 1, width)), shape=(t.size, n_control))
    if n_control == 1 or t.size == 0:
        return np.ones((t.size, n_control))
    degree = min(degree, n_control - 1)
    inner = np.linspace(0.0, 1.0, n_control - degree + 1)
    knots = np.r_[[0.0] * degree, inner, [1.0] * degree]
    from scipy.interpolate import BSpline  # on first use: the twin imports this module

    return BSpline.design_matrix(t, knots, degree).toarray()


def bspline_rows(t, n_control: int, degree: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The non-zero part of ``bspline_basis``'s rows: row i is ``values[i]`` in the columns
    ``first[i] .. first[i] + degree`` (Cox-de Boor recursion on the span of each t: Piegl & Tiller, The NURBS Book,
    algorithm A2.2), so that long series (controller traces) never build the dense matrix.

    Returns
    -------
    first : (len(t),) int array
    values : (len(t), degree + 1) array
        Each row sums to 1 on [0, 1].
    """
    t = np.clip(np.ravel(np.asarray(t, float)), 0.0, 1.0)
    if n_control == 1:
        return np.zeros(t.size, int), np.ones((t.size, 1))
    p = min(degree, n_control - 1)
    spans = n_control - p
    knots = np.r_[[0.0] * p, np.linspace(0.0, 1.0, spans + 1), [1.0] * p]
    span = np.minimum((t * spans).astype(int), spans - 1)
    i = span + p  # the knot interval [knots[i], knots[i + 1]) holding t
    # one contiguous array per basis function and per knot distance (columns of 2-d arrays
    # would be strided)
    values = [np.ones(t.size)]
    left, right = [None], [None]
    for j in range(1, p + 1):
        left.append(t - knots[i + 1 - j])
        right.append(knots[i + j] - t)
        saved = np.zeros(t.size)
        for r in range(j):
            temp = values[r] / (right[r + 1] + left[j - r])
            values[r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        values.append(saved)
    values = np.stack(values, axis=1)
    return span, values


def within_share(values, groups) -> np.ndarray:
    """Share of each column's sum of squares found within groups: SS_within / SS_total.

    Parameters
    ----------
    values : (n,) or (n, p) array
    groups : (n,) array of group labels (visits, runs, ...)

    Returns
    -------
    (p,) array (a float for 1-d ``values``)
        Near 0: the column is constant within each group and differs only between them
        (``< MIN_LEVEL_SHARE``: it varies only between groups). NaN when the column does not
        vary or there is a single group.
    """
    values = np.asarray(values, float)
    flat = values.ndim == 1
    values = values.reshape(len(values), -1)
    # labels of any type (a missing label is a group of its own)
    codes = pd.factorize(np.asarray(groups), use_na_sentinel=False)[0]
    counts = np.bincount(codes)
    means = np.column_stack([np.bincount(codes, values[:, j]) for j in
                             range(values.shape[1])]) / counts[:, None] if values.size else \
        np.zeros((len(counts), values.shape[1]))
    within = ((values - means[codes]) ** 2).sum(axis=0)
    total = ((values - values.mean(axis=0)) ** 2).sum(axis=0)
    share = np.full(values.shape[1], np.nan)
    if len(counts) >= 2:
        share = np.divide(within, total, out=share, where=total > 0)
    return float(share[0]) if flat else share


def varies_only_between(values, groups) -> bool:
    """Whether ``values`` vary (almost) only between the groups: ``within_share`` below
    ``MIN_LEVEL_SHARE`` (False when they do not vary or there is one group)."""
    share = within_share(values, groups)
    return bool(np.isfinite(share) and share < MIN_LEVEL_SHARE)
