"""One view of the fleet: every machine axis's backlash now, its trend, when it crosses the
limit, when it is next due, its alerts, worst first; a static site that opens from disk.

>>> import backlash as bl
>>> view = bl.fleet("readings.csv", threshold_um=8.0, out="fleet/")   # doctest: +SKIP
>>> view.axes[0].to_dict()["next_visit_due"]                          # doctest: +SKIP

The fleet is ``drift``'s analysis per axis, a schedule and a site. This module only wires:

- per machine axis the maintenance analysis (``models.condition.maintenance``: the visit
  series of ``features.visits.visit_backlash``, change points, Theil-Sen trend, the crossing of
  the limit, the forecast band, the next visit), the same as ``drift``'s; with a store's
  trace days sharing enough days with the laser, the analysis of both (``trace_forecasts``);
- the schedule (``models.condition.schedule``: next visit due, the fleet's wear rate an axis
  without a trend is planned with, the day a recorded forecast is for, overdue, worst first;
  the rules are in its docstring and docs/fleet.md);
- per axis the wear-rate map since the last change point (``models.wear.axis_map``), the
  ISO 230-2 chart of the last visit (``features.iso230``), a store's records read through the
  ``Source`` (forecasts, compensations, voided tests, trace days, ballbar runs, probing runs)
  and its watchers' state;
- the site (``pipeline.reports.fleet_report``), which draws what was computed here.
"""

from __future__ import annotations

import datetime as dt
import os
import re
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from features.readings import schema
from features.readings.errors import InputError, note
from models.condition.settings import DEFAULT_INTERVAL_DAYS, DEFAULTS, MaintenanceSettings
from pipeline.results import Result, TrackingRecord, axis_alerts
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import FORMAT, MAINTENANCE, Param, python_only, readings
from pipeline.steps.source import Source, source_of

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--as-of", "2026-06-30"],
    {"data": "{twin}", "as_of": "2026-06-30"},
)

PARAMETERS = {
    "data": readings("readings with several visits per machine axis (visit, started_at)"),
    "format": FORMAT,
    **MAINTENANCE,  # the analysis drift and fleet share
    "interval_days": Param((Interval(Real, 0, None, closed="neither"),), metavar="D"),
    "out": Param((str, os.PathLike, None), "write the fleet site into DIR (index.html, one page "
                 "per axis, fleet.json); it opens from disk", metavar="DIR", output="folder"),
    "store": python_only(str, os.PathLike, None),
    "stale_after_days": Param((Interval(Real, 0, None, closed="neither"),), metavar="D"),
}
# A watched axis silent this long [d] is stale: a weekend without production is not.
STALE_AFTER_DAYS = 2.0


