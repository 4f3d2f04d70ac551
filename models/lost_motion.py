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

with N_k a degree-2 B-spline basis of position ([Mechta2022], eqs. 4-5) on a fixed grid of
absolute position (a control point every ``LEAD_SPACING_MM``) and a small penalty on their second
differences (a P-spline), so a stretch of travel without samples follows its neighbours instead
of leaving the fit undetermined. It uses only the samples where the play is surely taken up
(the commanded path has run ``take_up_mm`` since its last reversal, so a reversal shorter than
the clearance never counts) and the axis moves steadily or rests (no acceleration within ``settle_s``). With several feeds c and L separate;
with reversals at many positions e(x) and L do.

The standard uncertainty of L is the cluster-robust (sandwich) one with the motions between
two reversals as clusters (pooled into ``GROUPS`` groups): samples of one move share their
errors (the servo's, the scale's interpolation), so the moves, not the samples, are the
independent evidence.

The fit is written as sufficient statistics that add up per move and a combiner per day
(``models.lost_motion_stream``): ``monitor`` on a file and ``watch`` on a live feed run the same
code and agree by construction; a day's state is bounded whatever its length.

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
from models.lost_motion_stream import BIN_NS, STEADY, stream_days

# Motor travel after a reversal past which the play is taken up [mm or deg]: larger than any
# plausible lost motion (DESIGN.md: 0.5-15 um) with its wind-up.
TAKE_UP_MM = 0.05
# Time after the last acceleration before a sample counts as steady [s]: the servo settles.
SETTLE_S = 0.1
# The estimator's constants (spline grid, penalty, clusters, steadiness, bins) are the stream
# module's: one definition for a file and a live feed.
# The samples are averaged over bins of BIN_S [s] first (weighted by their counts): where the
# fit looks (steady motion, rests) the servo and the scale do not change within one, so it
# loses nothing, and past the first pass its cost does not grow with the sampling rate.
BIN_S = 0.04


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
        Control points of the lead-error spline over the day's travel.
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
    # a step within float rounding is a rest (bin means of a resting set point differ in
    # their last bits with the order they were summed in)
    velocity = np.divide(step, dt, out=np.zeros(len(dt)), where=(dt > 0) & moving)
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
    from models.lost_motion_stream import DAY_NS, AxisStream

    day = np.asarray(day, np.int64)
    days = int(day[-1]) + 1 if len(day) else 0
    t_s = np.asarray(t_s, float)
    first = t_s[np.searchsorted(day, day)]  # each day's clock starts at its first sample
    if weight is None:
        ns = day * DAY_NS + np.round((t_s - first) * 1e9).astype(np.int64)
        found = dict(stream_days(ns, commanded, motor, load, take_up=take_up,
                                 settle_s=settle_s))
    else:
        stream = AxisStream(take_up, settle_s)
        found = dict(stream.feed(day, t_s - first, commanded, motor, load, weight)
                     + stream.close())
    return [DayFit(*found[d]) if d in found else DayFit(np.nan, np.nan, 0, 0, np.nan, 0)
            for d in range(days)]


def _binned(key, *channels):
    """Means of each channel over the runs of equal ``key`` (the bins of ``BIN_S``), and the
    samples per bin. The means are linear, so the play, the lead error (smooth over a bin's
    travel) and the lag keep their form, and steady motion stays steady."""
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[starts, len(key)]).astype(float)
    return (*(np.add.reduceat(v, starts) / count for v in channels), count)


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
            # the samples through the stream and day combiner ``watch`` runs
            # (models.lost_motion_stream): a file and a live feed agree by construction
            fits = [DayFit(*fit) for _, fit in stream_days(
                ns, *(part[c].to_numpy() for c in ("commanded_mm", "motor_mm", "load_mm")),
                take_up=take_up, settle_s=settle_s)]
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


@functools.lru_cache(maxsize=1)
def _blas():
    """The process's thread pools (found once: a search of the loaded libraries is slow)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
