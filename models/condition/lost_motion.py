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

The standard uncertainty of L is a delete-one-cluster jackknife (CR3) with the motions between
two reversals as clusters (pooled into ``GROUPS`` groups), stated for k = 2 with the t
quantile of its G - 1 degrees of freedom: samples of one move share their errors (the
servo's, the scale's interpolation, the lead-error fit's misfit where it passed), so the
moves, not the samples, are the independent evidence; each refit refits the lead error and the
lag without the move. Fewer than ``MIN_CLUSTERS`` moves, or a move without which the play
cannot be told from the lead error or the lag, give the day's value without an uncertainty
(NaN).

The fit is written as sufficient statistics that add up per move and a combiner per day
(``models.condition.lost_motion_stream``): ``monitor`` on a file and ``watch`` on a live feed run the same
code and agree by construction; a day's state is bounded whatever its length.

References: [Mechta2022] (B-spline intra-axis error model); Eilers & Marx (1996), "Flexible
smoothing with B-splines and penalties", Statistical Science 11(2) (P-splines); Siemens,
SINUMERIK Analyze MyMachine /Condition (a second, load-side encoder for backlash); Liang & Zeger (1986),
"Longitudinal data analysis using generalized linear models", Biometrika 73(1) (cluster-robust
variance); Bell & McCaffrey (2002), "Bias reduction in standard errors for linear regression
with multi-stage samples", Survey Methodology 28(2); MacKinnon & Webb (2017), "Wild bootstrap
inference for wildly different cluster sizes", J. Applied Econometrics 32(2) (the cluster
jackknife CR3); Cameron & Miller (2015), "A practitioner's guide to cluster-robust
inference", J. Human Resources 50(2) (few clusters); JCGM 100:2008 (GUM) G.3, G.6.4 (t
quantiles for few degrees of freedom).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.readings.schema import deviation_scale, deviation_unit
from models.condition.lost_motion_stream import BIN_NS, STEADY, stream_days

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
        Its standard uncertainty stated for k = 2 (``models.condition.lost_motion_stream``'s
        jackknife) [mm or deg]; NaN when the day's moves cannot give one.
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
    from models.condition.lost_motion_stream import DAY_NS, AxisStream

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
                      settle_s: float = SETTLE_S, travel: bool = False) -> pd.DataFrame:
    """Lost motion of every machine axis and UTC day of a validated trace with ``load_mm``
    (``features.traces``): a pure function of its input, so it runs per partition anywhere.

    Parameters
    ----------
    travel : bool
        Add ``TRAVEL_COLUMNS``, what ``check_physical`` needs of each day.

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
            # (models.condition.lost_motion_stream): a file and a live feed agree by construction
            extra = _travel(day, weight, *channels) if travel else {}
            if extra and _motor_off(extra, take_up).any():
                # refused after (check_physical), so not fitted: a motor side in counts would
                # size the lead-error grid by its counts
                fits = [DayFit(np.nan, np.nan, 0, 0, np.nan, 0)] * len(dates)
            else:
                fits = [DayFit(*fit) for _, fit in stream_days(
                    ns, *(part[c].to_numpy() for c in ("commanded_mm", "motor_mm", "load_mm")),
                    take_up=take_up, settle_s=settle_s)]
            rows = _day_rows(str(part["machine_id"].iloc[0]), str(part["axis"].iloc[0]),
                             dates, fits)
            frames.append(rows.assign(**extra))
    if not frames:
        return pd.DataFrame(columns=list(DAILY_COLUMNS) + (list(TRAVEL_COLUMNS) * travel))
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


# ------------------------------------------------------------- what cannot be physical
# Per day, what tells a wrong channel from a lost motion (``daily_lost_motion(travel=True)``):
# the travel (range) of the commanded, motor and load positions, the load's gain on the motor
# (least-squares slope: about 1, its sign the load's direction) and the load's mean offset
# from the motor [mm or deg].
TRAVEL_COLUMNS = ("travel_mm", "motor_travel_mm", "load_travel_mm", "load_gain",
                  "load_offset_mm")
# A load side travelling more than this factor more or less than the motor side is not the
# same axis in the same unit: raw counts, um for mm, a wrong gear ratio or lead.
TRAVEL_RATIO = 2.0
# A lost motion below zero by more than NEGATIVE_U standard uncertainties and NEGATIVE_FLOOR
# [um or arcsec] is no play: the load leads the motor at reversals. Three, not two, standard
# uncertainties: a fleet monitors thousands of axis days, and two would refuse one day in
# forty of an axis without play; the floor keeps a tiny u from refusing noise at zero.
NEGATIVE_U = 3.0
NEGATIVE_FLOOR = 1.0
# Known unit factors between two channels, named in the likely cause (within 5 %).
UNIT_FACTORS = {1000.0: "um against mm", 25.4: "inch against mm", 3600.0: "arcsec against deg"}


def _travel(day: np.ndarray, weight: np.ndarray, commanded: np.ndarray, motor: np.ndarray,
            load: np.ndarray) -> dict[str, np.ndarray]:
    """``TRAVEL_COLUMNS`` per day of one machine axis's bins (``day`` sorted)."""
    starts = np.flatnonzero(np.r_[True, day[1:] != day[:-1]])

    def span(v):
        return np.maximum.reduceat(v, starts) - np.minimum.reduceat(v, starts)

    def mean(v):
        return np.add.reduceat(weight * v, starts) / np.add.reduceat(weight, starts)

    dm, dl = motor - mean(motor)[day], load - mean(load)[day]
    var, cov = mean(dm * dm), mean(dm * dl)
    gain = np.divide(cov, var, out=np.full(len(var), np.nan), where=var > 0)
    return {"travel_mm": span(commanded), "motor_travel_mm": span(motor),
            "load_travel_mm": span(load), "load_gain": gain,
            "load_offset_mm": mean(load) - mean(motor)}


