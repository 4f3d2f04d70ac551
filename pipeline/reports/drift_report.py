"""Drift report: one PNG panel per machine axis and an HTML page beside it.

Files written to the output folder (the page refers to the image by relative name, so the
folder can be moved or logged to MLflow as is): ``drift.png``, ``drift.html``, ``drift.json``.
Each panel shows the axis's backlash at each visit (``features.visits.visit_backlash``:
``backlash_um``, its lost motion by the axis's measuring system) with its ±2 sigma bars (and,
with an uncertainty budget, a band of ± its expanded uncertainty ``backlash_U_um``), the
Theil-Sen trend since the last change point, the change points (dashed), the threshold, the crossing
interval and the forecast interval of the next measurement; the page's table gives both
intervals of the next visit: the measurement's and the axis's lost motion's.

The report draws, it computes nothing: every line, band and date comes from the maintenance
analysis of each axis (``models.condition.maintenance.AxisForecast``: trend line, band and
crossing over the horizon it computed, the next visit's forecast), on its one time axis.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import fileio
from models.condition.drift import WITHIN_KINDS
from pipeline.reports.fleet_charts import unit_label
from pipeline.reports.report_page import new_figure, save_figure, write_page

FILES = {"png": "drift.png", "html": "drift.html", "json": "drift.json"}


def write_drift_report(forecasts, out_dir, *, source: str = "", notes=(),
                       as_of: str | None = None) -> dict:
    """Write PNG, HTML and JSON of the analysed axes (``models.condition.maintenance``'s
    ``AxisForecast``: the series and what the analysis computed of it)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / name for k, name in FILES.items()}
    plot_series(forecasts, paths["png"])
    write_page(paths["html"], TITLE, render_body(forecasts, source=source, notes=notes,
                                                 as_of=as_of))
    fileio.write_json(paths["json"], fileio.clean_nan(
        {"source": source, "as_of": as_of, "series": [f.to_dict() for f in forecasts]}))
    return paths


def plot_series(forecasts, path) -> None:
    """One panel per axis: visits, trend, change points, threshold and forecast band."""
    # Fixed margins draw the figure once (constrained layout draws it twice), and one legend
    # serves every panel: text is most of a fleet's drawing time.
    fig, axes = new_figure(8, 3.2 * len(forecasts), nrows=len(forecasts), ncols=1,
                           squeeze=False, fixed_margins=True, gridspec_kw={"hspace": 0.55})
    for i, (ax, f) in enumerate(zip(axes[:, 0], forecasts)):
        _panel(ax, f)
        if i == 0:
            ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, path)


def _naive(times):
    """UTC times as matplotlib draws them (without a time zone)."""
    return pd.DatetimeIndex(pd.to_datetime(times, utc=True)).tz_localize(None)


def _panel(ax, f) -> None:
    s, v = f.series, f.series.visits
    if "backlash_U_um" in v:  # a budget was given: the expanded uncertainty of each visit
        ax.fill_between(_naive(v["date"]), v["backlash_um"] - v["backlash_U_um"],
                        v["backlash_um"] + v["backlash_U_um"], color="C0", alpha=0.12, lw=0,
                        label=f"± U, measurement uncertainty (k = {s.coverage_factor:g})")
    laser = v[v["source"] == "laser"] if "source" in v else v
    ax.errorbar(_naive(laser["date"]), laser["backlash_um"], yerr=2 * laser["sigma_um"],
                fmt="o", ms=4, capsize=2, color="C0",
                label=f"backlash per visit, {_kinds(laser)} (±2σ)")
    for source, (marker, colour) in EVIDENCE_MARKERS.items():  # drift --evidence
        mine = v[v["source"] == source] if "source" in v else v.iloc[:0]
        if len(mine):
            ax.errorbar(_naive(mine["date"]), mine["backlash_um"], yerr=2 * mine["sigma_um"],
                        fmt=marker, ms=4, mfc="none", capsize=2, color=colour,
                        label=f"{source}, shifted by its offset to the laser (±2σ)")
    tr = s.trend
    if f.trend_line is not None:
        ax.plot(_naive(f.trend_line["at"]), f.trend_line["fit_um"], color="C1",
                label="Theil-Sen trend since the last change point")
    if f.band is not None:  # the next measurement's interval (models.condition.drift)
        ax.fill_between(_naive(f.band["at"]), f.band["measurement_low_um"],
                        f.band["measurement_high_um"], color="C1", alpha=0.2, lw=0,
                        label=f"{100 * (1 - s.alpha):g} % forecast of the next measurement")
    for when in _naive(f.change_dates):
        ax.axvline(when, ls="--", color="0.4", lw=1)
    unit = unit_label(s.unit)
    if s.threshold_um is not None:
        ax.axhline(s.threshold_um, color="C3", lw=1, label=f"threshold {s.threshold_um:g} {unit}")
        _, early, late = f.crossing
        if early is not None:
            late = max(late if late is not None else f.horizon_end, early)
            ax.axvspan(*_naive([early, late]), color="C3", alpha=0.15,
                       label="crossing interval")
    slope = tr.get("slope", np.nan)
    ax.set_title(f"{s.machine_id} axis {s.axis}"
                 + (f", trend {slope:+.3f} {unit}/month" if np.isfinite(slope) else "")
                 + (" — ALERT" if s.alerts else ""), fontsize=10)
    ax.set_ylabel(f"backlash [{unit}]")
    ax.tick_params(axis="x", labelrotation=20, labelsize=8)


