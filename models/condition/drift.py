"""Drift of a visit series: change points, robust trend, threshold forecast and alerts.

The series is the axis's backlash at each visit (``features.visits.visit_backlash``:
``backlash_um``, the lost motion by the axis's measuring system, with its standard uncertainty
``backlash_u_um``; docs/backlash.md), analysed on the time axis in months of 30.4375 days since
the first visit:

- change points: exact optimal partitioning (dynamic programming) into piecewise linear
  segments, cost = chi-square of a weighted straight-line fit per segment, penalty
  ``6 ln(n)`` per extra segment (twice the BIC of 3 parameters: place, level, slope; doubled
  because sigma is itself estimated from the same short series). A change is kept only when
  its jump exceeds ``min_jump_sigma`` (3) standard errors of the two segment lines there. The sigma
  is the larger of ``backlash_u_um`` and a robust (MAD) estimate of the scatter between visits (from 7
  visits on), because conditions that change from visit to visit usually scatter more than the
  laser repeats. A fleet's series analysed together (``analyse_visits``) share strength: each
  series' scatter is shrunk toward the fleet's pooled scatter (the same unit's series) with the
  weight of ``SCATTER_PRIOR_RESIDUALS`` residuals, as the pooled wear map shrinks each axis's
  noise. Seven visits give five residuals, and a step spoils two of them: alone, such a series
  can hide an adjustment behind the scatter the adjustment itself makes. A series too short
  for a scatter of its own keeps u alone: when a whole fleet was adjusted at once, its short
  series' residuals are half steps, and their pooled scatter would hide every adjustment.
- trend since the last change point: Theil-Sen slope with its confidence interval
  (``scipy.stats.theilslopes``) and the Mann-Kendall test (Kendall's tau of value against time,
  ``scipy.stats.kendalltau``; the same statistic, with the tie correction).
- threshold crossing: the Theil-Sen line of the last segment crosses the threshold at the
  reported date; the interval is where the OLS prediction band of a future visit (Student t,
  ``1 - alpha``) crosses it: early end = upper band, late end = lower band (null when the lower
  band never reaches the threshold within ``horizon_months``). The crossing is null when the
  last visit is already at or above the threshold (an ``above_threshold`` alert fires instead)
  or when the Theil-Sen slope is not positive, or so small that the line reaches the threshold
  more than ``MAX_CROSSING_MONTHS`` (100 years) after the last visit.

Alert policy (each alert a dict with ``kind`` and ``message``): ``above_threshold``,
``crossing_soon`` (early end of the crossing interval within ``warn_months`` of the last
visit), ``increasing_trend`` (no threshold given: Mann-Kendall p < alpha and the Theil-Sen
interval above zero), ``level_jump`` (the latest change point raised the level: failure
suspected), ``last_visit_drop`` / ``last_visit_jump`` (a change point at the last visit: the
last visit alone is the last segment, its value more than ``min_jump_sigma`` standard errors
below / above the trend before it; an adjustment restarts the trend there, a jump awaits the
next visit to be confirmed; without such a change point ``last_visit_jump`` also fires when
the last visit lies that far above the line of its segment's earlier visits),
``limit_passed_unmeasured`` (``limit_passed_alert``: the crossing date lies before the day the
view is computed as of) and, with a monitored model (``models.condition.monitoring``), ``retrain``,
``input_out_of_range``, ``input_drift``. Every value, limit and message is in the axis's unit
(``DriftSeries.unit``: um, or arcsec for a rotary axis); ``limit_of`` gives each axis a limit
in its own unit, so no alert compares unlike units.

Forecast of the next visit (``forecast_interval``, ``forecast_terms``; the next visit is the
last plus the median time between the series' visits): the OLS line of the visits since the
last change point with two 1 - alpha intervals that answer two questions. The **measurement**
interval holds the value the laser will give (the line's uncertainty, the scatter between
visits pooled over the fleet's segments, the model error of rolling-origin backtests inside
the fleet's segments); the **lost-motion** interval holds the axis's lost motion itself (the
line's uncertainty, the part of the scatter that is the axis's own, the measured target's own
uncertainty, the model error). Fewer than three visits since the last change point give no
interval (``DriftSeries.forecast_note`` says why).

With a measurement uncertainty budget (ISO/TR 230-9; the series then carries
``backlash_U_um``, the expanded uncertainty of each visit's value, and ``backlash_u_visit_um``,
the standard uncertainty of the parts that change from visit to visit) a step counts only when
it exceeds the expanded uncertainty of the difference of the two visits it compares (beside a
change point, the last visit and the one before it, a trend segment's first and last),

.. math:: U(\\Delta) = k \\sqrt{u_{v,a}^2 + u_{v,b}^2}

(GUM 5.2.2 with the setup's systematic part fully correlated between visits, r = +1, so it
cancels; docs/uncertainty.md). A change point, a last-visit jump or a trend's rise within
U(Δ) is listed in ``within_uncertainty`` instead of raising ``level_jump``, ``last_visit_jump``
or ``increasing_trend``.

References: Sen (1968), Theil (1950); Mann (1945), Kendall (1975); Jackson et al. (2005),
"An algorithm for optimal partitioning of data on an interval", IEEE SPL 12(2); Tashman (2000),
"Out-of-sample tests of forecasting accuracy", IJF 16(4); Hyndman & Athanasopoulos (2021),
Forecasting: Principles and Practice, 3rd ed., 5.5 and 5.10; Montgomery, Peck & Vining (2012),
Introduction to Linear Regression Analysis, 5th ed., 2.4; JCGM 100:2008 (GUM) 6.3, F.2.4.5, G.4.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
import pandas as pd
from scipy import stats

from features.visits import DAYS_PER_MONTH, SERIES_KEYS, months_between
from models.condition.settings import DEFAULTS

MIN_VISITS_FOR_SCATTER = 7
# A crossing date further than this past the last visit [month] is no date: a line that flat
# does not reach the limit in the life of a machine (and pandas holds no date past 2262).
MAX_CROSSING_MONTHS = 1200.0
# Residuals' worth of weight the fleet's pooled scatter has in each series' own.
SCATTER_PRIOR_RESIDUALS = 10.0
# The fleet's pooled scatter needs this many residuals, from two series or more.
MIN_FLEET_RESIDUALS = 10
# What each kind of change within the measurement uncertainty is, in words.
WITHIN_KINDS = {"change_point": "the step", "last_visit": "the last visit's departure from "
                "the trend", "trend": "the rise of the trend"}
# Per-visit columns of the series that its JSON carries when present, each a quantity of its own.
OPTIONAL_JSON = ("target_kind", "n_points", "reversal_mean_um", "reversal_max_um", "source")


def uncertainty_column(visits: pd.DataFrame) -> str:
    """The column with the standard uncertainty of ``backlash_um``: ``backlash_u_um``, or
    ``u_um`` in a frame built before the name said which quantity it belongs to."""
    return "backlash_u_um" if "backlash_u_um" in visits or "u_um" not in visits else "u_um"


# --------------------------------------------------------------------------- statistics
def _second_differences(t, y) -> np.ndarray:
    """r_i / sqrt(1 + w² + (1-w)²) of ``scatter_sigma_um``, one per inner point."""
    w = (t[2:] - t[1:-1]) / (t[2:] - t[:-2])
    return (y[1:-1] - (w * y[:-2] + (1 - w) * y[2:])) / np.sqrt(1 + w ** 2 + (1 - w) ** 2)


def _mad_sigma(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def fleet_scatter_um(visits: pd.DataFrame) -> dict[str, float]:
    """The fleet's pooled scatter between visits, per deviation unit (``um``, ``arcsec``):
    the MAD estimate of ``scatter_sigma_um`` over the second differences of every series of
    that unit with three visits or more; a unit with fewer than ``MIN_FLEET_RESIDUALS`` of
    them, or from one series alone, gets none."""
    from features.readings.schema import deviation_unit

    residuals: dict[str, list[np.ndarray]] = {}
    for (_, axis), group in visits.groupby(list(SERIES_KEYS), sort=True, observed=True):
        if len(group) < 3:
            continue
        g = group.sort_values("date", kind="stable")
        t = np.asarray(months_between(g["date"], g["date"].iloc[0]), float)
        residuals.setdefault(deviation_unit(axis), []).append(
            _second_differences(t, g["backlash_um"].to_numpy(float)))
    return {unit: _mad_sigma(np.concatenate(parts)) for unit, parts in residuals.items()
            if len(parts) >= 2 and sum(map(len, parts)) >= MIN_FLEET_RESIDUALS}


def shrunk_scatter_um(own: float, n_visits: int, fleet: float | None) -> float:
    """A series' scatter [um] shrunk toward the fleet's: the variance-weighted mean with its
    own ``n_visits - 2`` residuals against ``SCATTER_PRIOR_RESIDUALS`` of the fleet's; its own
    (NaN for a short series) when there is no fleet or it has none."""
    if fleet is None or not np.isfinite(fleet) or not np.isfinite(own):
        return own
    m = max(n_visits - 2, 0)
    return float(np.sqrt((m * own ** 2 + SCATTER_PRIOR_RESIDUALS * fleet ** 2)
                         / (m + SCATTER_PRIOR_RESIDUALS)))


def scatter_sigma_um(t_month, y_um) -> float:
    """Robust scatter of a piecewise linear series from its second differences [um].

    Each inner point is compared with the straight line through its neighbours,
    r_i = y_i - (w y_{i-1} + (1-w) y_{i+1}), var(r_i) = sigma²(1 + w² + (1-w)²);
    sigma = 1.4826 MAD(r_i / sqrt(1 + w² + (1-w)²)). Steps spoil only the two residuals
    beside them, which the median ignores. NaN for fewer than 3 points.
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    if len(y) < 3:
        return float("nan")
    return _mad_sigma(_second_differences(t, y))


