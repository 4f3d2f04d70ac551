"""The fleet site: a static folder that opens from disk (no server, no script, no URL).

Files written into the output folder (``write_site``), all or nothing:

- ``index.html``: the fleet table, worst first, a sparkline of each axis's history, forecast
  band and last recorded forecast, the last recorded forecast and compensation, each row
  linking to the axis's page;
- ``<machine>_<axis>.html`` per axis: the history chart with change points, forecast band,
  threshold and crossing interval, the visit table, alerts, the wear-rate map since the last
  change point, the last visit's ISO 230-2 chart and figures, the recorded forecasts (with the
  wear-rate map of the last one's model when it is a wear map) and the compensation history
  (every recorded correction table against the target, the latest highlighted);
- ``fleet.json``: what ``backlash fleet --json`` prints.

Pages use the product's one page shell (``pipeline.reports.report_page.page``); charts are inline SVG
(``pipeline.reports.fleet_charts``). The pages draw what the workflow computed: each axis's
analysis (``AxisView.forecast``: trend line, forecast band and crossing over the horizon the
analysis computed, ``models.condition.maintenance``) and its schedule; they compute nothing.
The pages are built in memory, written into a temporary folder
beside the output folder (``features.readings.fileio.temp_folder``) and renamed into place: a
new folder appears whole, files of an existing one are replaced one by one only after every
file was written.
"""

from __future__ import annotations

import html
import json
import os
import shutil
from pathlib import Path

from features.readings.errors import InputError
from pipeline.reports import fleet_charts
from pipeline.reports.report_page import page

INDEX, JSON = "index.html", "fleet.json"
TITLE = "Fleet backlash"
KIND_NAMES = {"paper": "pendulum − linear", "iso": "ISO |B_i|", "mixed": "mixed"}
REASONS = {"above_threshold": "at or above the threshold at the last visit: due now",
           "crossing": "the crossing interval opens (early end) before the interval ends",
           "fleet_rate": "one visit since the last change point: the day its level plus the "
                         "fleet's wear rate reaches the threshold, before the interval ends",
           "interval": "the maintenance interval after the last visit"}
STYLE = """<style>
svg.spark { vertical-align: middle; }
table.fleet { font-size: 0.85em; }
table.fleet td, table.fleet th { padding: 0.2em 0.4em; }
svg.chart { max-width: 100%; height: auto; border: 1px solid #dde; margin: 0.4em 0; }
tr.alerting td { background: #fff4f0; }
td.alerts { color: #b8431f; font-weight: 600; }
td.nowrap { white-space: nowrap; }
nav { margin-bottom: 0.8em; }
</style>"""


def write_site(result, out) -> dict[str, Path]:
    """Write the site of a ``FleetResult`` into folder ``out``; return the files by name
    (``index.html`` also under ``"index"``, ``fleet.json`` under ``"json"``)."""
    from features.readings.fileio import clean_nan, temp_folder

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("is a file; expected a folder for the site", file=out, parameter="out")
    texts = {INDEX: page(TITLE, STYLE + index_body(result)),
             JSON: json.dumps(clean_nan(result.to_dict()), indent=2) + "\n"}
    for view in result.axes:
        texts[view.page] = page(f"{view.machine_id} axis {view.axis}", STYLE + axis_body(view))
    tmp = temp_folder(out)
    try:
        for name, text in texts.items():
            (tmp / name).write_text(text, encoding="utf-8")
        _move(tmp, out, list(texts))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    files = {name: out / name for name in texts}
    return {"index": out / INDEX, "json": out / JSON, **files}


def _move(tmp: Path, out: Path, names: list[str]) -> None:
    """A new folder: rename the whole temporary folder into place; an existing one: replace
    its files one by one (each rename is atomic)."""
    from features.readings import fileio

    if not out.exists():
        os.chmod(tmp, 0o777 & ~fileio._UMASK)
        try:
            os.rename(tmp, out)
            return
        except OSError:  # created meanwhile: fall back to file by file
            pass
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        os.replace(tmp / name, out / name)