TITLE = "Backlash drift across visits"
# The other sources of a series (``drift --evidence``): matplotlib marker and colour.
EVIDENCE_MARKERS = {"trace": ("s", "C2"), "ballbar": ("D", "C4")}
KIND_NAMES = {"paper": "pendulum − linear", "iso": "ISO |B_i|", "mixed": "mixed"}


def _kinds(visits) -> str:
    """Which definition the series' values use: 'pendulum − linear', 'ISO |B_i|' or both."""
    if "target_kind" not in visits:
        return "lost motion"
    return " / ".join(KIND_NAMES.get(k, k) for k in dict.fromkeys(visits["target_kind"]))


def _fmt(value, fmt=".3g") -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    return format(value, fmt) if isinstance(value, (int, float)) else html.escape(str(value))


def _interval(j: dict) -> str:
    """The slope's interval, or why there is none (a trend from two visits)."""
    low, high = j["slope_interval"]
    if j["slope_um_per_month"] is None or not np.isfinite(j["slope_um_per_month"]):
        return ""
    if not (np.isfinite(low) and np.isfinite(high)):
        return "(interval cannot be estimated from two visits)"
    return f"[{_fmt(low)}, {_fmt(high)}]"


def _forecast_cells(j: dict) -> str:
    """The next visit's date and the forecast's two intervals, or why there are none."""
    if j["forecast_date"] is None:
        return f"<td colspan='3'>{html.escape(j['forecast_note'] or '–')}</td>"
    return (f"<td>{_fmt(j['forecast_date'])}</td>"
            f"<td>{_fmt(j['forecast_um'])} [{_fmt(j['forecast_measurement_low_um'])}, "
            f"{_fmt(j['forecast_measurement_high_um'])}]</td>"
            f"<td>[{_fmt(j['forecast_lost_motion_low_um'])}, "
            f"{_fmt(j['forecast_lost_motion_high_um'])}]</td>")


def _visit_row(r: dict) -> str:
    """One visit of a series as a table row (columns a hand-built series lacks show –)."""
    def num(key, fmt=".3f"):
        value = r.get(key)  # counts turn float beside another source's points (no count)
        whole = fmt == "d" and isinstance(value, float) and np.isfinite(value)
        return _fmt(int(value) if whole else value, fmt)

    u = r.get("backlash_u_um", r.get("u_um"))
    cells = (num("n_tests", "d"), num("n_points", "d"),
             html.escape(KIND_NAMES.get(r.get("target_kind"), r.get("source") or "–")),
             num("backlash_um"),
             _fmt(u, ".3f"), *((num("backlash_U_um"),) if "backlash_U_um" in r else ()),
             num("sigma_um"), num("reversal_mean_um"), num("reversal_max_um"))
    return (f"<tr><td>{html.escape(str(r['visit']))}</td><td>{r['date'].date().isoformat()}</td>"
            + "".join(f"<td class='num'>{c}</td>" for c in cells) + "</tr>")


def _uncertainty_text(series) -> str:
    """What U means, when a budget was given (else nothing); ``series`` the analysed
    ``models.condition.drift.DriftSeries``."""
    k = next((s.coverage_factor for s in series if s.coverage_factor is not None), None)
    if k is None:
        return ""
    return (f"<p>U: the expanded measurement uncertainty (k = {k:g}) of each visit's backlash, "
            "the budget's U(B) (ISO/TR 230-9) combined with the repeatability u(backlash); "
            "shown as a band in the figure. A step between visits counts only when it exceeds "
            "the expanded uncertainty of the difference U(Δ), which leaves out the setup's "
            "systematic part common to every visit; smaller steps are listed as within the "
            "measurement uncertainty.</p>")