def _segment_costs(t, y, w):
    """Chi-square of the weighted straight-line fit of every segment y[i:j] (n+1 x n+1)."""
    c = [np.concatenate([[0.0], np.cumsum(v)])
         for v in (w, w * t, w * t * t, w * y, w * t * y, w * y * y)]
    i, j = np.triu_indices(len(t) + 1, k=1)
    s, st, stt, sy, sty, syy = (v[j] - v[i] for v in c)
    det = s * stt - st ** 2
    ok = det > 1e-12 * np.maximum(s * stt, 1e-300)
    slope = np.where(ok, (s * sty - st * sy) / np.where(ok, det, 1), 0.0)
    level = (sy - slope * st) / s
    chi2 = syy - 2 * level * sy - 2 * slope * sty + level ** 2 * s + 2 * level * slope * st \
        + slope ** 2 * stt
    cost = np.full((len(t) + 1, len(t) + 1), np.inf)
    cost[i, j] = np.maximum(chi2, 0.0)
    return cost


def optimal_partition(t_month, y_um, sigma_um, *, penalty: float, min_size: int = 2,
                      min_last: int | None = None):
    """Exact optimal partitioning into straight-line segments (Jackson et al. 2005).

    Minimises sum over segments of chi²(segment) + penalty x (number of segments) by dynamic
    programming over all O(n²) segments; every segment holds ``min_size`` points or more, the
    last one ``min_last`` (default ``min_size``). Returns the start indices of segments 2..k.
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    n = len(y)
    min_last = min_size if min_last is None else min_last
    cost = _segment_costs(t, y, 1.0 / np.asarray(sigma_um, float) ** 2)
    best = np.full(n + 1, np.inf)
    best[0] = -penalty
    last = np.zeros(n + 1, int)
    for j in range(min_size, n + 1):  # O(n) loop over series ends, n <= a few hundred
        starts = np.arange(0, j - (min_last if j == n else min_size) + 1)
        total = best[starts] + cost[starts, j] + penalty
        k = int(np.argmin(total))
        best[j], last[j] = total[k], starts[k]
    cuts, j = [], n
    while j > 0:
        j = last[j]
        if j > 0:
            cuts.append(j)
    return sorted(cuts)


def _line(t, y):
    """OLS line: level at t=0, slope, residual s (NaN below 3 points)."""
    if len(t) < 2 or np.ptp(t) == 0:
        return float(np.mean(y)), 0.0, float("nan")
    slope, level = np.polyfit(t, y, 1)
    s = float(np.sqrt(np.sum((y - level - slope * t) ** 2) / (len(t) - 2))) if len(t) > 2 \
        else float("nan")
    return float(level), float(slope), s


def change_points(t_month, y_um, sigma_um, *, penalty: float | None = None,
                  min_jump_sigma: float = 3.0, min_size: int = 2,
                  min_last: int = 1) -> list[dict]:
    """Change points of a piecewise linear series, each with the jump it made.

    Parameters
    ----------
    t_month : times [month]; y_um : values [um]; sigma_um : per-visit sigma [um]
    penalty : chi² penalty per extra segment; default 6 ln(n) (twice BIC, 3 parameters)
    min_jump_sigma : a kept change jumps by more than this many standard errors: the left
        segment's line extrapolated to the first visit after the change against the right
        segment's line there, se² = sum over both lines of sigma²(1/m + (t_k - t̄)²/Sxx).
    min_size, min_last : the fewest visits of a segment and of the last one. The last may
        hold the last visit alone (default): an adjustment or a failure just before the
        latest visit is a change there, its right "line" that visit's value (se² = sigma²),
        rather than a trend bent through it.

    Returns
    -------
    list of {"index", "jump_um", "jump_sigma"} in time order; ``index`` is the first visit
    after the change.
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    sigma = np.broadcast_to(np.asarray(sigma_um, float), y.shape)
    n = len(y)
    if n < min_size + min_last:
        return []
    penalty = 6.0 * np.log(n) if penalty is None else penalty
    cuts = optimal_partition(t, y, sigma, penalty=penalty, min_size=min_size,
                             min_last=min_last)
    found = _strong(t, y, sigma, cuts, min_jump_sigma)
    if min_last == 1:
        found = _last_visit_change(t, y, sigma, found, penalty=penalty,
                                   min_jump_sigma=min_jump_sigma, min_size=min_size)
    return found