# --------------------------------------------------------------------------- helpers
def _esc(value) -> str:
    return html.escape(str(value))


def _unit(view) -> str:
    """The axis's unit as the pages write it: µm, or arcsec for a rotary axis."""
    return fleet_charts.unit_label(view.series.unit)


def _fmt(value, fmt: str = ".3f") -> str:
    import math

    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, fmt)


def _history(view) -> dict:
    """The series as the charts take it: days since the first visit, values, change days
    (the change points of the analysis the trend comes from)."""
    v, origin = view.series.visits, view.series.origin
    return {"days": fleet_charts.days_since(origin, v["date"]),
            "backlash_um": v["backlash_um"].to_numpy(float),
            "sigma_um": v["sigma_um"].to_numpy(float),
            "change_days": list(fleet_charts.days_since(origin, view.forecast.change_dates))}


def _band(view) -> dict | None:
    """The forecast band the analysis computed as the charts take it (days since the first
    visit, the next measurement's interval), or None."""
    band = view.forecast.band
    if band is None:
        return None
    return {"days": fleet_charts.days_since(view.series.origin, band["at"]),
            "fit": band["fit_um"], "low": band["measurement_low_um"],
            "high": band["measurement_high_um"]}


def _trend(view) -> dict | None:
    """The analysis's trend line as the chart takes it (days since the first visit), or None."""
    line = view.forecast.trend_line
    if line is None:
        return None
    return {"days": fleet_charts.days_since(view.series.origin, line["at"]),
            "fit": line["fit_um"]}


def _crossing_days(view) -> tuple:
    """The crossing (date, early, late) in days since the first visit, None where unknown."""
    return tuple(None if t is None else float(fleet_charts.days_since(view.series.origin, [t])[0])
                 for t in view.forecast.crossing)


def _crossing_text(j: dict) -> str:
    early, late = j["crossing_interval"]
    if j["next_visit_reason"] == "above_threshold":
        return "reached"
    if j["crossing_date"] is None:
        return "–"
    return f"{_esc(j['crossing_date'])} [{_esc(early or '–')}, {_esc(late or 'later')}]"


# --------------------------------------------------------------------------- index.html
def index_body(result) -> str:
    """The fleet table, worst first, with a sparkline per axis and notes."""
    from pipeline.steps.rotary_evidence import probing_section

    p = result.parameters
    rows = "".join(_index_row(i, view) for i, view in enumerate(result.axes, 1))
    notes = "".join(f"<li>{_esc(n)}</li>" for n in result.notes)
    alerting = sum(1 for v in result.axes if v.alerts)
    return f"""<p class="summary">As of <strong>{_esc(p.get('as_of'))}</strong>. Data:
{_esc(result.source)}. {len(result.axes)} machine axes,
{alerting} with an alert. Limits: {_limits_text(p)}; maintenance interval
{_fmt(p.get('interval_days'), 'g')} days.</p>
<p>Each axis in its own unit: µm for a linear axis, arcsec for a rotary one. Backlash: the
axis's lost motion at its last visit by its measuring system (pendulum − linear
with a direct system, ISO |B_i| with an indirect one) ± its standard uncertainty. Sorted worst
first: axes at or above the threshold, then other alerting axes, then the rest; within each, the
earliest next visit due, the earliest crossing, the highest backlash. Next visit due: the
earlier of the last visit + the interval and the early end of the crossing interval (the day a
future visit's upper prediction bound reaches the threshold); due now when already above it.
History: backlash per visit, change points dashed, forecast orange (the interval of the next
measurement, the value a laser will read), threshold red, last
recorded forecast purple with its 95 % interval. Last forecast: the mean over its points of the
recorded forecast [95 % interval] and the day it is for (~ estimated from the axis's operating
hours); last compensation: its day, controller and reversal compensation.</p>
{f'<ul>{notes}</ul>' if notes else ''}
<table class="fleet"><tr><th>#</th><th>machine axis</th><th>visits</th><th>last visit</th>
<th>backlash</th><th>history and forecast</th><th>slope [per month]</th>
<th>change points</th><th>crossing [interval]</th><th>next visit due</th>
<th>last forecast</th><th>last compensation</th><th>alerts</th></tr>
{rows}</table>
{probing_section(result)}
<p>Files: <a href="{JSON}">{JSON}</a> (the same as <code>backlash fleet --json</code>).</p>"""