# --------------------------------------------------------------------------- one axis
@dataclass
class AxisView:
    """Everything the fleet view shows of one machine axis.

    Attributes
    ----------
    laser : models.condition.maintenance.AxisForecast
        The analysis of the axis's laser visits: ``laser.series`` holds the visits
        (``backlash_um``, ``backlash_u_um``, ``sigma_um`` [unit], ``t_month``), change points,
        trend [unit/month], crossing, alerts.
    next_visit_due : datetime.date
        When the axis should next be measured (``models.condition.schedule.next_visit_due``).
    next_visit_reason : str
        Which rule set it: ``above_threshold``, ``crossing``, ``fleet_rate`` or ``interval``.
    with_trace : models.condition.maintenance.AxisForecast or None
        With trace days in a store sharing ``MIN_SHARED_DAYS`` days with the laser: the
        analysis of the laser visits with the trace days shifted onto the laser's definition
        (``trace_forecasts``), which the trend, change points, crossing, alerts, next visit and
        forecast come from; None when they come from the laser visits alone.
    as_of : datetime.date or None
        The day the view is computed as of (``days_overdue`` counts to it).
    fleet_rate : dict or None
        For an axis with one visit since its last change point: the wear rate it is planned
        with, ``per_day`` [um/d, arcsec/d for a rotary axis] and ``basis`` (``operating hours``:
        the fleet's rate per hour times the axis's hours per day; ``calendar``: per month).
    wear : dict or None
        The wear-rate map since the last change point: ``position_mm``, ``rate``, ``low``,
        ``high`` [um per 1000 h], ``n_points``, ``visits``; None when it cannot be fitted.
    wear_note : str
        Why there is no wear-rate map (empty when there is one).
    iso : dict or None
        The last visit's ISO 230-2 chart: ``test_id``, ``method``, ``unit``, per-target arrays
        ``targets`` and the figures of every test of the visit (``figures``).
    page : str
        File name of the axis's page in the site.
    forecasts, compensations : list of dict
        The forecasts and compensations a fleet store recorded for the axis, oldest first
        (``pipeline.store.records``; a forecast without a day but with operating hours gets
        the day the axis's hours reach them, ``for_date_estimated``); empty for a file.
    evidence : DataFrame or None
        The trace days and ballbar runs a fleet store recorded for the axis
        (``pipeline.steps.evidence.evidence_frame``: ``source``, ``date``, ``value_um``, ``u_um``
        [um], ``label``, ``plane``), up to the view's day; None for a file.
    offsets : dict
        Per source with points: its offset to the laser's backlash
        (``models.condition.evidence.offset``: ``value``, ``u`` [um], ``days_in_common``), or None
        without a laser visit near any of its points.
    evidence_notes : list of str
        Why a source has no offset.
    voided : list of dict
        The axis's voided tests in a store (``visit``, ``test_id``, ``at``, ``user_name``,
        ``reason``: ``backlash void``); no reader reads them.
    live : dict or None
        A watched axis (``backlash watch``): ``last_sample`` (ISO, UTC), ``stale_after_s``
        (the silence it alerts ``source_stale`` past [s]), ``source``; None when not watched.
    """

    laser: object
    next_visit_due: dt.date
    next_visit_reason: str
    with_trace: object = None
    wear: dict | None = None
    wear_note: str = ""
    iso: dict | None = None
    page: str = ""
    forecasts: list = field(default_factory=list)
    compensations: list = field(default_factory=list)
    fleet_rate: dict | None = None
    as_of: dt.date | None = None
    evidence: object = None
    offsets: dict = field(default_factory=dict)
    evidence_notes: list = field(default_factory=list)
    voided: list = field(default_factory=list)
    live: dict | None = None

    @property
    def forecast(self):
        """The analysis the trend, crossing, alerts, next visit and forecast band come from
        (``models.condition.maintenance.AxisForecast``)."""
        return self.with_trace if self.with_trace is not None else self.laser

    @property
    def series(self):
        """The laser visits' series (``models.condition.drift.DriftSeries``)."""
        return self.laser.series

    @property
    def basis(self):
        """The series the trend, crossing, alerts and forecast come from."""
        return self.forecast.series

    @property
    def forecast_uses(self) -> list[str]:
        """The sources of the points the forecast used: ``laser``, and ``trace``."""
        return ["laser", "trace"] if self.with_trace is not None else ["laser"]

    @property
    def machine_id(self) -> str:
        return self.series.machine_id

    @property
    def axis(self) -> str:
        return self.series.axis

    @property
    def last(self):
        """The last visit's row of the series."""
        return self.series.visits.iloc[-1]

    @property
    def alerts(self) -> list[dict]:
        return self.basis.alerts

    @property
    def days_overdue(self) -> int | None:
        """Days the next visit is overdue as of the view's day (``overdue``), or None."""
        late = None if self.as_of is None else (self.as_of - self.next_visit_due).days
        return late if late is not None and late > 0 else None

    def to_dict(self) -> dict:
        """The axis as ``--json`` prints it (docs/fleet.md lists every key and its unit)."""
        from features.visits import DAYS_PER_MONTH
        from pipeline.store.records import summary

        s, v, f = self.series, self.series.visits, self.forecast
        b = f.series
        trend = b.trend
        return {
            "machine_id": s.machine_id, "axis": s.axis, "unit": s.unit, "visits": len(v),
            "first_visit_date": _day(v["date"].iloc[0]).isoformat(),
            "last_visit": str(self.last["visit"]), "last_visit_date": _day(self.last["date"]).isoformat(),
            "target_kind": str(self.last.get("target_kind", "")) or None,
            "backlash_um": _round(self.last["backlash_um"]),
            "backlash_u_um": _round(self.last["backlash_u_um"]),
            "slope_um_per_month": _round(trend.get("slope")),
            "slope_interval": [_round(trend.get("low")), _round(trend.get("high"))],
            "trend_since_visit": str(b.visits["visit"].iloc[b.segment_start]),
            "change_points": [str(b.visits["visit"].iloc[c["index"]])
                              for c in b.change_points],
            "change_jumps_um": [_round(c["jump_um"]) for c in b.change_points],
            "threshold_um": s.threshold_um,
            "crossing_date": f.day(f.crossing[0]),
            "crossing_interval": [f.day(f.crossing[1]), f.day(f.crossing[2])],
            "forecast_uses": self.forecast_uses,
            "forecast_offset_um": self.forecast_offset(),
            **f.next_visit,
            "next_visit_due": self.next_visit_due.isoformat(),
            "next_visit_reason": self.next_visit_reason,
            "days_overdue": self.days_overdue,
            "fleet_wear_rate_per_month": None if self.fleet_rate is None else _round(
                self.fleet_rate["per_day"] * DAYS_PER_MONTH, 5),
            "last_sample": None if self.live is None else self.live["last_sample"],
            "stale_after_s": None if self.live is None else self.live["stale_after_s"],
            "alerts": [a["kind"] for a in self.alerts],
            "alert_messages": [a["message"] for a in self.alerts],
            "last_forecast": summary(self.forecasts[-1]) if self.forecasts else None,
            "last_compensation": summary(self.compensations[-1]) if self.compensations else None,
            "history": {"visits": v["visit"].astype(str).tolist(),
                        "dates": [_day(d).isoformat() for d in v["date"]],
                        "backlash_um": [_round(x) for x in v["backlash_um"]],
                        "backlash_u_um": [_round(x) for x in v["backlash_u_um"]]},
            "page": self.page,
            "voided_tests": [{k: t[k] for k in ("visit", "test_id", "at", "user_name", "reason")}
                             for t in self.voided],
            **self.evidence_json(),
        }

    def forecast_offset(self) -> dict | None:
        """The offset [um] the trace days were shifted by onto the laser's definition, with
        its standard uncertainty and the days it comes from; None for a laser-only forecast."""
        off = self.offsets.get("trace") if self.with_trace is not None else None
        return None if off is None else {"trace": {
            "value": _round(off["value"]), "u": _round(off["u"]),
            "days_in_common": off["days_in_common"]}}

    def evidence_json(self) -> dict:
        """``evidence`` and ``offsets_um`` (docs/fleet.md): empty lists and nulls for a
        file."""
        import pandas as pd

        from pipeline.steps.evidence import EVIDENCE_COLUMNS, evidence_json

        frame = (self.evidence if self.evidence is not None
                 else pd.DataFrame(columns=[*EVIDENCE_COLUMNS, "plane"]))
        return evidence_json(frame, self.offsets)


