"""The condition of a machine axis across maintenance visits, for ``drift`` and ``fleet``:

- ``settings``: the settings both share (limits, significance, change-point and forecast
  horizons) with their defaults, defined once (light: no numeric library);
- ``maintenance``: the per-axis analysis, computed once per axis on one time axis (UTC
  datetimes): the visit series, robust trend, change points, forecast bands, threshold
  crossing and the expected next visit (``AxisForecast``);
- ``schedule``: the scheduling policy of a fleet: when an axis is next due, the fleet's wear
  rate an axis without a trend is planned with, the day a forecast for operating hours is for,
  overdue visits and the order worst first;

and what the condition is read from: ``drift`` (change points, robust trend, threshold
forecast of a visit series), ``backtest`` (rolling-origin backtests of a forecast),
``lost_motion`` and ``lost_motion_stream`` (lost motion from dual-feedback controller traces),
``evidence`` (trace and ballbar evidence beside the laser visits), ``monitoring`` (a trained
predictor's residuals and input drift).
"""