def _interval(j: dict) -> str:
    """The slope's interval, or why there is none (a trend from two visits)."""
    low, high = j["slope_interval"]
    if low is None or high is None:
        return "interval cannot be estimated from two visits"
    return f"[{_fmt(low)}, {_fmt(high)}]"


def _overdue(j: dict) -> str:
    return "" if j["days_overdue"] is None else (
        f"<br><small class='alerts'>overdue {j['days_overdue']} d</small>")


def _limits_text(p: dict) -> str:
    """The limits the view compares with, each with its unit."""
    parts = [f"{_fmt(p[k], 'g')} {u} ({kind} axes)" for k, u, kind in (
        ("threshold_um", "µm", "linear"), ("threshold_arcsec", "arcsec", "rotary"))
        if p.get(k) is not None]
    if p.get("limits") is not None:
        given = p["limits"]
        parts.append("per machine axis from " + (_esc(os.fspath(given)) if isinstance(
            given, (str, os.PathLike)) else "the limits given"))
    return "; ".join(parts) or "none"


def _index_row(rank: int, view) -> str:
    j = view.to_dict()
    unit = _unit(view)
    threshold = view.series.threshold_um
    spark = fleet_charts.sparkline(_history(view), _band(view), threshold_um=threshold,
                                   alert=bool(view.alerts), recorded=recorded_point(view, j),
                                   label=f"{view.machine_id} {view.axis} backlash history")
    slope = (f"{_fmt(j['slope_um_per_month'], '+.3f')}<br><small>{_interval(j)}</small>"
             if j["slope_um_per_month"] is not None else "–")
    early, late = j["crossing_interval"]
    crossing = (f"{_esc(j['crossing_date'])}<br><small>[{_esc(early or '–')}, "
                f"{_esc(late or 'later')}]</small>" if j["crossing_date"] else _crossing_text(j))
    return (f"<tr class='{'alerting' if view.alerts else ''}'><td class='num'>{rank}</td>"
            f"<td class='nowrap'><a href=\"{_esc(view.page)}\">{_esc(view.machine_id)} "
            f"{_esc(view.axis)}</a></td><td class='num'>{j['visits']}</td>"
            f"<td class='nowrap'>{_esc(j['last_visit_date'])}<br><small>visit "
            f"{_esc(j['last_visit'])}</small></td>"
            f"<td class='num'>{_fmt(j['backlash_um'])} {unit}<br><small>± "
            f"{_fmt(j['backlash_u_um'])}</small></td><td>{spark}</td><td class='num'>{slope}"
            f"<br><small>{unit}/month</small></td>"
            f"<td>{_esc(', '.join(j['change_points']) or '–')}</td>"
            f"<td class='nowrap'>{crossing}</td><td class='nowrap'>{_esc(j['next_visit_due'])}"
            f"{_overdue(j)}</td><td class='nowrap'>{_forecast_cell(j['last_forecast'], unit)}</td>"
            f"<td class='nowrap'>{_compensation_cell(j['last_compensation'])}</td>"
            f"<td class='alerts'>{'<br>'.join(map(_esc, j['alerts']))}</td></tr>\n")


def _for_text(last: dict) -> str:
    """The day (``~`` when estimated from operating hours) and hours a forecast is for."""
    parts = []
    if last["for_date"]:
        parts.append(f"{'~' if last['for_date_estimated'] else ''}{last['for_date']}")
    if last["for_operating_hours"] is not None:
        parts.append(f"{last['for_operating_hours']:g} h")
    if last["for_visit"]:
        parts.append(f"visit {last['for_visit']}")
    return _esc(", ".join(parts) or "–")


