"""Partial pooling of linear models across the axes of a fleet (empirical Bayes).

Every machine axis a has its own coefficients beta_a of one linear model (the wear map's level
and wear-rate maps and condition terms, on a basis common to the fleet) plus coefficients
d_a of its own (per-target deviations that no common basis follows). The fleet's axes are draws
from one distribution, and the errors of one visit share a common offset:

    y_a = A_a beta_a + D_a d_a + Z_a u_a + e_a
    beta_a ~ N(mu, Sigma),  d_a ~ N(0, lambda^2 I),  u ~ N(0, tau^2) per visit,
    e ~ N(0, sigma_a^2)

mu, Sigma, lambda, tau and every sigma_a are estimated from the whole fleet by expectation
maximisation (the random-coefficient model of [Laird1982]; partial pooling as in [Gelman2013],
ch. 5 and 15); sigma_a is shrunk toward the fleet's noise, since an axis with two visits cannot
estimate it alone. With theta_a = (beta_a, d_a), prior mean m0 and covariance P0, the posterior
of each axis is

    P_a = A_a' V_a^-1 A_a + P0^-1,   C_a = P_a^-1,   m_a = C_a (A_a' V_a^-1 y_a + P0^-1 m0)

so an axis with few visits forecasts close to the fleet's typical behaviour corrected by its own
data (its own information A_a' V_a^-1 A_a is small next to P0^-1), and an axis with many
visits follows its own. V_a = sigma_a^2 I + tau^2 Z Z' is inverted per visit block in closed
form (Sherman-Morrison), so no matrix larger than the number of coefficients is ever inverted
and an axis whose own data cannot determine every coefficient needs no special case.

Why not statsmodels' ``MixedLM``: it cannot hold the nested visit offset, a noise per axis and
the deviations together, and it inverts per-group matrices that are singular for an axis with
one or two visits; the EM below does all of it in information form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Relative floor on the prior's diagonal: keeps Sigma invertible when every axis agrees on a
# coefficient (conditioning only; a millionth of the coefficient's scale).
PRIOR_FLOOR = 1e-6
# Rows' worth of weight the fleet's noise variance has in each axis's own estimate.
NOISE_PRIOR_ROWS = 10.0
MAX_ITERATIONS = 100
# EM steps of a cross-validation fold, warm-started from the fit on all the data.
FOLD_ITERATIONS = 100
TOLERANCE = 1e-3


@dataclass
class VisitBlocks:
    """Sufficient statistics of the fleet's rows, per visit of each axis (a block), laid out
    (n_axes, most visits of an axis, ...) so that every EM step is a batched matrix product:
    A_g'A_g, A_g'1, A_g'y_g, 1'y_g, y_g'y_g and the block size n_g (0 for padding and for
    blocks a cross-validation fold holds out)."""

    gram: np.ndarray      # (n_axes, V, p, p)
    ones: np.ndarray      # (n_axes, V, p)
    cross: np.ndarray     # (n_axes, V, p)
    total: np.ndarray     # (n_axes, V)
    squares: np.ndarray   # (n_axes, V)
    size: np.ndarray      # (n_axes, V)

    @classmethod
    def of(cls, A: np.ndarray, y: np.ndarray, axis: np.ndarray, visit: np.ndarray,
           n_axes: int) -> VisitBlocks:
        """Blocks of the rows of ``A``, ``y`` grouped by ``axis`` (0 .. n_axes - 1) and
        ``visit`` (any label; the blocks of an axis in the label's order)."""
        order = np.lexsort((visit, axis))
        A, y, axis, visit = A[order], y[order], axis[order], visit[order]
        starts = np.flatnonzero(np.r_[True, (axis[1:] != axis[:-1])
                                      | (visit[1:] != visit[:-1])])
        ends = np.r_[starts[1:], len(y)]
        block_axis = axis[starts]
        rank = np.arange(len(starts)) - np.searchsorted(block_axis, block_axis)
        p, width = A.shape[1], int(rank.max()) + 1
        where = (block_axis, rank)
        blocks = cls(np.zeros((n_axes, width, p, p)), np.zeros((n_axes, width, p)),
                     np.zeros((n_axes, width, p)), np.zeros((n_axes, width)),
                     np.zeros((n_axes, width)), np.zeros((n_axes, width)))
        blocks.gram[where] = np.stack([A[a:b].T @ A[a:b] for a, b in zip(starts, ends)])
        blocks.ones[where] = np.add.reduceat(A, starts, axis=0)
        blocks.cross[where] = np.add.reduceat(A * y[:, None], starts, axis=0)
        blocks.total[where] = np.add.reduceat(y, starts)
        blocks.squares[where] = np.add.reduceat(y * y, starts)
        blocks.size[where] = ends - starts
        return blocks

    @property
    def n_axes(self) -> int:
        return len(self.size)

    def subset(self, keep: np.ndarray) -> VisitBlocks:
        """The blocks where ``keep`` (n_axes, V) is true; the others empty."""
        k = keep.astype(float)
        return VisitBlocks(self.gram * k[..., None, None], self.ones * k[..., None],
                           self.cross * k[..., None], self.total * k, self.squares * k,
                           self.size * k)

    def information(self, sigma2: np.ndarray, tau2: float):
        """A_a'V_a^-1 A_a and A_a'V_a^-1 y_a per axis, V = sigma_a^2 I + tau^2 11' per block
        (``sigma2`` per axis): V_g^-1 = (I - c_g 11') / sigma^2, c_g = tau^2 /
        (sigma^2 + n_g tau^2)."""
        c = tau2 / (sigma2[:, None] + self.size * tau2)            # (n_axes, V)
        weighted = self.ones * c[..., None]
        info = self.gram.sum(axis=1) - np.swapaxes(weighted, 1, 2) @ self.ones
        score = self.cross.sum(axis=1) - np.einsum("avi,av->ai", weighted, self.total)
        return info / sigma2[:, None, None], score / sigma2[:, None]


@dataclass
class Pooled:
    """The fitted fleet: prior mean ``mu`` and covariance ``prior``, each axis's noise
    ``sigma`` (array) and the visit offset ``tau`` [um], per-axis posterior means ``means`` (n_axes, p) and covariances
    ``covariances`` (n_axes, p, p), and ``mu_covariance`` (the uncertainty of mu itself)."""

    mu: np.ndarray
    prior: np.ndarray
    sigma: np.ndarray
    tau: float
    means: np.ndarray
    covariances: np.ndarray
    mu_covariance: np.ndarray
    iterations: int
    deviation_sd: np.ndarray   # standard deviation of each group of axis-own coefficients


def pool(blocks: VisitBlocks, start: np.ndarray, scale: np.ndarray,
         local: Deviations | None = None, warm: Pooled | None = None,
         max_iterations: int = MAX_ITERATIONS) -> Pooled:
    """Fit the random-coefficient model (module docstring) by EM.

    Parameters
    ----------
    blocks : VisitBlocks
        The fleet's rows, per visit of each machine axis.
    start : array (p,)
        Starting prior mean of the shared coefficients (the fleet's complete-pooling
        least-squares fit).
    scale : array (p,)
        A typical size of each shared coefficient, for the starting prior and its floor.
    local : Deviations, optional
        Coefficients of each axis's own (the last columns of the design): zero-mean, one
        variance per group shared by the fleet, estimated with the rest.
    warm : Pooled, optional
        A fit of the same model on similar data (cross-validation folds start from the fit
        on all the data, which saves most iterations).
    max_iterations : int
        EM steps at most (EM creeps when a variance tends to zero; the means settle first).
    """
    n_axes, n_shared = blocks.n_axes, len(start)
    local = local or Deviations.none(n_axes)
    n_shared + local.size
    n_rows, n_blocks = float(blocks.size.sum()), int(np.count_nonzero(blocks.size))
    floor = PRIOR_FLOOR * np.diag(scale ** 2)
    mu = np.concatenate([start, np.zeros(local.size)])
    shared = np.diag(scale ** 2)
    spread2 = local.start.copy()
    gram, cross = blocks.gram.sum(axis=(0, 1)), blocks.cross.sum(axis=(0, 1))
    sse = blocks.squares.sum() - 2 * mu @ cross + mu @ gram @ mu
    sigma2 = np.full(n_axes, max(float(sse) / max(n_rows - n_shared, 1.0), 1e-12))
    tau2 = 0.1 * float(sigma2[0])  # EM cannot leave an offset variance of exactly zero
    if warm is not None:
        mu, shared = warm.mu.copy(), warm.prior[:n_shared, :n_shared].copy()
        spread2, sigma2 = warm.deviation_sd ** 2, warm.sigma ** 2
        tau2 = max(warm.tau ** 2, 1e-3 * float(np.mean(sigma2)))
    for iteration in range(1, max_iterations + 1):
        prior = _block_diagonal(shared, spread2[local.group])
        prior_inv = np.linalg.inv(prior)
        info, score = blocks.information(sigma2, tau2)
        covs = np.linalg.inv(info + prior_inv)
        covs = (covs + np.swapaxes(covs, 1, 2)) / 2
        means = np.einsum("aij,aj->ai", covs, score + prior_inv @ mu)
        new_mu = np.concatenate([means[:, :n_shared].mean(axis=0), np.zeros(local.size)])
        spread = means[:, :n_shared] - new_mu[:n_shared]
        new_shared = (spread.T @ spread + covs[:, :n_shared, :n_shared].sum(axis=0)) / n_axes \
            + floor
        new_spread2 = local.variances(means[:, n_shared:], covs[:, n_shared:, n_shared:])
        new_sigma2, new_tau2 = _noise(blocks, means, covs, sigma2, tau2, n_rows, n_blocks)
        change = max(np.max(np.abs(new_mu[:n_shared] - mu[:n_shared]) / scale),
                     np.max(np.abs(np.sqrt(new_sigma2) - np.sqrt(sigma2)) / np.sqrt(sigma2)),
                     abs(np.sqrt(new_tau2) - np.sqrt(tau2)) / np.sqrt(np.mean(sigma2)),
                     *(np.abs(np.sqrt(new_spread2) - np.sqrt(spread2))
                       / np.maximum(np.sqrt(local.start), 1e-12)))
        mu, shared, spread2, sigma2, tau2 = new_mu, new_shared, new_spread2, new_sigma2, new_tau2
        if change < TOLERANCE:
            break
    prior = _block_diagonal(shared, spread2[local.group])
    # mu is the mean of the axes' true coefficients: its uncertainty is Sigma / n_axes plus the
    # part of the posteriors that the data do not pin down
    mu_cov = (prior + covs.mean(axis=0)) / n_axes
    return Pooled(mu, prior, np.sqrt(sigma2), float(np.sqrt(tau2)), means, covs, mu_cov,
                  iteration, np.sqrt(spread2))


@dataclass
class Deviations:
    """Each axis's own coefficients (the last ``size`` columns of the design): ``group`` of
    every column (columns of one group share a variance), ``used`` (n_axes, size) which columns
    an axis has (an axis with fewer targets leaves the rest unused) and ``start`` the starting
    variance of every group."""

    group: np.ndarray
    used: np.ndarray
    start: np.ndarray

    @classmethod
    def none(cls, n_axes: int) -> Deviations:
        return cls(np.zeros(0, int), np.zeros((n_axes, 0), bool), np.zeros(0))

    @property
    def size(self) -> int:
        return len(self.group)

    def variances(self, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
        """EM update of every group's variance: E[d^2] over the columns the axes use."""
        if not self.size:
            return self.start
        second = (means ** 2 + np.diagonal(covs, axis1=1, axis2=2)) * self.used
        count = np.bincount(self.group, self.used.sum(axis=0), len(self.start))
        total = np.bincount(self.group, second.sum(axis=0), len(self.start))
        return np.maximum(total / np.maximum(count, 1), PRIOR_FLOOR * self.start)


def _block_diagonal(shared: np.ndarray, variances: np.ndarray) -> np.ndarray:
    n, m = len(shared), len(variances)
    out = np.zeros((n + m, n + m))
    out[:n, :n] = shared
    out[n:, n:] = np.diag(variances)
    return out


def _noise(blocks: VisitBlocks, means, covs, sigma2, tau2, n_rows, n_blocks):
    """sigma^2 and tau^2 from the expected within-visit and visit-offset sums of squares (EM
    M-step of the variance components; each visit's offset u_g has the posterior
    u_g | beta ~ N(k_g 1'(y_g - A_g beta), tau^2 sigma^2 / (sigma^2 + n_g tau^2)),
    k_g = tau^2 / (sigma^2 + n_g tau^2), and beta ~ N(m_a, C_a))."""
    n, s2 = blocks.size, sigma2[:, None]
    gram = blocks.gram.sum(axis=1)
    # E||y_a - A_a beta||^2 per axis and E(1'(y_g - A_g beta))^2 per block, over the
    # posterior of beta
    sse = (blocks.squares.sum(axis=1)
           - 2 * np.einsum("ai,ai->a", blocks.cross.sum(axis=1), means)
           + np.einsum("ai,ai->a", (gram @ means[:, :, None])[..., 0], means)
           + np.einsum("aij,aji->a", gram, covs))
    total = blocks.total - (blocks.ones @ means[:, :, None])[..., 0]
    total2 = total ** 2 + np.einsum("avi,avi->av", blocks.ones @ covs, blocks.ones)
    k = tau2 / (s2 + n * tau2)
    u2 = (k ** 2 * total2 + tau2 * s2 / (s2 + n * tau2)) * (n > 0)      # E u_g^2
    within = sse + np.sum(-2 * k * total2 + n * u2, axis=1)
    # each axis's own noise (its target definition and instrument set it), shrunk toward the
    # fleet's with the weight of NOISE_PRIOR_ROWS rows: an axis with two visits cannot
    # estimate it alone
    fleet = float(within.sum()) / n_rows
    sigma2 = (within + NOISE_PRIOR_ROWS * fleet) / (n.sum(axis=1) + NOISE_PRIOR_ROWS)
    return np.maximum(sigma2, 1e-12), float(np.sum(u2)) / n_blocks
