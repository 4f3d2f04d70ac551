"""A rotary axis's probing evidence in the fleet view: its play per visit from the ``probing``
records a fleet store holds (``backlash kinematics --store``), trended as the fleet trends an
axis's laser visits (``models.condition.drift.analyse_series``: change points, Theil-Sen slope, the
crossing of the axis's limit, alerts), beside the axis's laser series or, when the axis has no
laser tests, instead of it.

The play is the axis's lost motion at reversal measured on the sphere centres [arcsec]: the
same quantity the laser measures as a rotary axis's backlash, but by another method, so the
two series are shown side by side and never pooled (no offset between them is estimated).

A visit recorded twice (the same probing again, or re-identified) counts once: its latest
recorded record. A record without a date (a probing table without ``started_at``) or without
a play (one approach direction only) has no place on the time axis: it is left out, with a note.
"""

from __future__ import annotations

import datetime as dt
import html
from dataclasses import dataclass, field

import pandas as pd


@dataclass
class ProbingView:
    """What the fleet view shows of one rotary axis's probing.

    Attributes
    ----------
    series : models.condition.drift.DriftSeries
        The visits (``backlash_um``: the play [arcsec], ``backlash_u_um`` its standard
        uncertainty), change points, trend [arcsec/month], crossing of the axis's limit,
        alerts; every value in arcsec (``series.unit``).
    laser : bool
        The axis has laser visits in the view as well (its own ``AxisView``).
    records : list of dict
        The probing record of each visit in the series, oldest first.
    """

    series: object
    laser: bool = False
    records: list = field(default_factory=list)

    @property
    def machine_id(self) -> str:
        return self.series.machine_id

    @property
    def axis(self) -> str:
        return self.series.axis

    @property
    def alerts(self) -> list[dict]:
        """The series' alerts, each saying it comes from the probing (``source``)."""
        return [{**a, "message": f"probing play: {a['message']}", "source": "probing"}
                for a in self.series.alerts]

    def to_dict(self) -> dict:
        """The axis as ``fleet --json`` prints it under ``probing`` (docs/fleet.md)."""
        s, v = self.series, self.series.visits
        trend, last = s.trend, self.records[-1]
        return {
            "machine_id": s.machine_id, "axis": s.axis, "unit": s.unit,
            "laser_visits": self.laser, "visits": len(v),
            "last_visit": str(v["visit"].iloc[-1]),
            "last_visit_date": v["date"].iloc[-1].date().isoformat(),
            "play_arcsec": _round(v["backlash_um"].iloc[-1]),
            "play_u_arcsec": _round(v["backlash_u_um"].iloc[-1]),
            "slope_arcsec_per_month": _round(trend.get("slope")),
            "slope_interval": [_round(trend.get("low")), _round(trend.get("high"))],
            "mann_kendall_p": _round(trend.get("p_value"), 6),
            "trend_since_visit": str(v["visit"].iloc[s.segment_start]),
            "change_points": [str(v["visit"].iloc[c["index"]]) for c in s.change_points],
            "threshold_arcsec": s.threshold_um,
            "crossing_date": s.date_at(s.crossing[0]),
            "crossing_interval": [s.date_at(s.crossing[1]), s.date_at(s.crossing[2])],
            "alerts": [a["kind"] for a in self.alerts],
            "alert_messages": [a["message"] for a in self.alerts],
            "history": {"visits": v["visit"].astype(str).tolist(),
                        "dates": [d.date().isoformat() for d in v["date"]],
                        "play_arcsec": [_round(x) for x in v["backlash_um"]],
                        "play_u_arcsec": [_round(x) for x in v["backlash_u_um"]]},
            "last_errors": last["errors"], "last_errors_u": last["errors_u"],
            "kinematics": last["kinematics"],
        }


def _round(value, digits: int = 4):
    import math

    if value is None:
        return None
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def probing_frame(found: list[dict], as_of: dt.date | None = None
                  ) -> tuple[pd.DataFrame, list[dict], list[str]]:
    """One machine axis's probing records (oldest recorded first) as a visit series: the
    latest record per visit dated up to the end of ``as_of``, as ``analyse_series`` reads it
    (``machine_id``, ``axis``, ``visit``, ``date`` at noon UTC, ``backlash_um`` = the play,
    ``backlash_u_um`` [arcsec]); the records kept, and notes on those left out."""
    latest = {}
    for r in found:  # oldest first: the latest wins
        latest[r["visit"]] = r
    kept, notes = [], []
    for r in latest.values():
        where = f"{r['machine_id']} axis {r['axis']} probing visit {r['visit']}"
        if r["date"] is None:
            notes.append(f"{where}: no date (its probing table has no started_at): left out "
                         "of the axis's probing series")
        elif r["play_arcsec"] is None:
            notes.append(f"{where}: no play (one approach direction only): left out of the "
                         "axis's probing series")
        elif as_of is None or dt.date.fromisoformat(r["date"]) <= as_of:
            kept.append(r)
    kept.sort(key=lambda r: (r["date"], r["visit"]))
    frame = pd.DataFrame({
        "machine_id": [r["machine_id"] for r in kept], "axis": [r["axis"] for r in kept],
        "visit": [r["visit"] for r in kept],
        "date": [pd.Timestamp(r["date"], tz="UTC") + pd.Timedelta(hours=12) for r in kept],
        "backlash_um": [float(r["play_arcsec"]) for r in kept],
        "backlash_u_um": [float(r["play_u_arcsec"] or 0.0) for r in kept]})
    return frame, kept, notes