def _band_text(last: dict) -> str:
    band = (f" [{_fmt(last['backlash_low_um'], '.2f')}, {_fmt(last['backlash_high_um'], '.2f')}]"
            if last["backlash_low_um"] is not None else "")
    return f"{_fmt(last['backlash_um'], '.2f')}{band}"


def _forecast_cell(last, unit: str) -> str:
    if last is None:
        return "–"
    when = last["for_date"] and f"{'~' if last['for_date_estimated'] else ''}{last['for_date']}"
    return f"{_band_text(last)} {unit}<br><small>for {_esc(when or _for_text(last))}</small>"


def _compensation_cell(last) -> str:
    if last is None:
        return "–"
    return (f"{_esc(last['date'])}<br><small>{_esc(last['controller'])}, "
            f"{_fmt(last['reversal_compensation_um'], '.2f')} {_esc(last['unit'])}</small>")


def recorded_point(view, j: dict) -> dict | None:
    """The last recorded forecast as the charts draw it (days since the first visit), or None
    when there is none or its day is unknown."""
    import datetime as dt

    last = j["last_forecast"]
    if last is None or last["for_date"] is None:
        return None
    origin = view.series.visits["date"].iloc[0].date()
    return {"day": float((dt.date.fromisoformat(last["for_date"]) - origin).days),
            "fit": last["backlash_um"], "low": last["backlash_low_um"],
            "high": last["backlash_high_um"]}


# --------------------------------------------------------------------------- axis pages
def axis_body(view) -> str:
    """An axis's page: summary, alerts, history chart, visits, wear map, ISO chart; every
    value in the axis's unit."""
    j = view.to_dict()
    return "\n".join([
        f'<nav><a href="{INDEX}">← fleet</a></nav>', _summary(view, j), _alerts(view),
        "<h2>History and forecast</h2>", _history_chart(view, j),
        "<h2>Visits</h2>", _visit_table(view),
        "<h2>Wear-rate map since the last change point</h2>", _wear(view),
        "<h2>Last visit: ISO 230-2 chart</h2>", _iso(view),
        "<h2>Recorded forecasts</h2>", _forecasts(view),
        "<h2>Compensation history</h2>", _compensations(view),
        *(["<h2>Voided tests (read by no command)</h2>", _voided(view)] if view.voided else [])])


def _voided(view) -> str:
    """The axis's voided tests with when, who and why (``backlash void``)."""
    rows = "".join(f"<tr><td>{_esc(t['visit'])}</td><td>{_esc(t['test_id'])}</td>"
                   f"<td>{_esc(t['at'][:19].replace('T', ' '))} UTC</td>"
                   f"<td>{_esc(t['user_name'])}</td><td>{_esc(t['reason'])}</td></tr>"
                   for t in view.voided)
    return ("<table><tr><th>visit</th><th>test</th><th>voided at</th><th>by</th>"
            f"<th>reason</th></tr>{rows}</table>")


def _summary(view, j: dict) -> str:
    kind = KIND_NAMES.get(j["target_kind"], j["target_kind"] or "–")
    unit = _unit(view)
    changes = ", ".join(f"{c} ({d:+.2f} {unit})" for c, d in zip(j["change_points"],
                                                                  j["change_jumps_um"]))
    trend = (f"Trend since visit {_esc(j['trend_since_visit'])}: "
             f"{_fmt(j['slope_um_per_month'], '+.3f')} {unit}/month {_interval(j)}"
             if j["slope_um_per_month"] is not None
             else "No trend (fewer than two visits since the last change point)")
    visits = f"{j['visits']} visit{'s' if j['visits'] > 1 else ''}"
    return f"""<div class="summary"><p>Backlash at visit {_esc(j['last_visit'])}
({_esc(j['last_visit_date'])}): <strong>{_fmt(j['backlash_um'])} ± {_fmt(j['backlash_u_um'])}
{unit}</strong> ({_esc(kind)}), {visits} since {_esc(j['first_visit_date'])}.<br>
{trend}. Change points: {_esc(changes or 'none')}.<br>
Threshold crossing{_threshold_text(j, unit)}: {_crossing_text(j)}.<br>
Next visit due: <strong>{_esc(j['next_visit_due'])}</strong>
({_esc(REASONS[j['next_visit_reason']])}){_overdue_text(view, j)}.<br>
{_esc(_forecast_text(j, unit))}<br>
{_esc(_uses_text(j, unit))}</p></div>"""