def _last_visit_change(t, y, sigma, found, *, penalty, min_jump_sigma, min_size):
    """The change points with the last visit's own weighed again.

    A two-visit last segment fits exactly, so the partition cannot tell a change before the
    last two visits from one before the last visit alone. When its two visits fall by more
    than ``min_jump_sigma`` sigma of their difference, the change is put before the last
    visit (wear does not lower the lost motion: the fall is an adjustment there). When the
    change before them proved weak, a change before the last visit is weighed on its own:
    kept when it saves more chi² than ``penalty`` and jumps by more than ``min_jump_sigma``.
    """
    n = len(y)
    kept = [c["index"] for c in found]
    if kept and kept[-1] == n - 2:
        if y[-2] - y[-1] <= min_jump_sigma * np.hypot(sigma[-2], sigma[-1]):
            return found
        moved = _strong(t, y, sigma, kept[:-1] + [n - 1], min_jump_sigma)
        return moved if moved and moved[-1]["index"] == n - 1 else found
    start = kept[-1] if kept else 0
    if n - 1 - start < min_size:
        return found
    w = 1.0 / sigma[start:] ** 2
    saved = _segment_costs(t[start:], y[start:], w)[0, -1] - _segment_costs(
        t[start:-1], y[start:-1], w[:-1])[0, -1]
    return _strong(t, y, sigma, kept + [n - 1], min_jump_sigma) if saved > penalty else found


def _strong(t, y, sigma, cuts, min_jump_sigma):
    """The jumps of ``cuts``, the weakest removed one at a time while any is within
    ``min_jump_sigma`` standard errors."""
    cuts = list(cuts)
    while True:
        found = _jumps(t, y, sigma, cuts)
        weak = [c for c in found if abs(c["jump_sigma"]) <= min_jump_sigma]
        if not weak:
            return found
        cuts.remove(min(weak, key=lambda c: abs(c["jump_sigma"]))["index"])


def _jumps(t, y, sigma, cuts):
    bounds = [0, *cuts, len(y)]
    out = []
    for a, k, b in zip(bounds[:-2], bounds[1:-1], bounds[2:]):
        left, right = _line(t[a:k], y[a:k]), _line(t[k:b], y[k:b])
        jump = (right[0] + right[1] * t[k]) - (left[0] + left[1] * t[k])
        se = np.sqrt(_fit_var(t[a:k], sigma[a:k], t[k]) + _fit_var(t[k:b], sigma[k:b], t[k]))
        out.append({"index": int(k), "jump_um": float(jump), "jump_sigma": float(jump / se)})
    return out


def _fit_var(t, sigma, at):
    """Variance [um²] of a straight-line fit evaluated at ``at``: s²(1/m + (at - t̄)²/Sxx)."""
    s2 = float(np.mean(np.asarray(sigma) ** 2))
    sxx = float(np.sum((t - t.mean()) ** 2))
    return s2 * (1 / len(t) + ((at - t.mean()) ** 2 / sxx if sxx > 0 else 0.0))


def trend(t_month, y_um, alpha: float = 0.05) -> dict:
    """Theil-Sen slope [um/month] with its 1-alpha interval, and the Mann-Kendall test.

    From two visits the slope is their difference over the time between them and its
    interval cannot be estimated (``low`` and ``high`` NaN).

    Mann-Kendall S = sum_{i<j} sign(y_j - y_i) is Kendall's tau between time and value, so
    its p-value (two-sided) comes from ``scipy.stats.kendalltau``.
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    if len(y) < 2:
        nan = float("nan")
        return {"slope": nan, "intercept": nan, "low": nan, "high": nan, "tau": nan,
                "p_value": nan}
    res = stats.theilslopes(y, t, alpha=1 - alpha)
    tau, p = stats.kendalltau(t, y) if len(y) >= 3 else (float("nan"), float("nan"))
    # two visits give one pairwise slope: its interval would have zero width, it cannot be
    # estimated (NaN, null in the JSON; the pages say so)
    low, high = (res[2], res[3]) if len(y) >= 3 else (float("nan"), float("nan"))
    return {"slope": float(res[0]), "intercept": float(res[1]), "low": float(low),
            "high": float(high), "tau": float(tau), "p_value": float(p)}


def crossing_forecast(t_month, y_um, sigma_um, threshold_um: float, *, slope: float,
                      intercept: float, alpha: float = 0.05, horizon_months: float = 120.0):
    """Time [month] the backlash crosses ``threshold_um``, with an interval, or Nones.

    Point: the Theil-Sen line ``intercept + slope t`` reaches the threshold. Interval: the
    first times the upper and the lower OLS prediction bounds of one future visit,
    yhat(t) ± q s sqrt(1 + 1/m + (t - t̄)²/Sxx), reach it (q Student t with m-2 degrees of
    freedom and s the residual scatter; with fewer than 4 visits q is normal and s the mean
    per-visit sigma). Searched up to ``horizon_months`` after the last visit on a daily grid.
    Returns (t_cross, t_early, t_late); None where undefined (see module docstring). A line
    so flat that it reaches the threshold more than ``MAX_CROSSING_MONTHS`` after the last
    visit gives no crossing date (as a line not growing; no calendar holds that date), its
    interval as the band gives it.
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    if y[-1] >= threshold_um or not slope > 0:
        return None, None, None
    t_cross = (threshold_um - intercept) / slope
    if not t_cross - t[-1] <= MAX_CROSSING_MONTHS:
        t_cross = None
    grid = t[-1] + np.arange(0.0, horizon_months * DAYS_PER_MONTH + 1.0) / DAYS_PER_MONTH
    _, lo, hi = prediction_band(t, y, sigma_um, grid, alpha)

    def first(mask):
        return float(grid[np.argmax(mask)]) if mask.any() else None

    t_early, t_late = first(hi >= threshold_um), first(lo >= threshold_um)
    return None if t_cross is None else float(max(t_cross, t[-1])), t_early, t_late