def _day(timestamp) -> dt.date:
    return timestamp.date()


def _round(value, digits: int = 4):
    import math

    if value is None:
        return None
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


# --------------------------------------------------------------------------- the result
@dataclass
class FleetResult(Result):
    """The fleet view: one ``AxisView`` per machine axis, worst first.

    Attributes
    ----------
    axes : list of AxisView
        Sorted worst first (``worst_first``).
    source : str
        Where the readings came from.
    readings : DataFrame
        The validated readings.
    parameters : dict
        The workflow's parameters as given (logged with the run).
    probing : list of pipeline.steps.rotary_evidence.ProbingView
        Each rotary axis's play per visit from a store's probing records, trended.
    """

    axes: list
    source: str
    readings: object = field(repr=False)
    parameters: dict = field(default_factory=dict)
    probing: list = field(default_factory=list)

    @property
    def alerts(self) -> list[dict]:
        """Every alert of every axis (``kind``, ``message``, ``machine_id``, ``axis``), those
        of a rotary axis's probing plays too (``source``: probing)."""
        return axis_alerts([*self.axes, *self.probing])

    def write(self, out) -> dict[str, Path]:
        """The static site (``pipeline.reports.fleet_report``): ``index.html``, ``fleet.json`` and
        one page per axis, written together (all or nothing)."""
        from pipeline.reports.fleet_report import write_site

        self.files = write_site(self, out)
        return self.files

    def to_dict(self) -> dict:
        p = self.parameters
        limits = p.get("limits")
        return {"source": self.source, "as_of": p.get("as_of"),
                "threshold_um": p.get("threshold_um"),
                "threshold_arcsec": p.get("threshold_arcsec"),
                "limits": None if limits is None else str(limits) if isinstance(
                    limits, (str, os.PathLike)) else "given",
                "interval_days": p.get("interval_days"), "n_alerts": len(self.alerts),
                "axes": [v.to_dict() for v in self.axes],
                "probing": [p.to_dict() for p in self.probing]}

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``fleet``: parameters, per-axis figures, the site's files."""
        from pipeline.results import data_hash

        p = self.parameters
        params = {"data": self.source, "data_sha256": data_hash(self.readings),
                  **{k: p.get(k) for k in ("threshold_um", "threshold_arcsec", "interval_days",
                                           "warn_months", "alpha", "min_jump_sigma")},
                  "limits": self.to_dict()["limits"] or "",
                  "n_axes": len(self.axes)}
        metrics = {"n_alerts": float(len(self.alerts))}
        for v in self.axes:
            key = f"{v.machine_id}_{v.axis}"  # any id: the adapter makes valid metric names
            metrics[f"backlash_um_{key}"] = float(v.last["backlash_um"])
            metrics[f"slope_um_per_month_{key}"] = v.basis.trend.get("slope", float("nan"))
            metrics[f"days_to_next_visit_{key}"] = float(
                (v.next_visit_due - _day(v.last["date"])).days)
        return TrackingRecord("fleet", f"fleet {os.path.basename(self.source)}", params=params,
                              metrics=metrics, artifacts=sorted(set(self.files.values())),
                              artifact_path="fleet")