def _forecast_text(j: dict, unit: str) -> str:
    """The forecast of the next visit with its two 95 % intervals, or why there is none."""
    if j["forecast_date"] is None:
        return f"Forecast: none, {j['forecast_note']}."
    return (f"Forecast for {j['forecast_date']} (the visits' usual pace): "
            f"{_fmt(j['forecast_um'])} {unit}; the next measurement "
            f"[{_fmt(j['forecast_measurement_low_um'])}, "
            f"{_fmt(j['forecast_measurement_high_um'])}] (drawn orange), the axis's lost "
            f"motion [{_fmt(j['forecast_lost_motion_low_um'])}, "
            f"{_fmt(j['forecast_lost_motion_high_um'])}] {unit} (95 %).")


def _uses_text(j: dict, unit: str) -> str:
    """Which points the trend, crossing and forecast used, and the trace days' offset."""
    off = (j["forecast_offset_um"] or {}).get("trace")
    if off is None:
        return "Trend and forecast from the laser visits."
    return (f"Trend and forecast from the laser visits and the trace days, shifted onto the "
            f"laser's backlash by {-off['value']:+.3f} ± {off['u']:.3f} {unit} (offset from "
            f"{off['days_in_common']} day(s) in common), weighted by their uncertainty.")


def _overdue_text(view, j: dict) -> str:
    as_of = "" if view.as_of is None else view.as_of.isoformat()
    if j["days_overdue"] is None:
        return f"; as of {_esc(as_of)}" if as_of else ""
    return f"; <strong>{j['days_overdue']} days overdue</strong> as of {_esc(as_of)}"


def _threshold_text(j: dict, unit: str) -> str:
    return "" if j["threshold_um"] is None else f" ({_fmt(j['threshold_um'], 'g')} {unit})"


def _alerts(view) -> str:
    if not view.alerts:
        return "<p>No alert.</p>"
    items = "".join(f"<li>{_esc(a['kind'])}: {_esc(a['message'])}</li>" for a in view.alerts)
    return f"<div class='alert'><ul>{items}</ul></div>"


def _history_chart(view, j: dict) -> str:
    origin = view.series.visits["date"].iloc[0].date()
    return fleet_charts.history_chart(
        _history(view), _band(view), _trend(view), origin, unit=view.series.unit,
        threshold_um=view.series.threshold_um, crossing=_crossing_days(view),
        due_days=float((view.next_visit_due - origin).days), recorded=recorded_point(view, j),
        label=f"{view.machine_id} {view.axis}: backlash per visit and forecast",
        evidence=evidence_marks(view, origin)) + _evidence_text(view)


# The other sources' markers: (shape, colour, what they are).
EVIDENCE_MARKS = {"trace": ("square", fleet_charts.GREEN, "trace lost motion per day"),
                  "ballbar": ("diamond", fleet_charts.PURPLE, "ballbar backlash")}


def evidence_marks(view, origin) -> list[dict]:
    """The trace days and ballbar runs of the axis as the history chart draws them (as
    recorded, not shifted; the legend gives each source's offset to the laser)."""
    frame = view.evidence
    if frame is None or frame.empty:
        return []
    out = []
    for source, (shape, colour, text) in EVIDENCE_MARKS.items():
        mine = frame[frame["source"] == source]
        off = view.offsets.get(source)
        shift = ("no offset: no laser visit near" if off is None
                 else f"offset {off['value']:+.2f} ± {off['u']:.2f}")
        out.append({"shape": shape, "colour": colour, "text": f"{text} ({shift})",
                    "days": [(d.date() - origin).days for d in mine["date"]],
                    "values": mine["value_um"].to_numpy(float),
                    "u": mine["u_um"].to_numpy(float)})
    return out