def prediction_band(t_month, y_um, sigma_um, at_month, alpha: float = 0.05):
    """OLS line and its 1-alpha prediction band for one future visit at ``at_month`` [um].

    yhat(t) ± q s sqrt(1 + 1/m + (t - t̄)²/Sxx); q Student t with m-2 degrees of freedom and s
    the residual scatter, or, below 4 visits, q normal and s the mean per-visit sigma.
    Returns (fit, low, high).
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    at = np.asarray(at_month, float)
    m = len(t)
    level, slope, s = _line(t, y)
    if m >= 4 and np.isfinite(s):
        q = stats.t.ppf(1 - alpha / 2, m - 2)
    else:
        q, s = stats.norm.ppf(1 - alpha / 2), float(np.mean(sigma_um))
    sxx = float(np.sum((t - t.mean()) ** 2)) or np.inf
    half = q * s * np.sqrt(1 + 1 / m + (at - t.mean()) ** 2 / sxx)
    fit = level + slope * at
    return fit, fit - half, fit + half


# --------------------------------------------------------------------------- forecast intervals
@dataclass(frozen=True)
class ForecastTerms:
    """What a fleet tells each of its series' forecasts (``forecast_terms``).

    ``scatter_um``: the pooled residual scatter [um] of straight lines through the fleet's
    segments between change points, with ``scatter_dof`` degrees of freedom (0: none);
    ``model_error_um``: the standard deviation [um] of the error the line and the scatter do not
    explain, from ``backtests`` one-visit-ahead forecasts (NaN below ``MIN_BACKTESTS``).
    """

    scatter_um: float = float("nan")
    scatter_dof: int = 0
    model_error_um: float = float("nan")
    backtests: int = 0


# Backtests the model error needs: fewer give a mean square too uncertain to add.
MIN_BACKTESTS = 5
# Visits since the last change point a forecast interval needs: three give the first residual,
# the first estimate of the scatter between visits.
MIN_FORECAST_VISITS = 3


def _segments(series) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(t [month], y [um], u [um]) of every segment between change points of every series."""
    out = []
    for s in series:
        v = s.visits
        t, y = v["t_month"].to_numpy(float), v["backlash_um"].to_numpy(float)
        u = v[uncertainty_column(v)].fillna(0.0).to_numpy(float)
        bounds = [0, *[c["index"] for c in s.change_points], len(v)]
        out += [(t[a:b], y[a:b], u[a:b]) for a, b in pairwise(bounds)]
    return out


def _own_scatter(t, y) -> tuple[float, int]:
    """Residual sum of squares [um²] of the OLS line through (t, y) and its m - 2 dof."""
    slope, level = np.polyfit(t, y, 1)
    return float(np.sum((y - level - slope * t) ** 2)), len(t) - 2


def forecast_terms(series) -> ForecastTerms:
    """The fleet's pooled scatter and model error for the forecasts of ``series`` (one unit).

    Scatter: s² = Σ RSS / Σ (m - 2) over every segment between change points with three visits
    or more (the segments' lines are fitted separately, so a step between them is no scatter;
    the pooled within-group variance of a one-way layout). Model error: rolling-origin
    one-visit-ahead backtests inside every segment [Tashman2000], [Hyndman2021] 5.10: visit
    j + 1 forecast from the segment's visits 1..j (j >= 3) with ``forecast_interval``'s
    variance v_j (no model error), e² = max(0, mean(r_j² - v_j)): the method-of-moments
    estimate of the variance the straight line and the scatter leave unexplained (wear that
    bends, a change too small to be found).
    """
    segments = [seg for seg in _segments(series) if len(seg[0]) >= MIN_FORECAST_VISITS
                and np.ptp(seg[0]) > 0]
    rss_dof = [_own_scatter(t, y) for t, y, _ in segments]
    dof = sum(d for _, d in rss_dof)
    scatter = float(np.sqrt(sum(r for r, _ in rss_dof) / dof)) if dof else float("nan")
    excess = []
    for t, y, u in segments:
        for j in range(MIN_FORECAST_VISITS, len(t)):
            f = forecast_interval(t[:j], y[:j], u[:j], t[j], scatter_um=scatter,
                                  scatter_dof=dof)
            if f is not None:
                excess.append((y[j] - f["fit_um"]) ** 2 - f["measurement_var_um2"])
    error = (float(np.sqrt(max(np.mean(excess), 0.0))) if len(excess) >= MIN_BACKTESTS
             else float("nan"))
    return ForecastTerms(scatter, dof, error, len(excess))


def forecast_interval(t_month, y_um, u_um, at_month, *, alpha: float = 0.05,
                      scatter_um: float = float("nan"), scatter_dof: int = 0,
                      model_error_um: float = float("nan"), target_u_um=None,
                      correction_um: float = 0.0, correction_u_um: float = 0.0) -> dict | None:
    """The forecast of a segment's straight line at ``at_month`` with its two intervals.

    Parameters
    ----------
    t_month : times of the visits since the last change point [month]
    y_um : their measured backlash [um]; u_um : its standard uncertainty [um]
        (``backlash_u_um``, the repeatability of each visit's value)
    at_month : float or array, when [month]
    alpha : 1 - the intervals' coverage
    scatter_um, scatter_dof : the fleet's pooled scatter between visits and its dof
        (``forecast_terms``); NaN, 0 for a series alone
    model_error_um : the backtests' model error [um] (``forecast_terms``); NaN: none
    target_u_um : the measured target's own standard uncertainty for the axis's lost motion
        [um] per visit (with a budget ``backlash_U_um`` / k: the parts that do not average out
        over the visit's points); default ``u_um``
    correction_um, correction_u_um : the correction δ of the lost motion to reference
        conditions and its standard uncertainty [um] (``models.condition.reference``): the
        lost-motion interval is centred on ŷ + δ and its variance gains u²(δ); default none

    Returns
    -------
    dict or None
        None with fewer than ``MIN_FORECAST_VISITS`` visits or one date (no scatter can be
        estimated). Else ``fit_um`` (the OLS line), ``measurement_low_um``/``_high_um`` (the
        next laser visit's value), ``lost_motion_low_um``/``_high_um`` (the axis's lost
        motion), ``measurement_var_um2``, ``scatter_um``, ``dof``.

    Notes
    -----
    The line's scatter s² pools the segment's own residuals (m - 2 dof) with the fleet's, the
    fleet weighing at most ``SCATTER_PRIOR_RESIDUALS`` residuals (as ``shrunk_scatter_um``),
    never below the visits' own ū² = mean(u²) (a visit cannot repeat better than its laser
    does). With se² = s²(1/m + (t - t̄)²/Sxx) the variance of the line at t and e the model
    error ([Montgomery2012] 2.4, [Hyndman2021] 5.5):

    - measurement: var = se² + s² + e², the next visit's value scatters about the line by s;
    - lost motion: var = se² + (s² - ū²) + u_T² + e²: the line's own uncertainty (confidence
      band), the part of the scatter that is the axis's (s² - ū², the lost motion itself moving
      from visit to visit) and the measured target's own uncertainty u_T instead of its
      repeatability: the line runs through measured values, so a target that reads low or high
      moves the line with it ([GUM] 6.3, F.2.4.5: an uncorrected bias enters as a standard
      uncertainty). Without a budget u_T = u and the two variances agree: only the budget knows
      more of the target's own error than its repeatability. With a correction to reference
      conditions δ (``models.condition.reference``): ŷ + δ ± t sqrt(var + u²(δ)) ([GUM] 6.3).

    Both are ± t(1 - alpha/2, nu) sqrt(var), nu the dof of s² (Welch-Satterthwaite's count for a
    pooled variance, [GUM] G.4).
    """
    t, y = np.asarray(t_month, float), np.asarray(y_um, float)
    u = np.nan_to_num(np.asarray(u_um, float))
    at = np.asarray(at_month, float)
    m = len(t)
    if m < MIN_FORECAST_VISITS or np.ptp(t) <= 0:
        return None
    rss, nu = _own_scatter(t, y)
    s2 = rss / nu
    if np.isfinite(scatter_um) and scatter_dof > 0:
        prior = min(float(scatter_dof), SCATTER_PRIOR_RESIDUALS)
        s2, nu = (nu * s2 + prior * scatter_um ** 2) / (nu + prior), nu + prior
    u2 = float(np.mean(u ** 2))
    s2 = max(s2, u2)
    target = u if target_u_um is None else np.nan_to_num(np.asarray(target_u_um, float))
    ut2 = float(np.mean(target ** 2))
    e2 = model_error_um ** 2 if np.isfinite(model_error_um) else 0.0
    slope, level = np.polyfit(t, y, 1)
    se2 = s2 * (1 / m + (at - t.mean()) ** 2 / float(np.sum((t - t.mean()) ** 2)))
    q = float(stats.t.ppf(1 - alpha / 2, nu))
    fit = level + slope * at
    meas = np.sqrt(se2 + s2 + e2)
    lost = np.sqrt(se2 + (s2 - u2) + ut2 + e2 + correction_u_um ** 2)
    centre = fit + correction_um
    return {"fit_um": fit, "measurement_low_um": fit - q * meas,
            "measurement_high_um": fit + q * meas, "lost_motion_low_um": centre - q * lost,
            "lost_motion_high_um": centre + q * lost, "measurement_var_um2": se2 + s2 + e2,
            "scatter_um": float(np.sqrt(s2)), "dof": float(nu)}


