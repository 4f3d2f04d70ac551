"""The settings of the maintenance analysis that ``drift`` and ``fleet`` share, with their
defaults, defined once.

This module is light (no numeric library at import): the workflows' signatures take their
defaults from ``DEFAULTS`` and ``pipeline.workflows.<job>`` is imported to show ``--help``.
"""

from __future__ import annotations

from dataclasses import dataclass

# The maintenance interval a fleet is planned with when none is given [d].
DEFAULT_INTERVAL_DAYS = 90.0


@dataclass(frozen=True)
class MaintenanceSettings:
    """What the per-axis maintenance analysis (``models.condition.maintenance``) is told.

    Every value, limit and interval is in the axis's own unit: um for a linear axis, arcsec
    for a rotary one (``features.readings.schema.deviation_unit``); a limit is never compared
    with a value in another unit (``models.condition.drift.limit_of``).

    Attributes
    ----------
    threshold_um : float or None, default None
        Backlash limit of the linear axes [um]: the date each crosses it is forecast.
    threshold_arcsec : float or None, default None
        Backlash limit of the rotary axes [arcsec].
    limits : dict or None, default None
        Limits per machine axis, ``{(machine_id, axis): limit}`` each in its axis's unit
        (``pipeline.steps.limits.read_limits``); an axis without one takes the threshold of
        its unit.
    alpha : float, default 0.05
        Significance level of the trend tests and 1 - the coverage of every interval (the
        slope's, the crossing's, the forecast's), in (0, 0.5).
    min_jump_sigma : float, default 3.0
        A change point must move the level by more than this many standard errors of the two
        segment lines there (``models.condition.drift.change_points``).
    warn_months : float, default 6.0
        Alert ``crossing_soon`` when the early end of the crossing interval lies within this
        many months [month of 30.4375 d] of the last visit.
    crossing_horizon_months : float, default 120.0
        How far past the last visit [month] the prediction band is searched for the crossing
        (``models.condition.drift.crossing_forecast``): a late end beyond it is null.
    interval_days : float or None, default None
        The maintenance interval [d] of a schedule (``fleet``): the next visit is due this long
        after the last one at the latest, and the forecast is computed one interval ahead, up
        to the crossing date, at most ``forecast_cap_months`` past the last visit. None: no
        schedule (``drift``), the forecast reaches the expected next visit or the end of the
        crossing interval (``models.condition.maintenance.horizon_month``).
    forecast_cap_months : float, default 24.0
        With a maintenance interval: the forecast never reaches further than this past the
        last visit [month].
    forecast_steps : int, default 40
        Points of the forecast band, evenly spaced from the last visit to the horizon.
    """

    threshold_um: float | None = None
    threshold_arcsec: float | None = None
    limits: dict | None = None
    alpha: float = 0.05
    min_jump_sigma: float = 3.0
    warn_months: float = 6.0
    crossing_horizon_months: float = 120.0
    interval_days: float | None = None
    forecast_cap_months: float = 24.0
    forecast_steps: int = 40

    def limits_of(self) -> dict:
        """The keywords of the limits (``models.condition.drift.analyse_visits``): ``threshold_um``,
        ``threshold_arcsec``, ``limits``."""
        return {"threshold_um": self.threshold_um, "threshold_arcsec": self.threshold_arcsec,
                "limits": self.limits}

    def trend_options(self) -> dict:
        """The keywords of the trend analysis of one series (``models.condition.drift.analyse_series``):
        ``alpha``, ``min_jump_sigma``, ``warn_months``, ``horizon_months``."""
        return {"alpha": self.alpha, "min_jump_sigma": self.min_jump_sigma,
                "warn_months": self.warn_months,
                "horizon_months": self.crossing_horizon_months}


DEFAULTS = MaintenanceSettings()