def _evidence_text(view) -> str:
    """One line per other source: its points and its offset to the laser's backlash."""
    lines = []
    for source, off in view.offsets.items():
        n = int((view.evidence["source"] == source).sum())
        lines.append(f"{source}: {n} point(s); " + (
            f"offset to the laser {off['value']:+.3f} ± {off['u']:.3f} {view.series.unit} "
            f"from {off['days_in_common']} day(s) in common" if off is not None else
            "no laser visit close enough to estimate its offset"))
    return "".join(f"<p class='note'>{_esc(line)}</p>" for line in lines)


def _visit_table(view) -> str:
    rows = []
    for r in view.series.visits.to_dict("records"):
        cells = (_fmt(r.get("n_tests"), "d"), _fmt(r.get("n_points"), "d"),
                 _esc(KIND_NAMES.get(r.get("target_kind"), "–")), _fmt(r["backlash_um"]),
                 _fmt(r["backlash_u_um"]), _fmt(r["sigma_um"]), _fmt(r.get("reversal_mean_um")),
                 _fmt(r.get("reversal_max_um")))
        rows.append(f"<tr><td>{_esc(r['visit'])}</td><td>{r['date'].date().isoformat()}</td>"
                    + "".join(f"<td class='num'>{c}</td>" for c in cells) + "</tr>")
    u = _unit(view)
    return ("<table><tr><th>visit</th><th>date</th><th>tests</th><th>points</th><th>target</th>"
            f"<th>backlash [{u}]</th><th>u [{u}]</th><th>σ [{u}]</th>"
            f"<th>mean reversal B_i [{u}]</th><th>B = max|B_i| [{u}]</th></tr>"
            + "".join(rows) + "</table>")


def _wear(view) -> str:
    if view.wear is None:
        return f"<p>No wear-rate map: {_esc(view.wear_note)}.</p>"
    from features.readings.schema import position_unit

    w = view.wear
    chart = fleet_charts.wear_chart(w, label=f"{view.machine_id} {view.axis}: wear-rate map",
                                    unit=view.series.unit, position_unit=position_unit(view.axis))
    return (f"{chart}<p>Wear rate w(x) [{_unit(view)} per 1000 operating hours] with its 95 % "
            "interval, "
            f"from {w['n_points']} interior backlash points of visits "
            f"{_esc(', '.join(w['visits']))} (models.wear.wear_map.WearMap, "
            f"{_esc(w['n_control'])} control points).</p>")


FIGURE_KEYS = ("A", "E", "M", "R", "B", "B_mean")
NONE_RECORDED = ("<p>None recorded{}: {} records it in a fleet store "
                 "(see <code>docs/fleet.md</code>).</p>")


def _forecasts(view) -> str:
    """Every recorded forecast, latest first, and the wear-rate map of the last one's model
    when it is a wear map."""
    from pipeline.store.records import summary

    if not view.forecasts:
        return NONE_RECORDED.format("", "<code>backlash predict MODEL DATA --store STORE</code>")
    rows = "".join(
        f"<tr><td>{_esc(s['recorded_at'][:19].replace('T', ' '))}</td><td>{_for_text(s)}</td>"
        f"<td class='num'>{_band_text(s)}</td><td class='num'>{s['points']}</td>"
        f"<td>{_esc(s['model'])}</td><td>{_esc(s['model_dir'] or '–')}</td></tr>"
        for s in map(summary, reversed(view.forecasts)))
    table = ("<table><tr><th>recorded (UTC)</th><th>for</th>"
             f"<th>backlash [{_unit(view)}] [95 %]</th>"
             "<th>points</th><th>model</th><th>model directory</th></tr>" + rows + "</table>")
    last = view.forecasts[-1]
    if last.get("wear_rate") is None:
        return table + "<p>The last forecast's model has no wear-rate map.</p>"
    from features.readings.schema import position_unit

    chart = fleet_charts.wear_chart(last["wear_rate"], label=f"{view.machine_id} {view.axis}: "
                                    "wear-rate map of the last forecast's model",
                                    unit=view.series.unit, position_unit=position_unit(view.axis))
    return (f"{table}<h3>Wear-rate map of the last forecast's model</h3>{chart}<p>w(x) "
            f"[{_unit(view)} per "
            f"1000 operating hours] with its 95 % interval, as {_esc(last['model'])} learned it "
            "for this axis.</p>")


