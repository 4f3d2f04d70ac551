"""The maintenance schedule of a fleet (``fleet``, docs/fleet.md): when each machine axis is
next due, the fleet's wear rate an axis without a trend of its own is planned with, the day a
forecast for operating hours is for, the overdue alert, and the order worst first. Every
function is pure: it reads the per-axis analysis (``models.condition.maintenance``) and
numbers, and returns dates and numbers.

Rules:

- **next visit due** (``next_visit_due``) = the earlier of (last visit + ``interval_days``)
  and the early end of the crossing interval (the first day the upper prediction bound of a
  future visit reaches the limit; the crossing date itself where the band gives no early end),
  never before the last visit; the last visit's day (due now) when the axis is at or above its
  limit. An axis with one visit since its last change point has no trend: the crossing term is
  then the day its level plus the planned wear rate r reaches the limit L,

  .. math:: t = t_{last} + (L - y_{last}) / r

- **the fleet's wear rate** (``fleet_wear_rates``): per unit, the upper ``FLEET_RATE_QUANTILE``
  over the axes with two visits or more since their last change point of their Theil-Sen slope
  against operating hours [unit/h] (where every visit has hours), and against time
  [unit/month]; negative slopes count as 0. An axis is planned with the hourly rate times its
  own hours per day (``models.wear.wear_clock.usage_rates``), else the monthly rate
  (``planned_rate``): it may wear as fast as most of the fleet.
- **a forecast's day** (``date_at_hours``): the day the axis's hour counter reaches the
  forecast's hours, by the least-squares line of the days d against the hours h of the visits
  since the last change point, d = d_0 + h · (dd/dh) (Montgomery, Peck & Vining (2012),
  Introduction to Linear Regression Analysis, 5th ed., 2.2).
- **worst first** (``priority``): at or above the limit, past the limit unmeasured, other
  alerts, none; then the earliest next visit due, the earliest crossing date (none last), the
  highest backlash now, machine and axis.

References: Sen (1968), Theil (1950) for the slopes (``models.condition.drift.trend``); Hyndman & Fan
(1996), Sample quantiles in statistical packages, Am. Stat. 50(4), definition 7 (numpy's
default quantile).
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pandas as pd

from features.readings.schema import deviation_unit
from features.visits import DAYS_PER_MONTH

# The fleet's wear rate an axis without a trend of its own is planned with: a high quantile of
# the rates of the fleet's axes, as the axis may wear as fast as most of them.
FLEET_RATE_QUANTILE = 0.9


# --------------------------------------------------------------------------- wear rates
def fleet_wear_rates(series: list, hours: dict | None = None) -> dict[str, dict]:
    """The fleet's wear rates by unit (``um``, ``arcsec``; module docstring).

    Parameters
    ----------
    series : list of models.condition.drift.DriftSeries
        Every analysed laser series of the fleet.
    hours : dict, optional
        Operating hours [h] per ``(machine_id, axis, visit)``; None: the readings carry none.

    Returns
    -------
    dict
        Per unit: ``per_hour`` [unit/h] and ``per_month`` [unit/month], each None without an
        axis to take it from.
    """
    from models.condition.drift import trend

    found: dict[str, dict[str, list]] = {}
    for s in series:
        seg = s.visits.iloc[s.segment_start:]
        if len(seg) < 2 or not np.isfinite(s.trend.get("slope", np.nan)):
            continue
        mine = found.setdefault(deviation_unit(s.axis), {"per_hour": [], "per_month": []})
        mine["per_month"].append(max(s.trend["slope"], 0.0))
        h = np.array([(hours or {}).get((s.machine_id, s.axis, str(v)), np.nan)
                      for v in seg["visit"]])
        if np.isfinite(h).all() and np.ptp(h) > 0:
            mine["per_hour"].append(max(trend(h, seg["backlash_um"])["slope"], 0.0))
    return {unit: {k: float(np.quantile(v, FLEET_RATE_QUANTILE)) if v else None
                   for k, v in rates.items()} for unit, rates in found.items()}


def planned_rate(series, rates: dict, hours_per_day: float | None = None) -> dict | None:
    """The wear rate an axis with one visit since its last change point is planned with:
    ``per_day`` [unit/d] and ``basis`` (``operating hours``: the fleet's rate per hour times
    the axis's ``hours_per_day`` [h/d]; ``calendar``: its rate per month); None for an axis
    with a trend of its own or without a fleet rate. ``rates``: ``fleet_wear_rates``."""
    if len(series.visits) - series.segment_start > 1:
        return None
    fleet = rates.get(deviation_unit(series.axis), {})
    if fleet.get("per_hour") is not None and hours_per_day is not None:
        return {"per_day": fleet["per_hour"] * hours_per_day, "basis": "operating hours"}
    if fleet.get("per_month") is not None:
        return {"per_day": fleet["per_month"] / DAYS_PER_MONTH, "basis": "calendar"}
    return None


# --------------------------------------------------------------------------- the schedule
def next_visit_due(last_visit: pd.Timestamp, level_um: float, threshold_um: float | None,
                   interval_days: float, *, rate: dict | None = None,
                   crossing: tuple = (None, None, None)) -> tuple[dt.date, str]:
    """When an axis is next due and which rule set it (module docstring).

    Parameters
    ----------
    last_visit : pandas.Timestamp
        The last visit (the laser's: the interval counts from it).
    level_um : float
        The backlash at that visit [unit].
    threshold_um : float or None
        The axis's limit [unit].
    interval_days : float
        The maintenance interval [d].
    rate : dict, optional
        The planned wear rate of an axis without a trend (``planned_rate``).
    crossing : tuple
        The crossing (date, early, late) of the axis's analysis (``AxisForecast.crossing``).

    Returns
    -------
    (datetime.date, str)
        The day, and ``above_threshold`` (due now), ``fleet_rate``, ``crossing`` (each only
        before the interval ends) or ``interval``.
    """
    by_interval = (last_visit + pd.Timedelta(days=float(interval_days))).date()
    if threshold_um is not None and level_um >= threshold_um:
        return last_visit.date(), "above_threshold"
    if threshold_um is not None and rate is not None and rate["per_day"] > 0:
        # compared in days first: a rate near zero puts the day past any calendar
        days = (threshold_um - level_um) / rate["per_day"]
        if days < interval_days:
            when = (last_visit + pd.Timedelta(days=days)).date()
            if when < by_interval:
                return when, "fleet_rate"
    early = crossing[1] if crossing[1] is not None else crossing[0]
    if early is not None:
        when = max(early.date(), last_visit.date())
        if when < by_interval:
            return when, "crossing"
    return by_interval, "interval"


def date_at_hours(dates: pd.Series, hours, at_hours: float,
                  origin: pd.Timestamp | None = None) -> pd.Timestamp | None:
    """The time the hour counter reaches ``at_hours`` [h] (module docstring), or None.

    ``dates`` and ``hours`` [h] are those of the visits since the last change point (NaN where
    unknown); the days are counted from ``origin`` (default the first of ``dates``). None with
    fewer than two visits of different hours, or a counter that does not run forward.
    """
    origin = dates.iloc[0] if origin is None else origin
    hours = np.asarray(hours, float)
    days = (dates - origin).dt.total_seconds().to_numpy() / 86400
    keep = np.isfinite(hours)
    if keep.sum() < 2 or np.ptp(hours[keep]) <= 0:
        return None
    per_hour, start = np.polyfit(hours[keep], days[keep], 1)
    if per_hour <= 0:
        return None
    return origin + dt.timedelta(days=float(start + per_hour * at_hours))


def overdue_alert(due: dt.date, reason: str, as_of: dt.date) -> dict | None:
    """``overdue`` when the next visit was due before ``as_of``, with the days; else None."""
    late = (as_of - due).days
    if late <= 0:
        return None
    return {"kind": "overdue", "message": (
        f"next visit was due on {due.isoformat()} ({reason.replace('_', ' ')}): {late} days "
        f"overdue as of {as_of.isoformat()}")}


def priority(kinds, due: dt.date, crossing: pd.Timestamp | None, level_um: float,
             machine_id: str, axis: str) -> tuple:
    """Sort key, worst first (module docstring): the alert group of ``kinds``, the day the
    next visit is due, the crossing date (None last), the backlash now [unit], machine and
    axis."""
    kinds = set(kinds)
    group = (0 if "above_threshold" in kinds else 1 if "limit_passed_unmeasured" in kinds
             else 2 if kinds else 3)
    return (group, due, crossing is None, 0.0 if crossing is None else crossing.timestamp(),
            -float(level_um), machine_id, axis)
