"""One maintenance analysis per machine axis, shared by ``drift`` and ``fleet``.

An axis's series is its backlash at each visit (``features.visits.visit_backlash``: the lost
motion by the axis's measuring system with its standard uncertainty, docs/backlash.md; with a
store's trace days, those shifted onto the laser's definition, ``pipeline.steps.evidence``).
``models.condition.drift`` analyses it on a time axis in months τ of 30.4375 d since the series' first
point: change points by exact optimal partitioning, the Theil-Sen trend since the last one,
the crossing of the axis's limit with its interval, the alerts, each series' scatter shrunk
toward its fleet's. This module computes, once per axis, everything both views show of it,
on **one time axis: UTC datetimes**, converted once from the months (``at_month``),

.. math:: t(\\tau) = t_0 + \\tau \\cdot 30.4375\\,\\mathrm{d}

with t_0 the series' first point, so that dates of different axes compare as dates:

- the **trend line** since the last change point, ŷ(τ) = a + b τ (Theil-Sen intercept a and
  slope b [unit/month]), from the segment's first visit to the horizon;
- the **forecast band** from the last visit to the horizon, ``forecast_steps`` points, with
  the two 1 - α intervals of ``models.condition.drift.forecast_interval`` (OLS line ŷ of the segment,
  se² its variance at τ, s² the scatter between visits pooled with the fleet's, ū² the
  visits' mean repeatability, u_T² the measured target's own uncertainty, e² the backtests'
  model error, t_ν Student's quantile):

  .. math::

     \\text{measurement: } \\hat y \\pm t_\\nu \\sqrt{se^2 + s^2 + e^2}, \\qquad
     \\text{lost motion: } \\hat y + \\delta \\pm
     t_\\nu \\sqrt{se^2 + (s^2 - \\bar u^2) + u_T^2 + e^2 + u^2(\\delta)}

  with δ, u(δ) the correction of the lost motion to reference conditions, 20 °C and the
  axis's median test feed (``models.condition.reference``; zero where the data cannot decide
  it, and the forecast's ``forecast_lost_motion_note`` says which condition stays the tests');

- the **crossing** of the limit, (date, early, late): where the Theil-Sen line, the upper and
  the lower OLS prediction bounds of a future visit reach it (``models.condition.drift.crossing_forecast``);
- the **next visit**: the forecast on the day the next visit is expected, the last plus the
  median time between the series' visits, with both intervals (``DriftSeries.forecast_json``:
  the keys ``drift --json`` and ``fleet --json`` carry).

**Horizon** (``horizon_month``): how far the band and the trend line reach. Without a
maintenance interval (``drift``): the expected next visit (only with a band) or the end of the
crossing interval (its date without a late end), whichever is later. With one (``fleet``, the
schedule's ``interval_days``): one interval past the last visit, further up to the crossing
date, but at most ``forecast_cap_months`` past the last visit. A report that draws further
asks the analysis for a further horizon; it never extends a curve itself.

References: Sen (1968), Theil (1950); Jackson et al. (2005), IEEE SPL 12(2); Montgomery,
Peck & Vining (2012), Introduction to Linear Regression Analysis, 5th ed., 2.4; Hyndman &
Athanasopoulos (2021), Forecasting: Principles and Practice, 3rd ed., 5.5 (as ``models.condition.drift``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.visits import DAYS_PER_MONTH
from models.condition.drift import DriftSeries, analyse_visits, limit_passed_alert
from models.condition.settings import DEFAULTS, MaintenanceSettings


@dataclass
class AxisForecast:
    """Everything the maintenance analysis says of one machine axis, on one time axis (UTC
    datetimes).

    Attributes
    ----------
    series : models.condition.drift.DriftSeries
        The analysed series: the visits (``date``, ``backlash_um``, ``backlash_u_um``,
        ``sigma_um`` [unit], ``t_month``), change points, Theil-Sen trend [unit/month] since
        the last one, crossing [month], alerts; every value in ``unit``.
    horizon_end : pandas.Timestamp
        How far the band and the trend line reach (module docstring).
    crossing : tuple of (pandas.Timestamp or None)
        (date, early, late) the limit is crossed; None where undefined.
    trend_line : dict or None
        The Theil-Sen line from the first visit since the last change point to the horizon:
        ``at`` (DatetimeIndex), ``fit_um`` [unit]; None without a trend (one visit).
    band : dict or None
        The forecast from the last visit to the horizon: ``at`` (DatetimeIndex), ``fit_um``,
        ``measurement_low_um``/``_high_um`` (the next measurement's interval),
        ``lost_motion_low_um``/``_high_um`` (the axis's lost motion's) [unit]; None with fewer
        than three visits since the last change point (``series.forecast_note`` says why).
    next_visit : dict
        The forecast of the next visit as the JSON carries it (``forecast_date``,
        ``forecast_um``, both intervals, ``forecast_note``...; ``DriftSeries.forecast_json``).
    """

    series: DriftSeries
    horizon_end: pd.Timestamp
    crossing: tuple = (None, None, None)
    trend_line: dict | None = None
    band: dict | None = None
    next_visit: dict = field(default_factory=dict)

    @property
    def machine_id(self) -> str:
        return self.series.machine_id

    @property
    def axis(self) -> str:
        return self.series.axis

    @property
    def unit(self) -> str:
        """The unit of every ``_um`` value: ``um``, or ``arcsec`` for a rotary axis."""
        return self.series.unit

    @property
    def alerts(self) -> list[dict]:
        return self.series.alerts

    @property
    def origin(self) -> pd.Timestamp:
        """The series' first point."""
        return self.series.origin

    @property
    def dates(self) -> pd.Series:
        """The date of each point of the series."""
        return self.series.visits["date"]

    @property
    def change_dates(self) -> list[pd.Timestamp]:
        """The date of the first visit after each change point."""
        return [self.dates.iloc[c["index"]] for c in self.series.change_points]

    @staticmethod
    def day(when) -> str | None:
        """A time of the forecast as its ISO day (``YYYY-MM-DD``), None as None."""
        return None if when is None else when.date().isoformat()

    def to_dict(self) -> dict:
        """The series as ``drift --json`` carries it (``DriftSeries.to_dict``), with the
        forecast of the next visit computed here."""
        return self.series.to_dict(forecast=self.next_visit)


# --------------------------------------------------------------------------- the time axis
def at_month(series: DriftSeries, t_month):
    """The UTC time(s) of ``t_month`` [month of 30.4375 d since the series' first point]:
    a Timestamp for a number, a DatetimeIndex for an array (module docstring). Every time
    is converted alike (to the nanosecond), so a band ends where its horizon does and a
    crossing falls on the day ``DriftSeries.date_at`` gives."""
    def one(t):
        return series.origin + pd.Timedelta(days=float(t) * DAYS_PER_MONTH)

    if np.ndim(t_month) == 0:
        return one(t_month)
    return pd.DatetimeIndex([one(t) for t in np.asarray(t_month, float)])


def horizon_month(series: DriftSeries, interval_days: float | None = None,
                  cap_months: float = DEFAULTS.forecast_cap_months) -> float:
    """How far ahead [month since the series' first point] the band and the trend line reach
    (module docstring): without ``interval_days`` [d], the later of the expected next visit
    (with a band; else the last visit) and the end of the crossing interval (its date without
    a late end); with it, the last visit + ``interval_days``, further up to the crossing date
    but at most ``cap_months`` [month] past the last visit."""
    t_last = float(series.visits["t_month"].iloc[-1])
    cross, _, late = series.crossing
    if interval_days is None:
        ahead = series.next_visit_month if series.forecast_note is None else t_last
        end = late if late is not None else cross
        return max(ahead, end if end is not None else -np.inf)
    end = t_last + interval_days / DAYS_PER_MONTH
    if cross is not None:
        end = max(end, min(cross, t_last + cap_months))
    return end


# --------------------------------------------------------------------------- one axis
def axis_forecast(series: DriftSeries, settings: MaintenanceSettings = DEFAULTS) -> AxisForecast:
    """The forecast object of an analysed series (``models.condition.drift.analyse_series``): its trend
    line, band, crossing and next visit on the UTC time axis, up to its horizon."""
    end = horizon_month(series, settings.interval_days, settings.forecast_cap_months)
    curve = series.forecast_curve(end, settings.forecast_steps)
    band = None if curve is None else {
        "at": at_month(series, curve["t_month"]), "fit_um": curve["fit"],
        "measurement_low_um": curve["measurement_low"],
        "measurement_high_um": curve["measurement_high"],
        "lost_motion_low_um": curve["lost_motion_low"],
        "lost_motion_high_um": curve["lost_motion_high"]}
    tr, line = series.trend, None
    if np.isfinite(tr.get("slope", np.nan)):
        t = np.array([float(series.visits["t_month"].iloc[series.segment_start]), end])
        line = {"at": at_month(series, t), "fit_um": tr["intercept"] + tr["slope"] * t}
    crossing = tuple(None if t is None else at_month(series, t) for t in series.crossing)
    return AxisForecast(series, at_month(series, end), crossing, line, band,
                        series.forecast_json())


def analyse_axes(visits: pd.DataFrame, settings: MaintenanceSettings = DEFAULTS, *,
                 as_of=None, min_visits: int = 1,
                 coverage_factor: float | None = None,
                 reference: dict | None = None) -> list[AxisForecast]:
    """The maintenance analysis of every machine axis in ``visits`` (``visit_backlash`` rows,
    with ``min_visits`` or more), in (machine_id, axis) order.

    Parameters
    ----------
    visits : DataFrame
        One row per machine axis and visit: ``machine_id``, ``axis``, ``visit``, ``date``,
        ``backlash_um`` and ``backlash_u_um`` [unit] (``features.visits.visit_backlash``).
        The axes are analysed together: each series' scatter is shrunk toward the pooled
        scatter of its unit's series, its forecast intervals take their scatter and model
        error (``models.condition.drift.analyse_visits``).
    settings : MaintenanceSettings
        Limits, significance level, change-point rule and horizons.
    as_of : datetime.date, optional
        The day the analysis is computed as of: an axis whose crossing date lies before it
        alerts ``limit_passed_unmeasured`` (``models.condition.drift.limit_passed_alert``).
    reference : dict, optional
        {(machine_id, axis): AxisReference} (``models.condition.reference
        .reference_corrections``): each lost-motion interval states the axis's lost motion at
        reference conditions (20 °C, the axis's median test feed); without, at the tests' own.
    min_visits : int, default 1
        The fewest visits of a series analysed.
    coverage_factor : float, optional
        k of the visits' ``backlash_U_um`` (an uncertainty budget): steps within U(Δ) do not
        alert (``models.condition.drift``).

    Returns
    -------
    list of AxisForecast
    """
    series = analyse_visits(visits, min_visits=min_visits, coverage_factor=coverage_factor,
                            reference=reference, **settings.limits_of(),
                            **settings.trend_options())
    if as_of is not None:
        for s in series:
            s.alerts += [a for a in [limit_passed_alert(s, as_of)] if a is not None]
    return [axis_forecast(s, settings) for s in series]