# --------------------------------------------------------------------------- one series
@dataclass
class DriftSeries:
    """Everything drift knows about one machine axis."""

    machine_id: str
    axis: str
    visits: pd.DataFrame  # visit_backlash rows of this series plus t_month, sigma_um [um]
    change_points: list = field(default_factory=list)
    trend: dict = field(default_factory=dict)
    segment_start: int = 0
    threshold_um: float | None = None
    crossing: tuple = (None, None, None)  # months since the first visit
    alerts: list = field(default_factory=list)
    model: dict | None = None
    alpha: float = 0.05
    # steps no larger than the expanded uncertainty of the difference (with a budget only):
    # {"visit", "kind" ('change_point', 'last_visit' or 'trend'), "jump_um", "U_um"}
    within_uncertainty: list = field(default_factory=list)
    coverage_factor: float | None = None  # k of backlash_U_um; None without a budget
    # the fleet's pooled scatter and backtests' model error (``forecast_terms``); None alone
    terms: ForecastTerms | None = None
    # the lost motion at reference conditions (``models.condition.reference.AxisReference``);
    # None: the lost-motion interval is at the tests' own conditions
    reference: object | None = None

    @property
    def unit(self) -> str:
        """The unit of every ``_um`` value of the series: ``um``, or ``arcsec`` for a rotary
        axis (``features.readings.schema.deviation_unit``)."""
        from features.readings.schema import deviation_unit

        return deviation_unit(self.axis)

    @property
    def last_visit_change(self) -> dict | None:
        """The change point at the last visit (a segment of that visit alone), or None."""
        last = self.change_points[-1] if self.change_points else None
        return last if last is not None and last["index"] == len(self.visits) - 1 else None

    @property
    def origin(self):
        return self.visits["date"].iloc[0]

    def date_at(self, t_month):
        if t_month is None:
            return None
        return (self.origin + pd.Timedelta(days=t_month * DAYS_PER_MONTH)).date().isoformat()

    @property
    def next_visit_month(self) -> float:
        """When the next visit is expected [month]: the last visit plus the median time
        between the series' visits (the pace it has been measured at)."""
        t = self.visits["t_month"].to_numpy(float)
        return float(t[-1] + (np.median(np.diff(t)) if len(t) > 1 else 0.0))

    @property
    def forecast_note(self) -> str | None:
        """Why the series has no forecast interval, or None when it has one."""
        n = len(self.visits) - self.segment_start
        if n >= MIN_FORECAST_VISITS:
            return None
        since = self.visits["visit"].iloc[self.segment_start]
        if n == 1:
            return (f"one visit since visit {since}: no trend, so no forecast interval")
        return (f"two visits since visit {since}: a line through two points leaves no "
                "residual, so the scatter between visits cannot be estimated and no forecast "
                "interval can be stated")

    def lost_motion_reference(self) -> dict | None:
        """The conditions the lost-motion interval states the lost motion at, for a line through
        the visits since the last change point (``models.condition.reference``):
        ``AxisReference.correction`` with ``conditions`` {"temp_c", "feed_mm_min"} (the
        reference value of a corrected condition, else the tests' mean) and ``note`` (None when
        both are at reference). None without a reference or a forecast."""
        if self.reference is None or self.forecast_note is not None:
            return None
        c = self.reference.correction(self.visits["visit"].iloc[self.segment_start:]
                                      .astype(str))
        own = c["tests_mean"]
        at = {"temp_c": 20.0 if "machine_temp_c" in c["corrected"] else own["machine_temp_c"],
              "feed_mm_min": (self.reference.reference["feed_mm_min"]
                              if "feed_mm_min" in c["corrected"] else own["feed_mm_min"])}
        missing = [n for n, k in (("temperature", "machine_temp_c"), ("feed", "feed_mm_min"))
                   if k not in c["corrected"]]
        note = None if not missing else (
            f"the lost motion is stated at the tests' own {' and '.join(missing)}: "
            + ("a visit since the last change has no laser test conditions"
               if c.get("reason") == "visits" else
               "the data cannot estimate its sensitivity (one feed, too small a temperature "
               "span, or feed and temperature collinear), so it is not corrected"))
        return {**c, "conditions": at, "note": note}

    def forecast_at(self, at_month) -> dict | None:
        """``forecast_interval`` of the visits since the last change point at ``at_month``
        [month], with the fleet's ``terms``; with a budget the target's own uncertainty is
        ``backlash_U_um`` / k; with a ``reference`` the lost motion at reference conditions
        (``lost_motion_reference``). None where ``forecast_note`` says why."""
        if self.forecast_note is not None:
            return None
        ref = self.lost_motion_reference() or {"correction_um": 0.0, "correction_u_um": 0.0}
        seg = self.visits.iloc[self.segment_start:]
        terms = self.terms or ForecastTerms()
        target = (seg["backlash_U_um"].to_numpy(float) / self.coverage_factor
                  if self.coverage_factor is not None and "backlash_U_um" in seg else None)
        return forecast_interval(seg["t_month"].to_numpy(float), seg["backlash_um"].to_numpy(float),
                                 seg[uncertainty_column(seg)].to_numpy(float), at_month,
                                 alpha=self.alpha, scatter_um=terms.scatter_um,
                                 scatter_dof=terms.scatter_dof,
                                 model_error_um=terms.model_error_um, target_u_um=target,
                                 correction_um=ref["correction_um"],
                                 correction_u_um=ref["correction_u_um"])

    def forecast_json(self) -> dict:
        """The forecast of the next visit as the JSON of ``drift`` and ``fleet`` carry it."""
        f = self.forecast_at(self.next_visit_month)
        terms = self.terms or ForecastTerms()

        def r(key):
            return None if f is None else round(float(f[key]), 4)

        ref = None if f is None else self.lost_motion_reference()

        return {"forecast_date": None if f is None else self.date_at(self.next_visit_month),
                "forecast_um": r("fit_um"),
                "forecast_measurement_low_um": r("measurement_low_um"),
                "forecast_measurement_high_um": r("measurement_high_um"),
                "forecast_lost_motion_low_um": r("lost_motion_low_um"),
                "forecast_lost_motion_high_um": r("lost_motion_high_um"),
                "forecast_model_error_um": (round(terms.model_error_um, 4)
                                            if np.isfinite(terms.model_error_um) else None),
                "forecast_backtests": terms.backtests,
                "forecast_note": self.forecast_note,
                "forecast_lost_motion_reference": None if ref is None else {
                    **{k: (None if v is None else round(float(v), 4))
                       for k, v in ref["conditions"].items()},
                    "correction_um": round(ref["correction_um"], 4),
                    "correction_u_um": round(ref["correction_u_um"], 4)},
                "forecast_lost_motion_note": None if ref is None else ref["note"]}

    def forecast_curve(self, end_month: float,
                       steps: int = DEFAULTS.forecast_steps) -> dict | None:
        """The forecast from the last visit to ``end_month`` [month]: ``t_month``, ``fit``,
        ``measurement_low``/``_high`` and ``lost_motion_low``/``_high`` [um]; None without
        an interval."""
        t_last = float(self.visits["t_month"].iloc[-1])
        ahead = np.linspace(t_last, max(end_month, t_last), steps)
        f = self.forecast_at(ahead)
        if f is None:
            return None
        return {"t_month": ahead, "fit": f["fit_um"], "measurement_low": f["measurement_low_um"],
                "measurement_high": f["measurement_high_um"],
                "lost_motion_low": f["lost_motion_low_um"],
                "lost_motion_high": f["lost_motion_high_um"]}

    def to_dict(self, forecast: dict | None = None) -> dict:
        """The series as ``drift --json`` carries it; ``forecast`` the forecast of the next
        visit when computed already (``forecast_json``)."""
        v = self.visits
        return {
            "machine_id": self.machine_id, "axis": self.axis, "unit": self.unit,
            "visits": v["visit"].astype(str).tolist(),
            "dates": [d.isoformat() for d in v["date"]],
            "backlash_um": v["backlash_um"].round(4).tolist(),
            "backlash_u_um": v[uncertainty_column(v)].round(4).tolist(),
            "sigma_um": v["sigma_um"].round(4).tolist(),
            **{k: (v[k].round(4) if v[k].dtype.kind == "f" else v[k]).tolist()
               for k in OPTIONAL_JSON if k in v},
            "slope_um_per_month": self.trend.get("slope"),
            "slope_interval": [self.trend.get("low"), self.trend.get("high")],
            "mann_kendall_p": self.trend.get("p_value"),
            "change_points": [str(v["visit"].iloc[c["index"]]) for c in self.change_points],
            "change_jumps_um": [round(c["jump_um"], 4) for c in self.change_points],
            "threshold_um": self.threshold_um,
            "threshold_crossing": self.date_at(self.crossing[0]),
            "crossing_interval": [self.date_at(self.crossing[1]), self.date_at(self.crossing[2])],
            "alerts": self.alerts,
            **(self.forecast_json() if forecast is None else forecast),
            **(self._uncertainty_json() if self.coverage_factor is not None else {}),
            **({"model": self.model} if self.model is not None else {}),
        }

    def _uncertainty_json(self) -> dict:
        """The budget's keys: per-visit ``backlash_U_um``, the U(Δ) of each change point
        (``change_U_um``) and the steps ``within_uncertainty`` [um]."""
        v = self.visits
        return {"coverage_factor": self.coverage_factor,
                "backlash_U_um": v["backlash_U_um"].round(4).tolist(),
                "change_U_um": [round(step_uncertainty_um(v, c["index"], self.coverage_factor),
                                      4) for c in self.change_points],
                "within_uncertainty": [{**w, "jump_um": round(w["jump_um"], 4),
                                        "U_um": round(w["U_um"], 4)}
                                       for w in self.within_uncertainty]}