# --------------------------------------------------------------------------- the workflow
def fleet(data, *, format: str = "auto", threshold_um: float | None = None,
          threshold_arcsec: float | None = None, limits=None, as_of=None,
          interval_days: float = DEFAULT_INTERVAL_DAYS, warn_months: float = DEFAULTS.warn_months,
          alpha: float = DEFAULTS.alpha, min_jump_sigma: float = DEFAULTS.min_jump_sigma,
          out=None, store=None, stale_after_days: float = STALE_AFTER_DAYS) -> FleetResult:
    """One view of every machine axis of the fleet, worst first.

    Parameters
    ----------
    data : str, path, DataFrame or pipeline.steps.source.Source
        Readings with visits (``visit``, ``started_at``): a file, a fleet store or a frame as
        ``read`` returns it; from the runner, a Source with the test selection. Everything is
        computed on the whole data within the selection's dates (the fleet's wear rate of an
        axis without a trend comes from every axis; the store's records are read whatever the
        selection), and the view shows the machine axes the selection keeps: a selection never
        changes what is said about an axis it keeps.
    format : str, default 'auto'
        Input layout of a file.
    threshold_um : float, optional
        Backlash limit of the linear axes [um]: forecast the date each crosses it.
    threshold_arcsec : float, optional
        Backlash limit of the rotary axes [arcsec].
    limits : str, path or dict, optional
        Limits per machine and axis, each in its axis's unit (``pipeline.steps.limits``: a TOML
        file ``[M01] X_um = 8.0, C_arcsec = 40.0`` or a dict of that shape); an axis without
        one takes ``threshold_um`` or ``threshold_arcsec``.
    as_of : str, date or None, default today (UTC)
        The day the view is computed as of (``YYYY-MM-DD``): given, it sees the tests
        started by then; an axis whose next visit was due before it alerts ``overdue``, one
        whose crossing date lies before it ``limit_passed_unmeasured``.
    interval_days : float, default 90
        Maintenance interval [d]: the next visit is due this long after the last one at the
        latest.
    warn_months : float, default 6.0
        Alert when the crossing may come within this many months of the last visit [month].
    alpha : float, default 0.05
        Significance level of the trend tests and intervals, in (0, 0.5).
    min_jump_sigma : float, default 3.0
        A change point must move the level by this many standard errors.
    out : str or path, optional
        Folder to write the site into (``FleetResult.write``).
    store : str or path, optional
        The fleet store (folder or ``postgresql://`` URL) whose recorded forecasts and
        compensations to show (``AxisView.forecasts``, ``compensations``); default ``data``
        when it names a store.
    stale_after_days : float, default 2.0
        A watched axis (``backlash watch``) whose last sample is older than this [d] at the
        view's time (now, or the end of ``as_of``) alerts ``source_stale``, unless its
        WATCH.toml gives its own ``stale_after_s``.

    Returns
    -------
    FleetResult
        Its ``alerts`` are empty when nothing needs attention.

    Raises
    ------
    InputError
        A bad limits file (one line naming the key), a bad ``as_of``, ``out`` naming a file,
        or readings without dates or with one visit per axis only. The runner
        (``pipeline.runner.run``, ``bl.fleet``) refuses a parameter out of range first,
        naming it.
    """
    from features import iso230
    from features.visits import visit_backlash
    from models.condition.drift import two_visit_notes
    from models.condition.maintenance import analyse_axes
    from models.condition.reference import reference_corrections
    from pipeline.steps.dated_view import as_of_date, dated_view, kept_view
    from pipeline.steps.evidence import axes_evidence
    from pipeline.steps.limits import limit_notes, read_limits
    from pipeline.steps.rotary_evidence import probing_views

    day = as_of_date(as_of)
    per_axis = None if limits is None else read_limits(limits)
    if out is not None and Path(out).exists() and not Path(out).is_dir():
        raise InputError("is a file; expected a folder for the site", file=out, parameter="out")
    settings = MaintenanceSettings(threshold_um, threshold_arcsec, per_axis, alpha=alpha,
                                   min_jump_sigma=min_jump_sigma, warn_months=warn_months,
                                   interval_days=interval_days)
    source = Source.of(data, format)
    # today as any other day: a test dated ahead (a mistyped year) is no visit yet, and
    # taken for the latest one it would hide an overdue axis
    whole, notes = dated_view(source.all_readings(), day)
    readings = kept_view(source, whole, day)
    records = source.records(store=store)  # the store's, whatever the selection
    notes += limit_notes(per_axis, threshold_um, threshold_arcsec, source.data, readings,
                         limits, also=set(records.get("probing", {})))
    # once, for the series and the pages alike; on every axis, as the fleet's wear rate is
    parts = fleet_parts(whole, iso230.per_target(whole))
    visits = visit_backlash(whole, parts.stats, points=parts.points, figures=parts.figures)
    reference = reference_corrections(whole, parts.points)
    every = analyse_axes(visits, settings, as_of=day, reference=reference)
    laser = [f for f in every if source.keeps(f.machine_id, f.axis)]
    notes += [f"{f.machine_id} axis {f.axis}: a single visit, no trend" for f in laser
              if len(f.series.visits) < 2]
    notes += two_visit_notes([f.series for f in laser])
    evidence = axes_evidence(visits, records, day) if records else {}
    traced, more = trace_forecasts(visits, records, evidence, day, settings,
                                   keeps=source.keeps, reference=reference)
    notes += more
    probing, more = probing_views(  # a rotary axis's probing plays, beside or without a laser
        records, day, keeps=source.keeps, laser={(f.machine_id, f.axis) for f in laser},
        settings=settings)
    notes += more
    for text in notes:
        note(text)
    views = axis_views(laser, whole, parts, interval_days, records, evidence, as_of=day,
                       traced=traced, fleet=every)
    live_alerts(views, source.live(store), day, stale_after_days)
    for text in (n for v in views for n in v.evidence_notes):
        notes.append(text)
        note(text)
    if store is not None:  # the result names a store without its password
        from pipeline.store import redact

        store = redact(store)
    parameters = {"format": format, "threshold_um": threshold_um,
                  "threshold_arcsec": threshold_arcsec, "limits": limits,
                  "as_of": day.isoformat(), "interval_days": interval_days,
                  "warn_months": warn_months, "alpha": alpha, "min_jump_sigma": min_jump_sigma,
                  "out": out, "store": store, "stale_after_days": stale_after_days}
    result = FleetResult(views, source_of(source.data, whole), readings, parameters,
                         notes=notes, probing=probing)
    if out is not None:
        result.write(out)
    return result


