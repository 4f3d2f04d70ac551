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

One least-squares fit per day separates them (on the samples averaged over bins of
``BIN_S``, weighted by their counts):

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
smoothing with B-splines and penalties", Statistical Science 11(2) (P-splines); Siemens,
SINUMERIK Analyze MyMachine /Condition (a second, load-side encoder for backlash); Liang & Zeger (1986),
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
# Relative change of the commanded velocity from one sample to the next still called steady.
STEADY = 1e-3
# The samples are averaged over bins of this length [s] first (weighted by their counts):
# where the fit looks (steady motion, rests) the servo and the scale do not change within one,
# so it loses nothing, and past the first pass its cost does not grow with the sampling rate.
# (On the done-when traces, 20 ms and 40 ms bins give RMS errors within 0.001 um of each other.)
BIN_S = 0.04
# 1 - r² of direction and velocity below which lost motion and servo lag are confounded (every
# move at one feed, no rests): the day shows no lost motion.
SEPARABLE = 1e-3
BIN_NS = 40_000_000  # BIN_S [ns]; a whole number of bins makes a day
# Days are fitted together in runs of about this many bins (``daily_lost_motion``).
CHUNK_SAMPLES = 50_000


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
        Index of the motion each sample belongs to: a new one starts at every reversal and
        after every gap in the log (ten sampling periods without a sample: what the axis did
        meanwhile is unknown, so its play must be taken up again).
    reversal : (n,) bool array
        The samples where the direction reversed.
    """
    dt, step = _backward(t_s, 1.0), _backward(commanded, 0.0)
    moving = np.abs(step) > 1e-9 * np.maximum(np.abs(commanded), 1.0)  # not float rounding
    sign = np.where(moving, np.sign(step), 0.0)
    last = np.maximum.accumulate(np.where(moving, np.arange(len(sign)), -1))
    direction = np.where(last >= 0, sign[np.maximum(last, 0)], 0.0)
    reversal = np.r_[False, (direction[1:] != direction[:-1]) & (direction[:-1] != 0)]
    # a gap: ten sampling periods (the median of the first ones) without a sample
    gap = dt > 10 * np.median(dt[1:2001]) if len(dt) > 1 else np.zeros(len(dt), bool)
    new_move = reversal | gap
    move = np.cumsum(new_move)
    travel = np.cumsum(np.abs(step))
    start = np.maximum.accumulate(np.where(new_move, np.arange(len(step)), 0))
    taken_up = (travel - travel[start] >= take_up) & (direction != 0)
    velocity = np.divide(step, dt, out=np.zeros(len(dt)), where=dt > 0)
    # steady: the velocity within STEADY of the sample before (a controller's set points are
    # rounded, so exact equality would find no steady motion)
    before = np.r_[velocity[0], velocity[:-1]]
    unsteady = (np.abs(velocity - before) > STEADY * np.maximum(np.abs(velocity),
                                                                 np.abs(before))) | gap
    unsteady[0] = True
    since = t_s - np.maximum.accumulate(np.where(unsteady, t_s, -np.inf))
    return direction, velocity, taken_up & (since >= settle_s), move, reversal


def _backward(values: np.ndarray, first: float) -> np.ndarray:
    """values[i] - values[i - 1], and ``first`` at 0."""
    out = np.empty(len(values))
    out[:1] = first
    np.subtract(values[1:], values[:-1], out=out[1:])
    return out


def count_reversals(usable: np.ndarray, move: np.ndarray, reversal: np.ndarray,
                    day: np.ndarray, days: int) -> np.ndarray:
    """Per day, the reversals with usable samples on both sides: the moves before and after
    each reversal both hold some."""
    has = np.bincount(move, weights=usable, minlength=move[-1] + 1) > 0
    at = np.flatnonzero(reversal)
    both = has[move[at] - 1] & has[move[at]]
    return np.bincount(day[at[both]], minlength=days)


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
    return fit_days(t_s, np.zeros(len(t_s), int), commanded, motor, load, take_up=take_up,
                    settle_s=settle_s)[0]


def fit_days(t_s, day, commanded, motor, load, weight=None, *, take_up: float = TAKE_UP_MM,
             settle_s: float = SETTLE_S) -> list[DayFit]:
    """``fit_day`` of every day of one machine axis, all days in one pass.

    Each day has its own spline and coefficients; the days' normal equations form one block
    diagonal, banded system, so the work is one pass over the samples plus a handful of
    array operations per day, however many days there are.

    Parameters
    ----------
    t_s : (n,) array
        Sample times [s], not decreasing.
    day : (n,) int array
        Day index 0..days-1 of each sample, not decreasing.
    commanded, motor, load : (n,) arrays
        As ``fit_day``.
    weight : (n,) array, optional
        Samples behind each row when the rows are already bin means (``daily_lost_motion``
        bins whole traces at once); by default the rows are samples, binned here.

    Returns
    -------
    list of DayFit
        One per day index.
    """
    day = np.asarray(day)
    days = int(day[-1]) + 1 if len(day) else 0
    if weight is None:
        t_s = np.asarray(t_s, float)
        span = (t_s[-1] - t_s[0]) / BIN_S + 2.0  # more bins than one day holds: a new day,
        key = np.floor(t_s * (1.0 / BIN_S)) + day * span  # a new bin
        t_s, day, commanded, motor, load, weight = _binned(
            key, *(np.asarray(v, float) for v in (t_s, day, commanded, motor, load)))
        day = day.astype(int)  # a bin lies within one day
    direction, velocity, usable, move, reversal = motion_state(
        t_s, commanded, take_up=take_up, settle_s=settle_s)
    reversals = count_reversals(usable, move, reversal, day, days)
    keep = usable & (reversals >= MIN_REVERSALS)[day]
    out = [DayFit(np.nan, np.nan, int(r), int(s), np.nan, 0) for r, s in
           zip(reversals, np.bincount(day[usable], weights=weight[usable], minlength=days))]
    if not keep.any():
        return out
    dense = np.c_[direction[keep] / 2.0, velocity[keep]]
    fits = _fit(motor[keep], (motor - load)[keep], dense, move[keep], day[keep], weight[keep])
    for d, (beta, u_l, k) in fits.items():
        out[d] = DayFit(float(beta[0]), u_l, int(reversals[d]), out[d].samples,
                        float(beta[1]), k)
    return out


def _binned(key, *channels):
    """Means of each channel over the runs of equal ``key`` (the bins of ``BIN_S``), and the
    samples per bin. The means are linear, so the play, the lead error (smooth over a bin's
    travel) and the lag keep their form, and steady motion stays steady."""
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[starts, len(key)]).astype(float)
    return (*(np.add.reduceat(v, starts) / count for v in channels), count)


def _fit(x, y, dense, clusters, day, weight) -> dict:
    """Weighted least squares of ``y`` on the dense columns and a P-spline of position, one
    set of coefficients per day: {day: (beta, u of the first coefficient, control points)}.
    Rows are bins of samples (their means, weighted by their counts).

    Row i of a day's spline part is ``values[i]`` in its columns ``first[i] + 0..DEGREE``, so
    the Gram matrix C of all days' splines is block diagonal and banded, summed by diagonal
    in one pass. The normal equations [[A_d, B_d'], [B_d, C_d]] z_d = r_d are solved by
    eliminating the spline blocks with one banded Cholesky factorisation: O(samples) work,
    and the same bits whatever threads the host's BLAS has (every engine must give the same
    numbers).
    """
    from scipy.linalg import solveh_banded

    q = dense.shape[1]
    dense = [np.ascontiguousarray(dense[:, j]) for j in range(q)]  # columns, contiguous
    starts = np.flatnonzero(np.r_[True, np.diff(day) != 0])  # day is sorted
    present = day[starts]
    n_day = np.add.reduceat(weight, starts).astype(int)  # samples per day
    slot = np.searchsorted(present, day)  # 0..D-1 per sample
    k_day = np.clip(n_day // SAMPLES_PER_CONTROL, MIN_CONTROL, MAX_CONTROL)
    offset = np.r_[0, np.cumsum(k_day)[:-1]]
    lo, hi = np.minimum.reduceat(x, starts), np.maximum.reduceat(x, starts)
    span = np.where(hi > lo, hi - lo, 1.0)
    first, values = _rows((x - lo[slot]) / span[slot], k_day, slot)
    col = offset[slot] + first  # the first non-zero column of each row in the whole system
    total, width = int(k_day.sum()), values.shape[1]
    # each row's columns and basis values, contiguous: every sum below runs over them
    cols = [col + a for a in range(width)]
    values = [np.ascontiguousarray(values[:, a]) for a in range(width)]

    def spline_t(w):  # B' w: (n,) -> (total,)
        return sum(np.bincount(cols[a], weights=values[a] * (weight * w), minlength=total)
                   for a in range(width))

    def per_day(w):  # weighted sum of w over each day's rows
        return np.add.reduceat(weight * w, starts)

    a_dense = np.stack([np.stack([per_day(dense[j] * dense[m]) for m in range(q)], -1)
                        for j in range(q)], 1)  # (D, q, q)
    cross = np.stack([spline_t(dense[j]) for j in range(q)], axis=1)  # (total, q)
    band = np.concatenate([_penalty_band(int(k), width) * (SMOOTHING * n)
                           for k, n in zip(k_day, n_day)], axis=1)
    for o in range(width):  # C[j, j + o], summed from the samples
        diag = sum(np.bincount(cols[a], weights=weight * values[a] * values[a + o],
                               minlength=total) for a in range(width - o))
        band[width - 1 - o, o:] += diag[:total - o]
    # a floor of 1e-12 of the largest diagonal keeps both blocks positive definite when the
    # data leave a direction free (a day of rests only has no velocity to fit a lag to)
    band[width - 1] += 1e-12 * band[width - 1].max()
    a_dense = a_dense + np.eye(q) * 1e-12 * max(a_dense[:, range(q), range(q)].max(), 1e-300)
    solved = solveh_banded(band, np.c_[cross, spline_t(y)], check_finite=False)
    block = np.repeat(np.arange(len(present)), k_day)  # the day slot of each spline column
    bounds = np.r_[0, np.cumsum(k_day)[:-1]]

    def block_t(u, v):  # u_d' v_d per day: (total, a), (total, b) -> (D, a, b)
        return np.add.reduceat(u[:, :, None] * v[:, None, :], bounds)

    schur = a_dense - block_t(cross, solved[:, :q])
    rhs_dense = np.stack([per_day(dense[j] * y) for j in range(q)], -1)  # (D, q)
    unit = np.zeros_like(rhs_dense)
    unit[:, 0] = 1.0  # the first row of the inverse: L's lever on each sample
    cross_rhs = block_t(cross, solved[:, q:])[:, :, 0]
    z_dense = np.linalg.solve(schur, np.stack([rhs_dense - cross_rhs, unit], -1))  # (D, q, 2)
    # the spline part of the right-hand sides: C^-1 B' y for beta, 0 for the lever
    z_spline = (np.c_[solved[:, q], np.zeros(total)]
                - np.einsum("ij,ijk->ik", solved[:, :q], z_dense[block]))

    def fitted(which):  # X z for the coefficients ``which`` (0: beta, 1: the lever)
        out = np.zeros(len(y))
        for j in range(q):
            out += dense[j] * z_dense[slot, j, which]
        for a in range(width):
            out += values[a] * z_spline[cols[a], which]
        return out

    scores = weight * fitted(1) * (y - fitted(0))
    u = _cluster_u(scores, clusters, slot, len(present))
    # L and c apart need velocities that do not follow the direction alone (several feeds, or
    # rests): 1 - r² of the two columns (uncentred) below SEPARABLE leaves them confounded
    r2 = a_dense[:, 0, 1] ** 2 / (a_dense[:, 0, 0] * a_dense[:, 1, 1]) if q > 1 else 0.0
    blind = np.broadcast_to(1.0 - r2 < SEPARABLE, len(present))
    return {int(d): (np.where(blind[i], np.nan, z_dense[i, :, 0]),
                     np.nan if blind[i] else u[i], int(k_day[i]))
            for i, d in enumerate(present)}


def _rows(t: np.ndarray, k_day: np.ndarray, slot: np.ndarray):
    """``features.statistics.bspline_rows`` for a different number of control points per
    day (``k_day``, sample i on day ``slot[i]``): each distinct number evaluated once, and
    without selecting rows when every day has the same (the rule's cap, on long days)."""
    sizes = np.unique(k_day)
    if len(sizes) == 1:
        return bspline_rows(t, int(sizes[0]), DEGREE)
    k = k_day[slot]
    first = np.empty(len(t), int)
    values = np.empty((len(t), DEGREE + 1))
    for size in sizes:
        rows = k == size
        first[rows], values[rows] = bspline_rows(t[rows], int(size), DEGREE)
    return first, values


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


def _cluster_u(scores: np.ndarray, clusters: np.ndarray, slot: np.ndarray,
               days: int) -> np.ndarray:
    """Cluster-robust standard uncertainty of the first coefficient per day,
    var = G/(G-1) sum_g (a' X_g' e_g)^2 over the day's G moves, a the first row of (X'X)^-1;
    ``scores`` are the per-sample terms (a' x_i) e_i."""
    base = clusters - clusters.min()
    per_move = np.bincount(base, weights=scores)
    used = np.bincount(base) > 0
    move_day = np.zeros(len(per_move), int)
    move_day[base] = slot  # a move lies within one day (a day change is a gap)
    g = np.bincount(move_day[used], minlength=days)
    ss = np.bincount(move_day[used], weights=per_move[used] ** 2, minlength=days)
    return np.sqrt(g / np.maximum(g - 1, 1) * ss)


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
    from features.traces.io import DAY_NS, groups

    frames = []
    # One BLAS thread: the matrices are small, where threads only wait for each other, and
    # an engine already runs one partition per core.
    with _blas().limit(limits=1, user_api="blas"):
        for part in groups(trace):
            ns = part["time"].to_numpy().view(np.int64)
            # bins of BIN_S on the UTC clock (a whole number of them makes a day), then days
            start = ns[0] - ns[0] % BIN_NS
            since = ns - start
            mean_ns, *channels, weight = _binned(
                since // BIN_NS, since,
                *(part[c].to_numpy() for c in ("commanded_mm", "motor_mm", "load_mm")))
            dates, day = _runs((start + mean_ns.astype(np.int64)) // DAY_NS)
            t_s = mean_ns * 1e-9
            fits = []
            for a, b in _chunks(day):
                fits += fit_days(t_s[a:b] - t_s[a], day[a:b] - day[a],
                                 *(v[a:b] for v in channels), weight[a:b], take_up=take_up,
                                 settle_s=settle_s)
            frames.append(_day_rows(str(part["machine_id"].iloc[0]),
                                    str(part["axis"].iloc[0]), dates, fits))
    if not frames:
        return pd.DataFrame(columns=list(DAILY_COLUMNS))
    return frames[0] if len(frames) == 1 else pd.concat(frames, ignore_index=True)


def _day_rows(machine: str, axis: str, dates: np.ndarray, fits: list[DayFit]) -> pd.DataFrame:
    """One machine axis's rows of ``daily_lost_motion``: its days (UTC day numbers) and fits,
    lost motion in um or arcsec."""
    scale = deviation_scale(axis)
    n = len(fits)
    field = {name: np.array([getattr(f, name) for f in fits], dtype)
             for name, dtype in (("lost_motion", float), ("lost_motion_u", float),
                                 ("reversals", np.int64), ("samples", np.int64),
                                 ("lag_s", float), ("control_points", np.int64))}
    iso = np.datetime_as_string(np.asarray(dates, "datetime64[D]"), unit="D")
    return pd.DataFrame({
        "machine_id": [machine] * n, "axis": [axis] * n, "unit": [deviation_unit(axis)] * n,
        "date": list(iso), "lost_motion_um": field["lost_motion"] * scale,
        "lost_motion_u_um": field["lost_motion_u"] * scale, "reversals": field["reversals"],
        "samples": field["samples"], "lag_s": field["lag_s"],
        "control_points": field["control_points"]}, columns=list(DAILY_COLUMNS))


def _runs(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct values of a sorted array and each element's index among them (what
    ``np.unique(values, return_inverse=True)`` gives, without sorting again)."""
    step = np.r_[False, values[1:] != values[:-1]]
    return values[np.r_[True, step[1:]]] if len(values) else values, np.cumsum(step)


def _chunks(day: np.ndarray):
    """(start, stop) of runs of whole days of about ``CHUNK_SAMPLES`` bins: fit together, a
    few days amortise the per-call cost, and their arrays stay in the processor's cache."""
    bounds = np.r_[0, np.flatnonzero(np.diff(day)) + 1, len(day)]
    start = 0
    for i in range(1, len(bounds)):
        if bounds[i] - bounds[start] >= CHUNK_SAMPLES or i == len(bounds) - 1:
            yield int(bounds[start]), int(bounds[i])
            start = i


@functools.lru_cache(maxsize=1)
def _blas():
    """The process's thread pools (found once: a search of the loaded libraries is slow)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