def analyse_series(visits: pd.DataFrame, *, threshold_um: float | None = None,
                   alpha: float = DEFAULTS.alpha, min_jump_sigma: float = DEFAULTS.min_jump_sigma,
                   penalty: float | None = None, warn_months: float = DEFAULTS.warn_months,
                   horizon_months: float = DEFAULTS.crossing_horizon_months,
                   coverage_factor: float | None = None,
                   fleet_scatter: float | None = None) -> DriftSeries:
    """Change points, trend since the last one, threshold forecast and alerts of one series.

    ``fleet_scatter``: the pooled scatter [um] of the fleet the series belongs to
    (``fleet_scatter_um``), which its own is shrunk toward (module docstring).

    ``visits`` holds one machine axis: ``visit``, ``date``, ``backlash_um`` [um] and its
    standard uncertainty ``backlash_u_um`` [um] (``u_um``, the name before, is read too).
    With ``coverage_factor`` k (a budget was given) it also holds ``backlash_U_um`` and
    ``backlash_u_visit_um`` [um], and steps within U(Δ) do not alert (module docstring).
    """
    v = visits.sort_values("date", kind="stable").reset_index(drop=True).copy()
    v["t_month"] = months_between(v["date"], v["date"].iloc[0])
    t, y = v["t_month"].to_numpy(), v["backlash_um"].to_numpy(float)
    # Below 5 second differences the MAD is dominated by a single step; trust u alone there.
    scatter = scatter_sigma_um(t, y) if len(y) >= MIN_VISITS_FOR_SCATTER else float("nan")
    scatter = shrunk_scatter_um(scatter, len(y), fleet_scatter)
    u = v[uncertainty_column(v)].fillna(0.0).to_numpy(float)
    floor = np.nanmax([scatter, np.nanmedian(u) if np.isfinite(u).any() else 0.0, 1e-3])
    v["sigma_um"] = np.fmax(u, floor)
    sigma = v["sigma_um"].to_numpy()

    cps = change_points(t, y, sigma, penalty=penalty, min_jump_sigma=min_jump_sigma)
    within = []
    if coverage_factor is not None:
        cps, within = resolved_changes(t, y, sigma, v, cps, coverage_factor)
    start = cps[-1]["index"] if cps else 0
    result = DriftSeries(str(v["machine_id"].iloc[0]), str(v["axis"].iloc[0]), v, cps,
                         trend(t[start:], y[start:], alpha), start, threshold_um, alpha=alpha,
                         within_uncertainty=within, coverage_factor=coverage_factor)
    if threshold_um is not None:
        result.crossing = crossing_forecast(
            t[start:], y[start:], sigma[start:], threshold_um, slope=result.trend["slope"],
            intercept=result.trend["intercept"], alpha=alpha, horizon_months=horizon_months)
    result.alerts = series_alerts(result, alpha=alpha, min_jump_sigma=min_jump_sigma,
                                  warn_months=warn_months)
    return result