def probing_views(records: dict, as_of: dt.date | None = None, *, keeps=None,
                  laser=frozenset(), settings=None) -> tuple[list[ProbingView], list[str]]:
    """A ``ProbingView`` per rotary axis with probing records in ``records`` (what
    ``pipeline.steps.source.Source.records`` read) that ``keeps(machine_id, axis)`` keeps
    (default all), alerting ones first, then by machine and axis; and the notes of records
    left out. ``laser``: the (machine_id, axis) with laser visits in the view; ``settings``
    (``models.condition.settings.MaintenanceSettings``, default its defaults): the limits
    (each axis's is ``models.condition.drift.limit_of``'s) and the trend analysis
    (``models.condition.drift.analyse_series``); with ``as_of`` a crossing before it alerts
    ``limit_passed_unmeasured`` as on a laser series."""
    from models.condition.drift import analyse_series, limit_of, limit_passed_alert
    from models.condition.settings import DEFAULTS

    settings = DEFAULTS if settings is None else settings
    views, notes = [], []
    for key, found in sorted((records.get("probing") or {}).items()):
        if keeps is not None and not keeps(*key):
            continue
        frame, kept, said = probing_frame(found, as_of)
        notes += said
        if frame.empty:
            continue
        series = analyse_series(frame, threshold_um=limit_of(*key, **settings.limits_of()),
                                **settings.trend_options())
        passed = limit_passed_alert(series, as_of) if as_of is not None else None
        if passed is not None:
            series.alerts.append(passed)
        views.append(ProbingView(series, key in laser, kept))
    views.sort(key=lambda v: (not v.alerts, v.machine_id, v.axis))
    return views, notes


# --------------------------------------------------------------------------- the site
def probing_section(result) -> str:
    """The index page's table of the rotary axes' probing plays (``result.probing``); empty
    when the store holds none."""
    from pipeline.reports import fleet_charts

    views = getattr(result, "probing", None) or []
    if not views:
        return ""
    rows = []
    for view in views:
        j = view.to_dict()
        days = list(fleet_charts.days_since(view.series.origin, view.series.visits["date"]))
        spark = fleet_charts.sparkline(
            {"days": days, "backlash_um": view.series.visits["backlash_um"].to_numpy(float),
             "change_days": [days[c["index"]] for c in view.series.change_points]}, None,
            threshold_um=view.series.threshold_um, alert=bool(view.alerts),
            label=f"{view.machine_id} {view.axis} probing play history")
        slope = j["slope_arcsec_per_month"]
        crossing = j["crossing_date"] or ("reached" if "above_threshold" in j["alerts"] else "–")
        rows.append(
            f"<tr class='{'alerting' if view.alerts else ''}'><td class='nowrap'>"
            f"{_esc(view.machine_id)} {_esc(view.axis)}</td><td>"
            f"{'yes' if view.laser else 'no'}</td><td class='num'>{j['visits']}</td>"
            f"<td class='nowrap'>{_esc(j['last_visit_date'])}<br><small>visit "
            f"{_esc(j['last_visit'])}</small></td><td class='num'>{j['play_arcsec']:.2f} ± "
            f"{j['play_u_arcsec']:.2f}</td><td>{spark}</td><td class='num'>"
            f"{'–' if slope is None else format(slope, '+.3f')}</td>"
            f"<td class='nowrap'>{_esc(crossing)}</td>"
            f"<td class='alerts'>{'<br>'.join(map(_esc, j['alerts']))}</td></tr>\n")
    return f"""<h2>Rotary axes: play from probing</h2>
<p>Each rotary axis's play at reversal [arcsec] identified from probed spheres (<code>backlash
kinematics --store</code>), per visit, trended as the laser visits are (change points, slope,
the crossing of the axis's limit). A second method beside the laser (shown apart, never
pooled with it), or the axis's only series when it has no laser tests.</p>
<table class="fleet"><tr><th>machine axis</th><th>laser visits</th><th>visits</th>
<th>last visit</th><th>play [arcsec]</th><th>history</th><th>slope [arcsec/month]</th>
<th>crossing</th><th>alerts</th></tr>
{''.join(rows)}</table>"""


def _esc(value) -> str:
    return html.escape(str(value))