def _compensations(view) -> str:
    """The correction tables of every recorded compensation against the target, the latest
    highlighted, and one row per compensation."""
    from features.readings.schema import position_unit
    from pipeline.store.records import summary

    if not view.compensations:
        return NONE_RECORDED.format(
            " yet", "<code>backlash compensate DATA --controller C --out DIR --store STORE</code>")
    unit = view.compensations[-1]["unit"]
    chart = fleet_charts.compensation_chart(
        view.compensations, unit, position_unit(view.axis),
        label=f"{view.machine_id} {view.axis}: compensation history")
    rows = "".join(
        f"<tr><td>{_esc(s['recorded_at'][:19].replace('T', ' '))}</td>"
        f"<td>{_esc(s['controller'])}</td><td>{_esc(s['source'])}</td>"
        f"<td class='num'>{_fmt(s['reversal_compensation_um'])}</td>"
        f"<td class='num'>{_fmt(s['max_abs_correction_um'])}</td><td class='num'>{s['points']}"
        f"</td><td>{_esc(', '.join(s['files']))}</td></tr>"
        for s in map(summary, reversed(view.compensations)))
    return (f"{chart}<p>Correction = −error of each approach direction, as the controller "
            "adds it to the commanded position.</p><table><tr><th>recorded (UTC)</th>"
            f"<th>controller</th><th>from</th><th>reversal compensation [{_esc(unit)}]</th>"
            f"<th>max |correction| [{_esc(unit)}]</th><th>points</th><th>files</th></tr>"
            + rows + "</table>")


def _iso(view) -> str:
    iso = view.iso
    if iso is None:
        return "<p>No per-target statistics for the last visit.</p>"
    chart = fleet_charts.iso_chart(iso["targets"], iso["unit"], iso["position_unit"],
                                   label=f"ISO 230-2 chart of {iso['test_id']}")
    head = "".join(f"<th>{k} [{_esc(iso['unit'])}]</th>" for k in FIGURE_KEYS)
    rows = "".join(f"<tr><td>{_esc(name)}</td>"
                   + "".join(f"<td class='num'>{_fmt(values.get(k))}</td>" for k in FIGURE_KEYS)
                   + "</tr>" for name, values in _figure_rows(iso))
    return (f"<p>Test {_esc(iso['test_id'])} ({_esc(iso['method'])}) of visit "
            f"{_esc(iso['visit'])}: mean deviation per target and direction with ±2s bands."
            f"</p>{chart}<table><tr><th>ISO 230-2 figures</th>{head}</tr>{rows}</table>")


def _figure_rows(iso: dict) -> list[tuple[str, dict]]:
    """The charted test's figures, then the mean over the visit's tests of each method."""
    figures = iso["figures"]
    rows = [(f"test {iso['test_id']}", f) for f in figures if f["test_id"] == iso["test_id"]]
    for method in sorted({str(f.get("method")) for f in figures}):
        mine = [f for f in figures if str(f.get("method")) == method]
        mean = {k: sum(float(f[k]) for f in mine) / len(mine) for k in FIGURE_KEYS}
        rows.append((f"mean of {len(mine)} {method} test{'s' if len(mine) > 1 else ''}", mean))
    return rows