def step_uncertainty_um(visits: pd.DataFrame, index: int, k: float,
                        before: int | None = None) -> float:
    """Expanded uncertainty U(Δ) [um] of the change between visit ``before`` (default
    ``index - 1``) and visit ``index``.

    .. math:: U(\\Delta) = k \\sqrt{u_{v,b}^2 + u_{v,i}^2}

    with u_v = ``backlash_u_visit_um``, the standard uncertainty of the parts of each visit's
    value that change from visit to visit; the systematic part common to both cancels in the
    difference ([GUM] 5.2.2, r = +1).
    """
    u = visits["backlash_u_visit_um"].to_numpy(float)
    return float(k * np.hypot(u[index - 1 if before is None else before], u[index]))


def resolved_changes(t, y, sigma, visits, cps, k):
    """Split change points into those larger than U(Δ) and those within it.

    The change points within U(Δ) are removed one at a time, smallest ratio first, and the
    jumps of the rest re-estimated on the merged segments (as ``change_points`` does with
    weak ones). Returns (kept, within); ``within`` as ``DriftSeries.within_uncertainty``.
    """
    within = []
    while cps:
        ratios = [abs(c["jump_um"]) / step_uncertainty_um(visits, c["index"], k) for c in cps]
        i = int(np.argmin(ratios))
        if ratios[i] > 1.0:
            break
        c = cps[i]
        within.append({"visit": str(visits["visit"].iloc[c["index"]]), "kind": "change_point",
                       "jump_um": c["jump_um"],
                       "U_um": step_uncertainty_um(visits, c["index"], k)})
        cps = _jumps(t, y, sigma, [x["index"] for x in cps if x is not c])
    return cps, sorted(within, key=lambda w: w["visit"])


def series_alerts(s: DriftSeries, *, alpha: float, min_jump_sigma: float,
                  warn_months: float) -> list[dict]:
    """The alerts of one analysed series (kinds listed in the module docstring)."""
    v, tr, alerts = s.visits, s.trend, []
    last_y, last_t = float(v["backlash_um"].iloc[-1]), float(v["t_month"].iloc[-1])
    last_visit = str(v["visit"].iloc[-1])
    if s.threshold_um is not None:
        if last_y >= s.threshold_um:
            alerts.append(_alert("above_threshold", f"backlash {last_y:.2f} {s.unit} at visit "
                                 f"{last_visit} is at or above the threshold "
                                 f"{s.threshold_um:g} {s.unit}"))
        elif s.crossing[1] is not None and s.crossing[1] - last_t <= warn_months:
            alerts.append(_alert("crossing_soon", f"backlash may reach {s.threshold_um:g} {s.unit} "
                                 f"from {s.date_at(s.crossing[1])} (within {warn_months:g} "
                                 "months of the last visit)"))
    elif tr["p_value"] < alpha and tr["low"] > 0 and not _trend_within(s):
        alerts.append(_alert("increasing_trend", f"backlash grows by {tr['slope']:.3f} {s.unit}/month "
                             f"[{tr['low']:.3f}, {tr['high']:.3f}] since visit "
                             f"{v['visit'].iloc[s.segment_start]} (Mann-Kendall p = "
                             f"{tr['p_value']:.2g})"))
    if s.last_visit_change is not None:
        alerts.append(_last_visit_alert(s))
    elif s.change_points and s.change_points[-1]["jump_um"] > 0:
        c = s.change_points[-1]
        alerts.append(_alert("level_jump", f"backlash stepped up by {c['jump_um']:.2f} {s.unit} "
                             f"({c['jump_sigma']:.1f} sigma) at visit {v['visit'].iloc[c['index']]}"
                             ": failure or loosened preload suspected"))
    jump = _last_visit_jump(s)
    if jump is not None and jump > min_jump_sigma and not _last_within(s):
        alerts.append(_alert("last_visit_jump", f"visit {last_visit} lies {jump:.1f} sigma above "
                             "the trend of the visits before it (unconfirmed change)"))
    return alerts


def limit_passed_alert(s: DriftSeries, as_of) -> dict | None:
    """``limit_passed_unmeasured`` when the crossing date of ``s`` lies before the day
    ``as_of`` (a ``datetime.date``): no visit measured it, but the trend says the axis has
    probably passed its limit since its last visit; None otherwise."""
    if s.crossing[0] is None:
        return None
    when = s.date_at(s.crossing[0])
    days = (as_of - pd.Timestamp(when).date()).days
    if days <= 0:
        return None
    return _alert("limit_passed_unmeasured", f"the trend reached the limit {s.threshold_um:g} "
                  f"{s.unit} on {when}, {days} days before {as_of.isoformat()}, after the last "
                  f"visit ({s.visits['date'].iloc[-1].date().isoformat()}): probably past its "
                  "limit, unmeasured")


def _last_visit_alert(s: DriftSeries) -> dict:
    """``last_visit_drop`` or ``last_visit_jump``: the change point at the last visit, with
    how far the lost motion moved from the visit before it."""
    v, c = s.visits, s.last_visit_change
    step = float(v["backlash_um"].iloc[-1] - v["backlash_um"].iloc[-2])
    visit, sigma = v["visit"].iloc[-1], abs(c["jump_sigma"])
    if c["jump_um"] < 0:
        return _alert("last_visit_drop", f"lost motion fell by {-step:.2f} {s.unit} at visit {visit} "
                      f"({sigma:.1f} sigma below the trend before it): an adjustment or repair? "
                      "The trend restarts there")
    return _alert("last_visit_jump", f"lost motion rose by {step:.2f} {s.unit} at visit {visit} "
                  f"({sigma:.1f} sigma above the trend before it): failure or loosened preload "
                  "suspected; the next visit confirms it")