def live_alerts(views: list, watched: list, day: dt.date, stale_after_days: float) -> None:
    """Each watched axis's last sample (``AxisView.live``), and ``source_stale`` on one silent
    longer than its limit at the view's time: now, or the end of an earlier ``as_of`` day.
    ``watched``: the store's watched axes (``Source.live``)."""
    latest = {}
    for a in watched:
        known = latest.get((a["machine_id"], a["axis"]))
        if known is None or (a["last_sample"] or "") > (known["last_sample"] or ""):
            latest[(a["machine_id"], a["axis"])] = a  # the latest of several watchers
    now = min(dt.datetime.now(dt.UTC), dt.datetime.combine(
        day + dt.timedelta(days=1), dt.time(), dt.UTC))
    for view in views:
        a = latest.get((view.machine_id, view.axis))
        if a is None:
            continue
        limit = a.get("stale_after_s") or stale_after_days * 86400.0
        view.live = {"last_sample": a["last_sample"], "stale_after_s": limit,
                     "source": a.get("source")}
        last = (None if a["last_sample"] is None else
                dt.datetime.fromisoformat(a["last_sample"]))
        if last is None or (now - last).total_seconds() > limit:
            silent = ("has sent no sample" if last is None else
                      f"has sent nothing since {a['last_sample'][:19]}Z")
            view.alerts.append({"kind": "source_stale", "message": (
                f"{view.machine_id} {view.axis}: the watched feed {silent} (limit "
                f"{limit / 3600:g} h); is the watcher or the controller down?")})