def check_physical(daily: pd.DataFrame, names: dict, *, min_travel: float = TAKE_UP_MM,
                   file=None, remedy: str = "") -> None:
    """Refuse the first day of ``daily`` (``daily_lost_motion(travel=True)``) whose figures
    cannot be physical, before anything is recorded.

    Refused: a load side that moves against the motor side (a sign), or travels more than
    ``TRAVEL_RATIO`` times more or less (raw counts, a wrong unit or gear ratio), a motor side
    that travels so against the set point, on a day whose motor (set point) travelled at least
    ``min_travel`` (below it no play is taken up and the ranges are noise); a lost motion
    larger than the day's commanded travel; a lost motion negative beyond ``NEGATIVE_U``
    standard uncertainties and ``NEGATIVE_FLOOR``.

    Parameters
    ----------
    names : dict
        Channel (``commanded``, ``motor``, ``load``) -> the name the user gave it (a PV, a
        column), named in the message.
    file : str or path, optional
        The input the days come from.
    remedy : str
        Appended to a scale, sign or unit problem (how the input states a scale).

    Raises
    ------
    InputError
        One line: the machine axis and day, the channel, the figures and the likely cause.
    """
    from features.readings.errors import InputError

    for row in daily.itertuples():
        problem = _scale_problem(row, names, min_travel)
        problem = (problem + remedy if problem
                   else _motor_problem(row, names, min_travel) or _negative(row, names))
        if problem:
            raise InputError(f"{row.machine_id} {row.axis} on {row.date}: {problem}", file=file)


def _motor_off(travel: dict, min_travel: float) -> np.ndarray:
    """Days whose motor side travels more than ``TRAVEL_RATIO`` times more or less than the
    set point, which moved at least ``min_travel``."""
    ratio = travel["motor_travel_mm"] / np.where(travel["travel_mm"] > 0, travel["travel_mm"], 1)
    return (travel["travel_mm"] >= min_travel) & ((ratio > TRAVEL_RATIO)
                                                   | (ratio < 1 / TRAVEL_RATIO))


