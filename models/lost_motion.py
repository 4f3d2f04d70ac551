"""Lost motion from dual feedback: the motor travel the load does not follow at a reversal,
estimated per machine axis and day from a controller trace (docs/monitor.md).

With a motor-side position m (rotary encoder times the screw's nominal lead) and a load-side
position l (linear scale) logged together, their difference holds three things:

- the play: after a reversal the motor crosses the clearance before the load follows, so once
  the play is taken up the load trails the motor by half the lost motion L against the
  direction of the last motion d (a play, or dead-zone, operator on the motor's path; elastic
  wind-up from friction adds to it);
- the lead error e(x) of the screw, a smooth function of position, the same both ways;
- while moving, a term proportional to the velocity v: the servo lag between the two
  channels' sampling, viscous wind-up.

One least-squares fit per day separates them:

.. math:: m_i - l_i = \\frac{d_i}{2} L + c\\, v_i + \\sum_k \\beta_k N_k(x_i) + \\varepsilon_i

with N_k a B-spline basis of position ([Mechta2022], eqs. 4-5; ``features.statistics``) over
the day's travel, with as many control points as its samples carry (one per 40, at most 130)
and a small penalty on their second differences (a P-spline), so a stretch of travel without
samples follows its neighbours instead of leaving the fit undetermined. It uses only the
samples where the play is surely taken up (the commanded path has run ``take_up_mm`` since its
last reversal, so a reversal shorter than the clearance never counts) and the axis moves
steadily or rests (no acceleration within ``settle_s``). With several feeds c and L separate;
with reversals at many positions e(x) and L do.

The standard uncertainty of L is the cluster-robust (sandwich) one with each motion between
two reversals a cluster: samples of one move share their errors (the servo's, the scale's
interpolation), so the moves, not the samples, are the independent evidence.

References: [Mechta2022] (B-spline intra-axis error model); Eilers & Marx (1996), "Flexible
smoothing with B-splines and penalties", Statistical Science 11(2) (P-splines); Siemens, SINUMERIK Analyze
MyMachine /Condition (a second, load-side encoder for backlash); Liang & Zeger (1986),
"Longitudinal data analysis using generalized linear models", Biometrika 73(1) (cluster-robust
variance).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.readings.schema import deviation_scale, deviation_unit
from features.statistics import bspline_rows

# Motor travel after a reversal past which the play is taken up [mm or deg]: larger than any
# plausible lost motion (DESIGN.md: 0.5-15 um) with its wind-up.
TAKE_UP_MM = 0.05
# Time after the last acceleration before a sample counts as steady [s]: the servo settles.
SETTLE_S = 0.1
# The lead-error spline (degree 2, [Mechta2022]) has one control point per
# SAMPLES_PER_CONTROL usable samples, between MIN_CONTROL and MAX_CONTROL (on a 350 mm travel
# a control point every 2.7 mm: a screw pitch's wave of 10 mm or more is followed).
DEGREE = 2
MIN_CONTROL, MAX_CONTROL = 4, 130
SAMPLES_PER_CONTROL = 40
# Ridge on the control points' second differences, per sample: ties a control point without
# data to its neighbours (a P-spline, Eilers & Marx 1996) instead of leaving the system
# singular; far below the weight of the samples under a control point.
SMOOTHING = 1e-6
MIN_REVERSALS = 2


@dataclass
class DayFit:
    """One day's lost motion of one machine axis.

    Attributes
    ----------
    lost_motion : float
        L [mm or deg] (NaN when the day cannot show it).
    lost_motion_u : float
        Its standard uncertainty [mm or deg].
    reversals : int
        Reversals of the commanded path whose play was taken up on both sides.
    samples : int
        Samples used by the fit.
    lag_s : float
        The velocity coefficient c [s]: servo lag between the channels, viscous wind-up.
    control_points : int
        Control points of the lead-error spline the data chose.
    """

    lost_motion: float
    lost_motion_u: float
    reversals: int
    samples: int
    lag_s: float
    control_points: int


def motion_state(t_s: np.ndarray, commanded: np.ndarray, *, take_up: float = TAKE_UP_MM,
                 settle_s: float = SETTLE_S):
    """Direction of the last motion, velocity and usable samples along a commanded path.

    Parameters
    ----------
    t_s : (n,) array
        Sample times [s], not decreasing.
    commanded : (n,) array
        Set point [mm or deg].
    take_up : float
        Travel since the last reversal after which the play is taken up [mm or deg].
    settle_s : float
        Time after an acceleration (or a gap in the samples) before a sample is steady [s].

    Returns
    -------
    direction : (n,) array of {-1, 0, +1}
        Direction of the last motion (0 before the first).
    velocity : (n,) array
        Commanded velocity [mm/s or deg/s] (backward difference; 0 at rest).
    usable : (n,) bool array
        Play taken up and the axis steady or at rest.
    move : (n,) int array
        Index of the motion (between reversals) each sample belongs to.
    """
    dt = np.diff(t_s, prepend=t_s[0] - 1.0)
    step = np.diff(commanded, prepend=commanded[0])
    scale = max(float(np.max(np.abs(commanded))), 1.0)
    moving = np.abs(step) > 1e-9 * scale
    sign = np.where(moving, np.sign(step), 0.0)
    last = np.maximum.accumulate(np.where(moving, np.arange(len(sign)), -1))
    direction = np.where(last >= 0, sign[np.maximum(last, 0)], 0.0)
    reversal = np.r_[False, (direction[1:] != direction[:-1]) & (direction[:-1] != 0)]
    move = np.cumsum(reversal)
    travel = np.cumsum(np.abs(step))
    start = np.maximum.accumulate(np.where(reversal, np.arange(len(step)), 0))
    taken_up = (travel - travel[start] >= take_up) & (direction != 0)
    velocity = np.where(dt > 0, step / np.where(dt > 0, dt, 1.0), 0.0)
    accel = np.abs(np.diff(velocity, prepend=velocity[0]))
    # a gap in the log: ten sampling periods (the median of the first ones) without a sample
    gap = dt > 10 * np.median(dt[1:2001]) if len(dt) > 1 else np.zeros(len(dt), bool)
    unsteady = (accel > 1e-6 * max(float(np.max(np.abs(velocity))), 1e-12)) | gap
    unsteady[0] = True
    since = t_s - np.maximum.accumulate(np.where(unsteady, t_s, -np.inf))
    return direction, velocity, taken_up & (since >= settle_s), move


def count_reversals(direction: np.ndarray, usable: np.ndarray, move: np.ndarray) -> int:
    """Reversals with usable samples on both sides: consecutive moves that both hold some."""
    used = move[usable]  # non-decreasing: its distinct values are where it steps
    moves = used[np.r_[True, np.diff(used) != 0]] if len(used) else used
    return int(np.sum(np.diff(moves) == 1))


def fit_day(t_s, commanded, motor, load, *, take_up: float = TAKE_UP_MM,
            settle_s: float = SETTLE_S) -> DayFit:
    """Lost motion L of one axis over one day (module docstring's model).

    Parameters
    ----------
    t_s : (n,) array
        Sample times [s], not decreasing.
    commanded, motor, load : (n,) arrays
        Set point, motor-side and load-side positions [mm or deg].
    take_up, settle_s : float
        As ``motion_state``.

    Returns
    -------
    DayFit
        L [mm or deg] with its standard uncertainty; NaN when fewer than ``MIN_REVERSALS``
        reversals took up the play on both sides.
    """
    direction, velocity, usable, move = motion_state(
        np.asarray(t_s, float), np.asarray(commanded, float), take_up=take_up,
        settle_s=settle_s)
    reversals = count_reversals(direction, usable, move)
    if reversals < MIN_REVERSALS:
        return DayFit(np.nan, np.nan, reversals, int(usable.sum()), np.nan, 0)
    x = np.asarray(motor, float)[usable]
    y = (np.asarray(motor, float) - np.asarray(load, float))[usable]
    dense = np.c_[direction[usable] / 2.0, velocity[usable]]
    if np.ptp(dense[:, 1]) == 0:  # the axis only rested: nothing to learn a lag from
        dense = dense[:, :1]
    beta, u_l, n_control = _fit(x, y, dense, move[usable])
    lag = float(beta[1]) if dense.shape[1] > 1 else np.nan
    return DayFit(float(beta[0]), u_l, reversals, len(y), lag, n_control)


def _fit(x, y, dense, clusters):
    """Least squares of ``y`` on the dense columns and the P-spline of position:
    (beta, u of the first coefficient, control points).

    Row i of the spline part is ``values[i]`` in columns ``first[i] + 0..DEGREE``, so its Gram
    matrix C is banded and summed by diagonal in one pass over the samples. The normal
    equations [[A, B'], [B, C]] z = r are solved by eliminating the spline block with a banded
    Cholesky factorisation: O(k) work, and the same bits whatever threads the host's BLAS
    has (every engine must give the same numbers).
    """
    from scipy.linalg import solveh_banded

    n, q = len(y), dense.shape[1]
    k = int(np.clip(n // SAMPLES_PER_CONTROL, MIN_CONTROL, MAX_CONTROL))
    lo, hi = float(x.min()), float(x.max())
    first, values = bspline_rows((x - lo) / (hi - lo) if hi > lo else np.zeros_like(x), k,
                                 DEGREE)
    width = values.shape[1]

    def spline_t(w):  # B' w: (n,) -> (k,)
        return sum(np.bincount(first + a, weights=values[:, a] * w, minlength=k)
                   for a in range(width))

    a_dense = np.array([[np.sum(dense[:, j] * dense[:, m]) for m in range(q)]
                        for j in range(q)])
    cross = np.stack([spline_t(dense[:, j]) for j in range(q)], axis=1)  # (k, q)
    band = _penalty_band(k, width) * (SMOOTHING * n)
    for offset in range(width):  # C[j, j + offset] summed from the samples
        diag = sum(np.bincount(first + a, weights=values[:, a] * values[:, a + offset],
                               minlength=k) for a in range(width - offset))
        band[width - 1 - offset, offset:] += diag[:k - offset]
    rhs_dense = np.array([np.sum(dense[:, j] * y) for j in range(q)])
    unit = np.zeros(q)
    unit[0] = 1.0  # the first row of the inverse: L's lever on each sample
    solved = solveh_banded(band, np.c_[cross, spline_t(y), np.zeros(k)], check_finite=False)
    schur = a_dense - cross.T @ solved[:, :q]
    z_dense = np.linalg.solve(schur, np.c_[rhs_dense, unit] - cross.T @ solved[:, q:])
    z_spline = solved[:, q:] - solved[:, :q] @ z_dense
    beta, lever_row = np.r_[z_dense, z_spline].T

    def fitted(coef):  # X coef: (q + k,) -> (n,)
        out = dense[:, 0] * coef[0]
        for j in range(1, q):
            out += dense[:, j] * coef[j]
        for a in range(width):
            out += values[:, a] * coef[q:][first + a]
        return out

    resid = y - fitted(beta)
    return beta, _cluster_u(fitted(lever_row) * resid, clusters), k


@functools.lru_cache(maxsize=16)
def _penalty_band(k: int, width: int) -> np.ndarray:
    """D'D for second differences D of k control points, in the upper banded form of
    ``scipy.linalg.solveh_banded`` (row width - 1 - o holds the o-th superdiagonal); the caller
    scales it (a new array: the cached one is never changed)."""
    d2 = np.diff(np.eye(k), 2, axis=0)
    full = d2.T @ d2 if k > 2 else np.zeros((k, k))
    band = np.zeros((width, k))
    for offset in range(width):
        band[width - 1 - offset, offset:] = np.diagonal(full, offset)
    return band


def _cluster_u(scores_per_sample, clusters) -> float:
    """Cluster-robust standard uncertainty of the first coefficient,
    var = G/(G-1) sum_g (a' X_g' e_g)^2 with a the first row of (X'X)^-1; the caller passes
    the per-sample terms (a' x_i) e_i."""
    scores = np.bincount(clusters - clusters.min(), weights=scores_per_sample)
    scores = scores[np.bincount(clusters - clusters.min()) > 0]
    g = len(scores)
    return float(np.sqrt(g / max(g - 1, 1) * np.sum(scores ** 2)))


DAILY_COLUMNS = ("machine_id", "axis", "unit", "date", "lost_motion_um", "lost_motion_u_um",
                 "reversals", "samples", "lag_s", "control_points")


def daily_lost_motion(trace: pd.DataFrame, *, take_up: float = TAKE_UP_MM,
                      settle_s: float = SETTLE_S) -> pd.DataFrame:
    """Lost motion of every machine axis and UTC day of a validated trace with ``load_mm``
    (``features.traces``): a pure function of its input, so it runs per partition anywhere.

    Returns
    -------
    DataFrame
        One row per machine axis and day (``DAILY_COLUMNS``): ``lost_motion_um`` and its
        standard uncertainty ``lost_motion_u_um`` in um on a linear axis and arcsec on a
        rotary one (``unit``), ``reversals`` and ``samples`` used, ``lag_s`` and the spline's
        ``control_points``.
    """
    from features.traces.io import groups

    # One BLAS thread: the matrices are small (about 130 square), where threads only wait for
    # each other, and an engine already runs one partition per core.
    with _blas().limit(limits=1, user_api="blas"):
        rows = [_day_row(day, take_up, settle_s) for day in groups(trace, by_day=True)]
    return pd.DataFrame(rows, columns=list(DAILY_COLUMNS))


@functools.lru_cache(maxsize=1)
def _blas():
    """The process's thread pools (found once: a search of the loaded libraries is slow)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _day_row(part: pd.DataFrame, take_up: float, settle_s: float) -> tuple:
    ns = part["time"].to_numpy().view(np.int64)
    fit = fit_day((ns - ns[0]) * 1e-9, part["commanded_mm"].to_numpy(),
                  part["motor_mm"].to_numpy(), part["load_mm"].to_numpy(), take_up=take_up,
                  settle_s=settle_s)
    axis = str(part["axis"].iloc[0])
    scale = deviation_scale(axis)
    return (str(part["machine_id"].iloc[0]), axis, deviation_unit(axis),
            pd.Timestamp(ns[0], tz="UTC").date().isoformat(), fit.lost_motion * scale,
            fit.lost_motion_u * scale, fit.reversals, fit.samples, fit.lag_s,
            fit.control_points)