def trace_forecasts(visits, records: dict, evidence: dict, as_of: dt.date,
                    settings: MaintenanceSettings, keeps=None,
                    reference: dict | None = None) -> tuple[dict, list]:
    """The maintenance analysis (``models.condition.maintenance.analyse_axes``) of each machine
    axis whose store holds trace days sharing ``MIN_SHARED_DAYS`` days or more with its laser
    visits: the laser visits with the trace days shifted onto the laser's definition and
    weighted by their uncertainty, as ``drift --evidence laser,trace``
    (``pipeline.steps.evidence.with_evidence``; ``evidence`` what ``axes_evidence`` found).
    Returns {(machine_id, axis): AxisForecast} and the notes of the axes whose trace days are
    too few to be used (of those ``keeps(machine_id, axis)`` keeps, default all: the analysis
    pools the scatter over every axis given, so a selection's axes are given with the
    others; ``reference``: the axes' ``AxisReference``, ``analyse_axes``)."""
    if not records.get("trace"):
        return {}, []
    from models.condition.maintenance import analyse_axes
    from pipeline.steps.evidence import MIN_SHARED_DAYS, few_days_note, with_evidence

    joined, found, _ = with_evidence(visits, records, ("laser", "trace"), as_of,
                                     evidence=evidence)
    shared = {key: off["trace"]["days_in_common"] for key, off in found.items()
              if off.get("trace") is not None}
    used = {key for key, n in shared.items() if n >= MIN_SHARED_DAYS}
    notes = [few_days_note(key, "trace", n) for key, n in shared.items()
             if n < MIN_SHARED_DAYS and (keeps is None or keeps(*key))]
    analysed = analyse_axes(joined, settings, as_of=as_of, reference=reference) if used else []
    return {(f.machine_id, f.axis): f for f in analysed if (f.machine_id, f.axis) in used}, notes


def fleet_parts(readings, stats) -> _Parts:
    """The readings' per-target ISO statistics ``stats`` (``features.iso230.per_target``),
    their backlash points and per-test figures, computed once for the series and the pages."""
    from features import iso230
    from features.targets import targets_of

    return _Parts(stats, targets_of(stats, "auto", readings.attrs.get("source", "readings")),
                  iso230.axis_figures(readings, stats))