def render_body(forecasts, *, source: str = "", notes=(), as_of: str | None = None) -> str:
    """The report body: a summary table, the figure, and per-series visit tables."""
    series = [f.series for f in forecasts]
    rows = []
    for f, s in zip(forecasts, series):
        j = f.to_dict()
        rows.append(
            f"<tr><td>{html.escape(s.machine_id)}</td><td>{html.escape(s.axis)}</td>"
            f"<td>{unit_label(s.unit)}</td>"
            f"<td>{len(j['visits'])}</td><td>{_fmt(j['backlash_um'][-1])}</td>"
            f"<td>{_fmt(j['slope_um_per_month'])} {_interval(j)}</td>"
            f"<td>{html.escape(', '.join(j['change_points']) or '–')}</td>"
            f"<td>{_fmt(j['threshold_crossing'])} [{_fmt(j['crossing_interval'][0])}, "
            f"{_fmt(j['crossing_interval'][1])}]</td>{_forecast_cells(j)}"
            f"<td>{html.escape('; '.join(a['kind'] for a in s.alerts) or '–')}</td></tr>")
    details = []
    for s in series:
        v, unit = s.visits, unit_label(s.unit)
        body = "".join(_visit_row(r) for r in v.to_dict("records"))
        items = "".join(f"<li>{html.escape(a['kind'])}: {html.escape(a['message'])}</li>"
                        for a in s.alerts)
        alerts = f"<div class='alert'><ul>{items}</ul></div>" if items else "<p>No alert.</p>"
        within = "".join(
            f"<li>{html.escape(WITHIN_KINDS[w['kind']])} of {w['jump_um']:+.3f} {unit} at visit "
            f"{html.escape(w['visit'])}: within the measurement "
            f"uncertainty U(Δ) = {w['U_um']:.3f} {unit}, not an alert</li>"
            for w in s.within_uncertainty)
        if within:
            alerts += f"<ul>{within}</ul>"
        big_u = f"<th>U [{unit}]</th>" if "backlash_U_um" in v else ""
        model = ""
        if s.model:
            m = s.model
            model = (f"<p>Model residual RMSE per visit [{unit}]: "
                     f"{html.escape(', '.join(f'{a}: {b:.3g} (band {c:.3g})' for a, b, c in zip(m['visits'], m['rmse_um'], m['band_um'])))}"
                     f"; inputs outside the training range: "
                     f"{html.escape(', '.join(m['out_of_range']) or 'none')}; drifted inputs "
                     f"(KS): {html.escape(', '.join(m['drifted_inputs']) or 'none')}.</p>")
        details.append(
            f"<h2>{html.escape(s.machine_id)} axis {html.escape(s.axis)}</h2>{alerts}"
            f"{model}<table><tr><th>visit</th><th>date</th><th>tests</th><th>points</th>"
            f"<th>target</th><th>backlash [{unit}]</th><th>u(backlash) [{unit}]</th>{big_u}"
            f"<th>σ [{unit}]</th><th>mean reversal B_i [{unit}]</th>"
            f"<th>B = max|B_i| [{unit}]</th></tr>{body}</table>")
    note_html = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
    level = f"{100 * (1 - series[0].alpha):g} %" if series else ""
    day = f" As of {html.escape(as_of)}." if as_of else ""
    return f"""<p>Data: {html.escape(source)}.{day}</p>
<p>Series value: the axis's backlash at the visit, the mean lost motion over its interior
backlash points by the axis's measuring system (target <em>pendulum − linear</em> with a
direct system, <em>ISO |B_i|</em> with an indirect one or a single test method); u(backlash) is
its standard uncertainty from the tests' repeatability and σ the larger of u and the robust
scatter between visits. The mean signed ISO reversal value and B = max|B_i| (means over the
visit's tests) are shown for reference: with a direct system they are not the lost motion. Slope: Theil-Sen since the last change point ({level} interval); change points by
optimal partitioning into straight-line segments; crossing: Theil-Sen line, interval from the
OLS prediction band of a future visit. Next visit (the last plus the median time between the
axis's visits): the forecast with two {level} intervals, <em>measurement</em> (the value the
laser will read: the trend's uncertainty, the scatter between visits and the model error of
backtests) and <em>lost motion</em> (the axis's lost motion itself: the trend's uncertainty,
the axis's own part of the scatter and the measured target's own uncertainty); the figure's
band is the measurement's. Fewer than three visits since the last change point: no interval,
and the reason.</p>
{_uncertainty_text(series)}
{f'<ul>{note_html}</ul>' if note_html else ''}
<p>Each axis in its own unit: µm for a linear axis, arcsec for a rotary one.</p>
<table><tr><th>machine</th><th>axis</th><th>unit</th><th>visits</th><th>last backlash</th>
<th>slope [per month]</th><th>change points</th><th>threshold crossing</th>
<th>next visit</th><th>forecast: measurement</th><th>forecast: lost motion</th><th>alerts</th></tr>
{''.join(rows)}</table>
<p><img src="{FILES['png']}" alt="backlash series"></p>
{''.join(details)}
"""