def _motor_problem(row, names: dict, min_travel: float) -> str | None:
    """A motor side that does not travel as the set point does (raw counts, a unit, a lead);
    None when it does."""
    if not _motor_off({k: np.array([getattr(row, k)]) for k in TRAVEL_COLUMNS},
                      min_travel)[0]:
        return None
    unit = "deg" if row.unit == "arcsec" else "mm"
    ratio = row.motor_travel_mm / row.travel_mm
    return (f"the motor side {names['motor']} travels {row.motor_travel_mm:.6g} {unit} while "
            f"the commanded {names['commanded']} travels {row.travel_mm:.6g} {unit} "
            f"({ratio:.6g}x): {_cause(ratio)}; expected the same travel within a factor of "
            f"{TRAVEL_RATIO:g}")


def _scale_problem(row, names: dict, min_travel: float) -> str | None:
    """What a scale of the load side would fix on this day (a sign, raw counts, a unit, a
    gear ratio), with its likely cause; None when nothing."""
    unit = "deg" if row.unit == "arcsec" else "mm"
    load, motor = f"load side {names['load']}", f"motor side {names['motor']}"
    if row.motor_travel_mm >= min_travel and not _motor_problem(row, names, min_travel):
        if row.load_gain < 0:
            return (f"the {load} moves against the {motor} (gain {row.load_gain:.4g}): a "
                    "sign; expected both counting the same way")
        ratio = row.load_travel_mm / row.motor_travel_mm
        if not 1 / TRAVEL_RATIO <= ratio <= TRAVEL_RATIO:
            return (f"the {load} travels {row.load_travel_mm:.6g} {unit} while the {motor} "
                    f"travels {row.motor_travel_mm:.6g} {unit} ({ratio:.6g}x): "
                    f"{_cause(ratio)}; expected the same travel within a factor of "
                    f"{TRAVEL_RATIO:g}")
    if row.lost_motion_um > row.travel_mm * deviation_scale(row.axis):
        return (f"lost motion {row.lost_motion_um:.6g} {row.unit} is larger than the day's "
                f"travel of {row.travel_mm:.6g} {unit} (commanded {names['commanded']}): a "
                f"wrong scale or unit of the {load} or the {motor}")
    return None


def _negative(row, names: dict) -> str | None:
    """A lost motion negative beyond its uncertainty: the load leads the motor."""
    value, u = row.lost_motion_um, row.lost_motion_u_um
    # a day without an uncertainty (too few moves) is judged by the floor alone
    if value < -max(NEGATIVE_U * u if np.isfinite(u) else 0.0, NEGATIVE_FLOOR):
        return (f"lost motion {value:.6g} +- {u:.3g} {row.unit} is negative beyond its "
                "uncertainty: the load leads the motor at reversals; are the motor side "
                f"{names['motor']} and the load side {names['load']} swapped, or one of them "
                "lagging in time?")
    return None


def _cause(ratio: float) -> str:
    """The likely cause of a load travel ``ratio`` times the motor's."""
    big = max(ratio, 1 / ratio)
    for factor, what in UNIT_FACTORS.items():
        if abs(big / factor - 1) < 0.05:
            return f"a wrong unit ({what})"
    return "raw counts or a wrong unit" if big > 50 else "a wrong scale, gear ratio or lead"


def offset_notes(daily: pd.DataFrame, names: dict, *, min_travel: float = TAKE_UP_MM
                 ) -> list[str]:
    """A note per machine axis whose load side sits further from the motor side than the
    motor travels: not the same coordinates. The lost motion does not change (the lead-error
    spline's constant absorbs any offset), so it is said, not refused."""
    notes = []
    for (machine, axis), days in daily.groupby(["machine_id", "axis"], sort=True):
        off = days[days["motor_travel_mm"] >= min_travel]
        far = off[off["load_offset_mm"].abs() > off["motor_travel_mm"]]
        if len(far):
            r = far.iloc[0]
            unit = "deg" if r.unit == "arcsec" else "mm"
            notes.append(f"{machine} {axis}: the load side {names['load']} sits "
                         f"{r.load_offset_mm:+.6g} {unit} from the motor side {names['motor']} "
                         f"on {r.date}, more than the {r.motor_travel_mm:.6g} {unit} it "
                         "travels: not the same coordinates; lost motion does not change with "
                         "an offset (the lead-error fit absorbs it); a raw log's reference "
                         f"scale 1,{-r.load_offset_mm:.6g} states it")
    return notes