def _last_visit_jump(s: DriftSeries) -> float | None:
    """How many standard errors the last visit lies above the line through its segment's
    earlier visits: se² = sigma² of the last visit + the variance of the line there (a line
    through two visits extrapolates with much of their scatter)."""
    v = s.visits.iloc[s.segment_start:]
    if len(v) < 3:
        return None
    t, y = v["t_month"].to_numpy(), v["backlash_um"].to_numpy(float)
    sigma = v["sigma_um"].to_numpy(float)
    level, slope, _ = _line(t[:-1], y[:-1])
    se = np.sqrt(sigma[-1] ** 2 + _fit_var(t[:-1], sigma[:-1], t[-1]))
    return float((y[-1] - level - slope * t[-1]) / se)


def _trend_within(s: DriftSeries) -> bool:
    """With a budget: whether the rise of the trend line over its segment is within U(Δ) of
    the segment's first and last visits (then listed in ``within_uncertainty``)."""
    if s.coverage_factor is None:
        return False
    t = s.visits["t_month"].to_numpy(float)
    first, last = s.segment_start, len(t) - 1
    rise = float(s.trend["slope"] * (t[last] - t[first]))
    u_rise = step_uncertainty_um(s.visits, last, s.coverage_factor, before=first)
    if abs(rise) > u_rise:
        return False
    s.within_uncertainty.append({"visit": str(s.visits["visit"].iloc[last]), "kind": "trend",
                                 "jump_um": rise, "U_um": u_rise})
    return True


def _last_within(s: DriftSeries) -> bool:
    """With a budget: whether the last visit's departure from the trend of the visits before it
    is within U(Δ) of the last two visits (then listed in ``within_uncertainty``)."""
    if s.coverage_factor is None:
        return False
    v = s.visits.iloc[s.segment_start:]
    t, y = v["t_month"].to_numpy(), v["backlash_um"].to_numpy(float)
    level, slope, _ = _line(t[:-1], y[:-1])
    step = float(y[-1] - level - slope * t[-1])
    u_step = step_uncertainty_um(s.visits, len(s.visits) - 1, s.coverage_factor)
    if abs(step) > u_step:
        return False
    s.within_uncertainty.append({"visit": str(v["visit"].iloc[-1]), "kind": "last_visit",
                                 "jump_um": step, "U_um": u_step})
    return True


def _alert(kind: str, message: str) -> dict:
    return {"kind": kind, "message": message}


def analyse_visits(visits: pd.DataFrame, *, min_visits: int = 2,
                   threshold_um: float | None = None, threshold_arcsec: float | None = None,
                   limits: dict | None = None, reference: dict | None = None,
                   **options) -> list[DriftSeries]:
    """``analyse_series`` of every machine axis in ``visits`` (``visit_backlash`` rows) with
    ``min_visits`` or more, in (machine_id, axis) order, each with its fleet's pooled scatter
    (``fleet_scatter_um``), its limit in its own unit (``limit_of``) and the terms of its
    forecast intervals from the series of its unit (``forecast_terms``: the pooled scatter of
    their segments and the model error of their backtests). ``reference``: {(machine_id,
    axis): AxisReference} (``models.condition.reference.reference_corrections``): the
    lost-motion intervals state the lost motion at reference conditions."""
    from features.readings.schema import deviation_unit

    fleet = fleet_scatter_um(visits)
    series = [analyse_series(group, fleet_scatter=fleet.get(deviation_unit(axis)),
                             threshold_um=limit_of(str(machine), str(axis), threshold_um,
                                                   threshold_arcsec, limits), **options)
              for (machine, axis), group in visits.groupby(list(SERIES_KEYS), sort=True,
                                                           observed=True)
              if len(group) >= min_visits]
    # the forecasts' scatter and model error are the fleet's, per unit (never um with arcsec)
    for unit in {s.unit for s in series}:
        mine = [s for s in series if s.unit == unit]
        terms = forecast_terms(mine)
        for s in mine:
            s.terms = terms
    for s in series:
        s.reference = (reference or {}).get((s.machine_id, s.axis))
    return series


def limit_of(machine: str, axis: str, threshold_um: float | None = None,
             threshold_arcsec: float | None = None, limits: dict | None = None) -> float | None:
    """The limit of one machine axis in its own unit: its entry in ``limits`` ({(machine,
    axis): limit}), else ``threshold_arcsec`` [arcsec] for a rotary axis and ``threshold_um``
    [um] for a linear one; a limit is never compared with a value in another unit."""
    from features.readings.schema import is_rotary

    own = (limits or {}).get((machine, axis))
    if own is not None:
        return own
    return threshold_arcsec if is_rotary(axis) else threshold_um


def two_visit_notes(series: list[DriftSeries]) -> list[str]:
    """One note per series whose trend comes from two visits: its interval and a forecast
    interval cannot be estimated."""
    return [f"{s.machine_id} axis {s.axis}: the trend since visit "
            f"{s.visits['visit'].iloc[s.segment_start]} comes from two visits; its interval "
            "cannot be estimated, nor a forecast interval (two visits leave no residual to "
            "estimate the scatter between visits from)"
            for s in series if len(s.visits) - s.segment_start == 2]


# --------------------------------------------------------------------------- model alerts
def attach_model(series: list[DriftSeries], monitoring: pd.DataFrame) -> None:
    """Add per-visit model figures (``models.condition.monitoring.monitor_model``) to each series and
    alert on its latest visit."""
    for s in series:
        mine = monitoring[(monitoring["machine_id"].astype(str) == s.machine_id)
                          & (monitoring["axis"].astype(str) == s.axis)]
        order = {v: i for i, v in enumerate(s.visits["visit"].astype(str))}
        mine = mine.assign(_o=mine["visit"].astype(str).map(order)).sort_values("_o")
        if mine.empty:
            continue
        last = mine.iloc[-1]
        s.model = {
            "visits": mine["visit"].astype(str).tolist(),
            "rmse_um": mine["rmse_um"].round(4).tolist(),
            "band_um": mine["band_um"].round(4).tolist(),
            "bias_um": mine["bias_um"].round(4).tolist(),
            "retrain": bool(last["retrain"]),
            "out_of_range": list(last["out_of_range"]),
            "ks_p": {k: round(v, 6) for k, v in last["ks_p"].items()},
            "drifted_inputs": list(last["drifted"]),
        }
        visit = last["visit"]
        if last["retrain"]:
            s.alerts.append(_alert("retrain", f"model RMSE {last['rmse_um']:.2f} um at visit "
                                   f"{visit} leaves the validation band "
                                   f"{last['band_um']:.2f} um: retrain"))
        if last["out_of_range"]:
            s.alerts.append(_alert("input_out_of_range", f"visit {visit}: "
                                   f"{', '.join(last['out_of_range'])} outside the training "
                                   "range"))
        if last["drifted"]:
            s.alerts.append(_alert("input_drift", f"visit {visit}: "
                                   f"{', '.join(last['drifted'])} distributed unlike the "
                                   "training inputs (Kolmogorov-Smirnov)"))