def axis_views(laser: list, readings, parts: _Parts, interval_days: float,
               records: dict | None = None, evidence: dict | None = None,
               as_of: dt.date | None = None, traced: dict | None = None,
               fleet: list | None = None) -> list[AxisView]:
    """One ``AxisView`` per analysed axis ``laser`` (``AxisForecast`` of its laser visits),
    worst first, each with its page name and its place in the schedule
    (``models.condition.schedule``); ``parts`` the readings' statistics, points and figures
    (``fleet_parts``), ``records`` the store's (``Source.records``), ``evidence`` each axis's
    other sources (``axes_evidence``), ``traced`` the axes' analyses with their trace days
    (``trace_forecasts``); with ``as_of`` the alert ``overdue`` of that day. ``fleet``: every
    axis of the fleet when ``laser`` are some of them (a selection's): the fleet's wear rates
    and the page names come from all of them."""
    from models.condition.schedule import fleet_wear_rates, overdue_alert
    from models.wear.wear_clock import usage_rates

    fleet = laser if fleet is None else fleet
    rates = fleet_wear_rates([f.series for f in fleet], parts.hours)
    usage = {(u["machine_id"], u["axis"]): u["hours_per_day"] for u in usage_rates(readings)}
    views = [_view(f, parts, interval_days, records or {}, evidence or {}, rates, usage,
                   (traced or {}).get((f.machine_id, f.axis))) for f in laser]
    for view in views if as_of is not None else ():
        view.as_of = as_of
        view.alerts.extend(a for a in [overdue_alert(view.next_visit_due,
                                                     view.next_visit_reason, as_of)] if a)
    views.sort(key=worst_first)
    names = page_names([(f.machine_id, f.axis) for f in fleet])
    for view in views:
        view.page = names[(view.machine_id, view.axis)]
    return views


def _view(laser, parts: _Parts, interval_days: float, records: dict, evidence: dict,
          rates: dict, usage: dict, with_trace=None) -> AxisView:
    """The view of the axis whose laser visits' analysis is ``laser``; its trend, crossing and
    forecast from ``with_trace`` (the laser visits with the trace days) when given."""
    from models.condition.schedule import next_visit_due, planned_rate
    from models.wear.axis_map import axis_wear_map

    s = laser.series
    key = (s.machine_id, s.axis)
    basis = with_trace if with_trace is not None else laser
    rate = planned_rate(basis.series, rates, usage.get(key))
    due, reason = next_visit_due(s.visits["date"].iloc[-1],
                                 float(s.visits["backlash_um"].iloc[-1]), s.threshold_um,
                                 interval_days, rate=rate, crossing=basis.crossing)
    wear, why = axis_wear_map(parts.points_of(key), s.visits["visit"].astype(str).iloc[
        s.segment_start:], parts.hours_of(key))
    view = AxisView(laser, due, reason, with_trace, wear, why, last_iso(s, parts),
                    forecasts=[dated(f, s, parts) for f in records.get("forecast", {}).get(
                        key, [])],
                    compensations=records.get("compensation", {}).get(key, []),
                    fleet_rate=rate, voided=records.get("voided", {}).get(key, []))
    if key in evidence:  # a store: the other evidence of the axis's backlash
        view.evidence, view.offsets, view.evidence_notes = evidence[key]
    return view


def dated(record: dict, s, parts: _Parts) -> dict:
    """A forecast with the day it is for: its own, else the day the axis's operating hours
    reach the forecast's hours (``models.condition.schedule.date_at_hours``, over the visits
    since the last change point)."""
    import numpy as np

    from models.condition.schedule import date_at_hours

    if record["for_date"] is not None or record["operating_hours"] is None or parts.hours is None:
        return record
    seg = s.visits.iloc[s.segment_start:]
    hours = [parts.hours.get((s.machine_id, s.axis, str(v)), np.nan) for v in seg["visit"]]
    when = date_at_hours(seg["date"], hours, record["operating_hours"], origin=s.origin)
    if when is None:
        return record
    return {**record, "for_date": _day(when).isoformat(), "for_date_estimated": True}


def worst_first(view: AxisView) -> tuple:
    """Sort key (``models.condition.schedule.priority``): above the threshold, past the limit
    unmeasured, other alerts, none; then the earliest next visit due, the earliest crossing
    date (none last), the highest backlash now, machine and axis."""
    from models.condition.schedule import priority

    return priority([a["kind"] for a in view.alerts], view.next_visit_due,
                    view.forecast.crossing[0], view.last["backlash_um"], view.machine_id,
                    view.axis)


def page_names(keys: list[tuple[str, str]]) -> dict[tuple[str, str], str]:
    """``<machine>_<axis>.html`` per machine axis ``(machine_id, axis)``, characters other
    than letters, digits, ``.``, ``-`` and ``_`` replaced by ``_``; a name taken twice gets
    ``-2``, ``-3``... in the order of machine and axis (not worst first), so an axis keeps
    its page's name from one day to the next and whatever the selection."""
    names, taken = {}, set()
    for machine_id, axis in sorted(set(keys)):
        stem = re.sub(r"[^\w.-]", "_", f"{machine_id}_{axis}", flags=re.ASCII).lstrip(".")
        name, k = f"{stem}.html", 2
        while name.lower() in taken or name == "index.html":
            name, k = f"{stem}-{k}.html", k + 1
        taken.add(name.lower())
        names[(machine_id, axis)] = name
    return names


# --------------------------------------------------------------------------- per-axis figures
@dataclass
class _Parts:
    """What the per-axis figures read, computed once for the fleet and looked up by machine
    axis (and visit): per-target ISO statistics, backlash points, per-test figures, hours."""

    stats: object
    points: object
    figures: object

    def __post_init__(self):
        from features.visits import SERIES_KEYS, VISIT_KEYS

        self._stats_rows = _rows(self.stats, VISIT_KEYS)
        self._figure_rows = _rows(self.figures, VISIT_KEYS)
        self.points = self.points[self.points["interior"].to_numpy()]
        self._point_rows = _rows(self.points, SERIES_KEYS)
        hours = (self.stats.groupby(list(VISIT_KEYS), observed=True)["operating_hours"].mean()
                 if "operating_hours" in self.stats else None)
        self.hours = None if hours is None or hours.isna().all() else {
            tuple(map(str, k)): float(h) for k, h in hours.items()}

    def stats_at(self, key: tuple):
        return _take(self.stats, self._stats_rows, key)

    def figures_at(self, key: tuple):
        return _take(self.figures, self._figure_rows, key)

    def points_of(self, key: tuple):
        return _take(self.points, self._point_rows, key)

    def hours_of(self, key: tuple) -> dict | None:
        """The operating hours [h] per visit of machine axis ``key``; None when the readings
        carry none."""
        if self.hours is None:
            return None
        return {v: h for (m, a, v), h in self.hours.items() if (m, a) == key}


def _rows(frame, keys) -> dict:
    """Row positions of ``frame`` by the text of its ``keys`` columns."""
    groups = frame.groupby(list(keys), sort=False, observed=True).indices
    return {tuple(map(str, k)): rows for k, rows in groups.items()}


def _take(frame, rows: dict, key: tuple):
    """The rows of ``frame`` under ``key``, or None."""
    return frame.iloc[rows[key]] if key in rows else None


def last_iso(s, parts: _Parts) -> dict | None:
    """The last visit's ISO 230-2 chart: its first linear test (else its first test) per
    target, and the figures of every test of the visit."""
    key = (s.machine_id, s.axis, str(s.visits["visit"].iloc[-1]))
    stats = parts.stats_at(key)
    if stats is None:
        return None
    order = stats.assign(_lin=stats["method"] != "linear").sort_values(["_lin", "test_id"])
    test = order["test_id"].iloc[0]
    rows = stats[stats["test_id"] == test].sort_values("target")
    figures = parts.figures_at(key)
    return {"test_id": str(test), "method": str(rows["method"].iloc[0]),
            "visit": key[2], "unit": str(rows["unit"].iloc[0]),
            "position_unit": schema.position_unit(s.axis),
            "targets": {c: rows[c].to_numpy(float) for c in
                        ("target", "mean_up", "mean_down", "s_up", "s_down", "mean_bi", "B_i")},
            "figures": [] if figures is None else figures.to_dict("records")}
