"""One view of the fleet: every machine axis's backlash now, its trend, when it crosses the
limit, when it is next due, its alerts, worst first; a static site that opens from disk.

>>> import backlash as bl
>>> view = bl.fleet("readings.csv", threshold_um=8.0, out="fleet/")   # doctest: +SKIP
>>> view.axes[0].to_json()["next_visit_due"]                          # doctest: +SKIP

Per machine axis (``AxisView``): the visit series (``features.visits.visit_backlash``: the
axis's backlash ``backlash_um`` by its measuring system, docs/backlash.md), its drift
(``models.drift.analyse_series``: change points, Theil-Sen trend since the last one, the date
the threshold is crossed with its interval, alerts), the date the next visit is due, the
forecast band, the wear-rate map since the last change point (``models.wear.wear_map.WearMap``) and
the ISO 230-2 chart of the last visit (``features.iso230``).

Rules (docs/fleet.md):

- **next visit due** = the earlier of (last visit + ``interval_days``) and the early end of the
  crossing interval (the first day the upper prediction band of a future visit reaches the
  threshold; the crossing date itself where the band gives no early end); the last visit's date
  (due now) when the axis is already at or above the threshold. Never before the last visit.
  An axis with one visit since its last change point (an adjustment just before its latest
  visit, or a single visit) has no trend: its crossing is estimated from its level and the
  fleet's wear rate (``fleet_wear_rates``: the upper ``FLEET_RATE_QUANTILE`` of the rates of
  the axes of its unit with a trend, per operating hour times the axis's own usage, else per
  month), never "due now" because of the drop.
- **worst first**: axes at or above the threshold, then other alerting axes, then the rest;
  within each group the earliest next visit due, then the earliest crossing date (none last),
  then the highest backlash now, then machine and axis.
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
from pipeline.results import Result, TrackingRecord, axis_alerts
from pipeline.steps.parameters import (
    ALPHA,
    AS_OF,
    FORMAT,
    LIMITS,
    MIN_JUMP_SIGMA,
    THRESHOLD_ARCSEC,
    THRESHOLD_UM,
    WARN_MONTHS,
    Param,
    python_only,
    readings,
)
from pipeline.steps.source import Source
from pipeline.workflows import check_params, source_of
from pipeline.workflows.constraints import Interval

DEFAULT_INTERVAL_DAYS = 90.0
# The forecast is drawn one visit interval ahead, further up to the crossing date but never
# more than this many months past the last visit.
FORECAST_CAP_MONTHS = 24.0
FORECAST_STEPS = 40
MIN_WEAR_VISITS = 3  # visits since the last change point a wear-rate map needs
# The fleet's wear rate an axis without a trend of its own is planned with: a high quantile of
# the rates of the fleet's axes, as the axis may wear as fast as most of them.
FLEET_RATE_QUANTILE = 0.9


# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--as-of", "2026-06-30"],
    {"data": "{twin}", "as_of": "2026-06-30"},
)

PARAMETERS = {
    "data": readings("readings with several visits per machine axis (visit, started_at)"),
    "format": FORMAT,
    "threshold_um": THRESHOLD_UM,
    "threshold_arcsec": THRESHOLD_ARCSEC,
    "limits": LIMITS,
    "as_of": AS_OF,
    "interval_days": Param((Interval(Real, 0, None, closed="neither"),),
                           "maintenance interval [days]: the next visit is due this long after "
                           "the last one at the latest", metavar="D"),
    "warn_months": WARN_MONTHS,
    "alpha": ALPHA,
    "min_jump_sigma": MIN_JUMP_SIGMA,
    "out": Param((str, os.PathLike, None), "write the fleet site into DIR (index.html, one page "
                 "per axis, fleet.json); it opens from disk", metavar="DIR", output="folder"),
    "store": python_only(str, os.PathLike, None),
    "stale_after_days": Param((Interval(Real, 0, None, closed="neither"),),
                              "an axis whose watched feed (backlash watch) has sent no sample "
                              "for this long alerts source_stale, unless its WATCH.toml says "
                              "(stale_after_s)", metavar="D"),
}
# A watched axis silent this long [d] is stale: a weekend without production is not.
STALE_AFTER_DAYS = 2.0


# --------------------------------------------------------------------------- one axis
@dataclass
class AxisView:
    """Everything the fleet view shows of one machine axis.

    Attributes
    ----------
    series : models.drift.DriftSeries
        The visits (``backlash_um``, ``backlash_u_um``, ``sigma_um`` [um], ``t_month``), change
        points, trend [um/month], threshold crossing [months since the first visit], alerts.
    next_visit_due : datetime.date
        When the axis should next be measured (module docstring).
    next_visit_reason : str
        Which rule set it: ``above_threshold``, ``crossing``, ``fleet_rate`` or ``interval``.
    as_of : datetime.date or None
        The day the view is computed as of (``days_overdue`` counts to it).
    fleet_rate : dict or None
        For an axis with one visit since its last change point: the wear rate it is planned
        with, ``per_day`` [um/d, arcsec/d for a rotary axis] and ``basis`` (``operating hours``:
        the fleet's rate per hour times the axis's hours per day; ``calendar``: per month).
    forecast : dict or None
        The prediction band ahead: ``days`` since the first visit, ``fit``, ``low``, ``high``
        [um]; None with fewer than two visits since the last change point.
    trend_line : dict or None
        The Theil-Sen line since the last change point: ``days``, ``fit`` [um].
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
        (``models.evidence.offset``: ``value``, ``u`` [um], ``days_in_common``), or None
        without a laser visit near any of its points.
    evidence_notes : list of str
        Why a source has no offset.
    voided : list of dict
        The axis's voided tests in a store (``visit``, ``test_id``, ``at``, ``user_name``,
        ``reason``: ``backlash void``); no reader reads them.
    analysis : models.drift.DriftSeries or None
        With trace days in a store sharing ``MIN_SHARED_DAYS`` days with the laser: the
        analysis of the laser visits with the trace days shifted onto the laser's definition
        (``trace_analyses``), which the trend, change points, crossing, alerts, next visit and
        forecast come from; None when they come from the laser visits alone (``series``).
    live : dict or None
        A watched axis (``backlash watch``): ``last_sample`` (ISO, UTC), ``stale_after_s``
        (the silence it alerts ``source_stale`` past [s]), ``source``; None when not watched.
    """

    series: object
    next_visit_due: dt.date
    next_visit_reason: str
    forecast: dict | None = None
    trend_line: dict | None = None
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
    analysis: object = None
    live: dict | None = None

    @property
    def basis(self):
        """The series the trend, crossing, alerts and forecast come from."""
        return self.analysis if self.analysis is not None else self.series

    @property
    def forecast_uses(self) -> list[str]:
        """The sources of the points the forecast used: ``laser``, and ``trace``."""
        return ["laser", "trace"] if self.analysis is not None else ["laser"]

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

    @property
    def crossing_days(self) -> tuple:
        """Crossing (date, early, late) in days since the first visit, None where unknown."""
        from features.visits import DAYS_PER_MONTH

        shift = _days_between(self.series.origin, self.basis.origin)
        return tuple(None if t is None else t * DAYS_PER_MONTH + shift
                     for t in self.basis.crossing)

    def to_json(self) -> dict:
        """The axis as ``--json`` prints it (docs/fleet.md lists every key and its unit)."""
        from features.visits import DAYS_PER_MONTH
        from pipeline.store.records import summary

        s, v, b = self.series, self.series.visits, self.basis
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
            "crossing_date": b.date_at(b.crossing[0]),
            "crossing_interval": [b.date_at(b.crossing[1]), b.date_at(b.crossing[2])],
            "forecast_uses": self.forecast_uses,
            "forecast_offset_um": self.forecast_offset(),
            **b.forecast_json(),
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
        off = self.offsets.get("trace") if self.analysis is not None else None
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
        Sorted worst first (module docstring).
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

    def to_json(self) -> dict:
        p = self.parameters
        limits = p.get("limits")
        return {"source": self.source, "as_of": p.get("as_of"),
                "threshold_um": p.get("threshold_um"),
                "threshold_arcsec": p.get("threshold_arcsec"),
                "limits": None if limits is None else str(limits) if isinstance(
                    limits, (str, os.PathLike)) else "given",
                "interval_days": p.get("interval_days"), "n_alerts": len(self.alerts),
                "axes": [v.to_json() for v in self.axes],
                "probing": [p.to_json() for p in self.probing]}

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``fleet``: parameters, per-axis figures, the site's files."""
        from pipeline.results import data_hash

        p = self.parameters
        params = {"data": self.source, "data_sha256": data_hash(self.readings),
                  **{k: p.get(k) for k in ("threshold_um", "threshold_arcsec", "interval_days",
                                           "warn_months", "alpha", "min_jump_sigma")},
                  "limits": self.to_json()["limits"] or "",
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
          interval_days: float = DEFAULT_INTERVAL_DAYS, warn_months: float = 6.0,
          alpha: float = 0.05, min_jump_sigma: float = 3.0, out=None,
          store=None, stale_after_days: float = STALE_AFTER_DAYS) -> FleetResult:
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
        started by then; an axis whose next visit was due before it alerts ``overdue``, one whose crossing
        date lies before it ``limit_passed_unmeasured``.
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
        A parameter out of range (naming it), a bad limits file (one line naming the key),
        ``out`` naming a file, or readings without dates or with one visit per axis only.
    """
    values = {"format": format, "threshold_um": threshold_um,
              "threshold_arcsec": threshold_arcsec, "limits": limits, "as_of": as_of,
              "interval_days": interval_days, "warn_months": warn_months, "alpha": alpha,
              "min_jump_sigma": min_jump_sigma, "out": out, "store": store,
              "stale_after_days": stale_after_days}
    check_params(PARAMETERS, values, "fleet")
    from pipeline.steps.dated_view import as_of_date, dated_view, kept_view
    from pipeline.steps.limits import limit_notes, read_limits

    day = as_of_date(as_of)
    values["as_of"] = day.isoformat()
    per_axis = None if limits is None else read_limits(limits)
    if out is not None and Path(out).exists() and not Path(out).is_dir():
        raise InputError("is a file; expected a folder for the site", file=out, parameter="out")
    from features import iso230
    from features.visits import visit_backlash
    from models.drift import analyse_visits, two_visit_notes

    source = Source.of(data, format)
    # today as any other day: a test dated ahead (a mistyped year) is no visit yet, and
    # taken for the latest one it would hide an overdue axis
    whole, notes = dated_view(source.all_readings(), day)
    readings = kept_view(source, whole, day)
    from pipeline.steps.rotary_evidence import probed_axes

    notes += limit_notes(per_axis, threshold_um, threshold_arcsec, source.data, readings,
                         limits, also=probed_axes(source.store if store is None else store))
    # once, for the series and the pages alike; on every axis, as the fleet's wear rate is
    parts = fleet_parts(whole, iso230.per_target(whole))
    visits = visit_backlash(whole, parts.stats, points=parts.points, figures=parts.figures)
    every = analyse_visits(visits, min_visits=1, threshold_um=threshold_um,
                           threshold_arcsec=threshold_arcsec, limits=per_axis, alpha=alpha,
                           min_jump_sigma=min_jump_sigma, warn_months=warn_months)
    series = [s for s in every if source.keeps(s.machine_id, s.axis)]
    notes += [f"{s.machine_id} axis {s.axis}: a single visit, no trend" for s in series
              if len(s.visits) < 2]
    notes += two_visit_notes(series)
    keeping = source.store if store is None else store  # the store of the records
    records = store_records(keeping)
    analyses, more = trace_analyses(visits, records, day, keeps=source.keeps,
                                    threshold_um=threshold_um,
                                    threshold_arcsec=threshold_arcsec, limits=per_axis,
                                    alpha=alpha, min_jump_sigma=min_jump_sigma,
                                    warn_months=warn_months)
    notes += more
    from pipeline.steps.rotary_evidence import probing_views

    probing, more = probing_views(  # a rotary axis's probing plays, beside or without a laser
        records, day, keeps=source.keeps, laser={(s.machine_id, s.axis) for s in series},
        threshold_um=threshold_um, threshold_arcsec=threshold_arcsec, limits=per_axis,
        alpha=alpha, min_jump_sigma=min_jump_sigma, warn_months=warn_months)
    notes += more
    for text in notes:
        note(text)
    views = axis_views(series, whole, parts, interval_days, records, as_of=day,
                       analyses=analyses, fleet=every)
    live_alerts(views, keeping, day, stale_after_days)
    for text in (n for v in views for n in v.evidence_notes):
        notes.append(text)
        note(text)
    if store is not None:  # the result names a store without its password
        from pipeline.store import redact

        values["store"] = redact(store)
    result = FleetResult(views, source_of(source.data, whole), readings, values, notes=notes,
                         probing=probing)
    if out is not None:
        result.write(out)
    return result


def live_alerts(views: list, store, day: dt.date, stale_after_days: float) -> None:
    """Each watched axis's last sample (``AxisView.live``), and ``source_stale`` on one silent
    longer than its limit at the view's time: now, or the end of an earlier ``as_of`` day."""
    from pipeline.store.live import live_axes

    if isinstance(store, (str, os.PathLike)) and "://" in str(store):
        return  # a PostgreSQL store keeps no watcher's state
    watched = {}
    for a in live_axes(store):
        known = watched.get((a["machine_id"], a["axis"]))
        if known is None or (a["last_sample"] or "") > (known["last_sample"] or ""):
            watched[(a["machine_id"], a["axis"])] = a  # the latest of several watchers
    now = min(dt.datetime.now(dt.UTC), dt.datetime.combine(
        day + dt.timedelta(days=1), dt.time(), dt.UTC))
    for view in views:
        a = watched.get((view.machine_id, view.axis))
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
            view.basis.alerts.append({"kind": "source_stale", "message": (
                f"{view.machine_id} {view.axis}: the watched feed {silent} (limit "
                f"{limit / 3600:g} h); is the watcher or the controller down?")})


def store_records(data) -> dict:
    """The records of a fleet store by kind and machine axis (``pipeline.store.records``);
    none for a file or a frame."""
    from pipeline.store import is_store, open_store
    from pipeline.store.records import read_records
    from pipeline.store.tables import TABLES

    if not isinstance(data, (str, os.PathLike)) or not is_store(data):
        return {}
    store = open_store(data, parameter="store")
    records = {kind: read_records(store, kind) for kind in TABLES}
    voids = store.voids()
    records["voided"] = {key: rows.drop(columns=["machine_id", "axis"]).to_dict("records")
                         for key, rows in voids.groupby(["machine_id", "axis"])}
    return records


def trace_analyses(visits, records: dict, as_of: dt.date, keeps=None,
                   **options) -> tuple[dict, list]:
    """The drift analysis (``models.drift.analyse_visits`` with ``options``) of each machine
    axis whose store holds trace days sharing ``MIN_SHARED_DAYS`` days or more with its laser
    visits: the laser visits with the trace days shifted onto the laser's definition and
    weighted by their uncertainty, as ``drift --evidence laser,trace``
    (``pipeline.steps.evidence.with_evidence``). Returns {(machine_id, axis): DriftSeries}
    and the notes of the axes whose trace days are too few to be used (of those
    ``keeps(machine_id, axis)`` keeps, default all: the analysis pools the scatter over every
    axis given, so a selection's axes are given with the others)."""
    if not records.get("trace"):
        return {}, []
    from models.drift import analyse_visits
    from pipeline.steps.evidence import MIN_SHARED_DAYS, few_days_note, with_evidence

    joined, found, _ = with_evidence(visits, records, ("laser", "trace"), as_of)
    shared = {key: off["trace"]["days_in_common"] for key, off in found.items()
              if off.get("trace") is not None}
    used = {key for key, n in shared.items() if n >= MIN_SHARED_DAYS}
    notes = [few_days_note(key, "trace", n) for key, n in shared.items()
             if n < MIN_SHARED_DAYS and (keeps is None or keeps(*key))]
    series = analyse_visits(joined, min_visits=1, **options) if used else []
    return {(s.machine_id, s.axis): s for s in series if (s.machine_id, s.axis) in used}, notes


def fleet_parts(readings, stats) -> _Parts:
    """The readings' per-target ISO statistics ``stats`` (``features.iso230.per_target``),
    their backlash points and per-test figures, computed once for the series and the pages."""
    from features import iso230
    from features.targets import targets_of

    return _Parts(stats, targets_of(stats, "auto", readings.attrs.get("source", "readings")),
                  iso230.axis_figures(readings, stats))


def axis_views(series: list, readings, parts: _Parts, interval_days: float,
               records: dict | None = None, as_of: dt.date | None = None,
               analyses: dict | None = None, fleet: list | None = None) -> list[AxisView]:
    """One ``AxisView`` per analysed series, worst first, each with its page name; ``parts``
    the readings' statistics, points and figures (``fleet_parts``), ``records`` what
    ``store_records`` found, ``analyses`` the axes' analyses with their trace days
    (``trace_analyses``); with ``as_of`` the alerts of that day (``as_of_alerts``).
    ``fleet``: the series of every axis of the fleet when ``series`` are some of them (a
    selection's): the fleet's wear rates and the page names come from all of them."""
    from models.wear.wear_clock import usage_rates

    fleet = series if fleet is None else fleet
    rates = fleet_wear_rates(fleet, parts)
    usage = {(u["machine_id"], u["axis"]): u["hours_per_day"] for u in usage_rates(readings)}
    views = []
    for s in series:
        analysis = (analyses or {}).get((s.machine_id, s.axis))
        views.append(_view(s, parts, interval_days, records or {},
                           _rate_of(analysis or s, rates, usage), as_of, analysis))
    for view in views if as_of is not None else ():
        view.as_of = as_of
        view.basis.alerts += as_of_alerts(view, as_of)
    views.sort(key=worst_first)
    names = page_names([(s.machine_id, s.axis) for s in fleet])
    for view in views:
        view.page = names[(view.machine_id, view.axis)]
    return views


def _view(s, parts: _Parts, interval_days: float, records: dict,
          fleet_rate: dict | None = None, as_of: dt.date | None = None,
          analysis=None) -> AxisView:
    """The view of laser series ``s``; its trend, crossing and forecast from ``analysis``
    (the laser visits with the trace days, ``trace_analyses``) when given."""
    basis = analysis or s
    due, reason = next_visit(s, interval_days, fleet_rate, by=basis)
    end = _forecast_end(basis, interval_days)
    wear, why = wear_map(s, parts)
    key = (s.machine_id, s.axis)
    forecasts = [dated(f, s, parts) for f in records.get("forecast", {}).get(key, [])]
    shift = _days_between(s.origin, basis.origin)
    view = AxisView(s, due, reason, _shifted(forecast(basis, end), shift),
                    _shifted(trend_line(basis, end), shift), wear, why,
                    last_iso(s, parts), forecasts=forecasts,
                    compensations=records.get("compensation", {}).get(key, []),
                    fleet_rate=fleet_rate, voided=records.get("voided", {}).get(key, []),
                    analysis=analysis)
    if records:  # a store: the other evidence of the axis's backlash
        from pipeline.steps.evidence import axis_offsets, evidence_frame

        view.evidence = evidence_frame(records, key, as_of)
        view.offsets, view.evidence_notes = axis_offsets(s.visits, view.evidence)
    return view


def fleet_wear_rates(series: list, parts: _Parts) -> dict[str, dict]:
    """The fleet's wear rates by unit (``um``, ``arcsec``): per axis with two visits or more
    since its last change point, the Theil-Sen slope of its backlash against operating hours
    (``per_hour``, where every visit has hours) and against time (``per_month``), negative
    slopes as 0; each the upper ``FLEET_RATE_QUANTILE`` over the fleet's axes (None without
    any)."""
    import numpy as np

    from features.readings.schema import deviation_unit
    from models.drift import trend

    found: dict[str, dict[str, list]] = {}
    for s in series:
        seg = s.visits.iloc[s.segment_start:]
        if len(seg) < 2 or not np.isfinite(s.trend.get("slope", np.nan)):
            continue
        mine = found.setdefault(deviation_unit(s.axis), {"per_hour": [], "per_month": []})
        mine["per_month"].append(max(s.trend["slope"], 0.0))
        hours = np.array([(parts.hours or {}).get((s.machine_id, s.axis, str(v)), np.nan)
                          for v in seg["visit"]])
        if np.isfinite(hours).all() and np.ptp(hours) > 0:
            mine["per_hour"].append(max(trend(hours, seg["backlash_um"])["slope"], 0.0))
    return {unit: {k: float(np.quantile(v, FLEET_RATE_QUANTILE)) if v else None
                   for k, v in rates.items()} for unit, rates in found.items()}


def _rate_of(s, rates: dict, usage: dict) -> dict | None:
    """The wear rate an axis with one visit since its last change point is planned with
    (``AxisView.fleet_rate``); None for an axis with a trend of its own or no fleet rate."""
    from features.readings.schema import deviation_unit
    from features.visits import DAYS_PER_MONTH

    if len(s.visits) - s.segment_start > 1:
        return None
    fleet = rates.get(deviation_unit(s.axis), {})
    per_day = usage.get((s.machine_id, s.axis))
    if fleet.get("per_hour") is not None and per_day is not None:
        return {"per_day": fleet["per_hour"] * per_day, "basis": "operating hours"}
    if fleet.get("per_month") is not None:
        return {"per_day": fleet["per_month"] / DAYS_PER_MONTH, "basis": "calendar"}
    return None


def dated(record: dict, s, parts: _Parts) -> dict:
    """A forecast with the day it is for: its own, else the day the axis's operating hours
    reach the forecast's hours, by the least-squares line of hours against time over the
    visits since the last change point (two visits with different hours at least)."""
    import numpy as np

    if record["for_date"] is not None or record["operating_hours"] is None or parts.hours is None:
        return record
    seg = s.visits.iloc[s.segment_start:]
    hours = np.array([parts.hours.get((s.machine_id, s.axis, str(v)), np.nan)
                      for v in seg["visit"]])
    days = (seg["date"] - s.visits["date"].iloc[0]).dt.total_seconds().to_numpy() / 86400
    keep = np.isfinite(hours)
    if keep.sum() < 2 or np.ptp(hours[keep]) <= 0:
        return record
    per_hour, start = np.polyfit(hours[keep], days[keep], 1)
    if per_hour <= 0:
        return record
    when = s.visits["date"].iloc[0] + dt.timedelta(days=float(start + per_hour
                                                              * record["operating_hours"]))
    return {**record, "for_date": _day(when).isoformat(), "for_date_estimated": True}


def as_of_alerts(view: AxisView, as_of: dt.date) -> list[dict]:
    """The alerts of the day ``as_of``: ``limit_passed_unmeasured`` when the crossing date
    lies before it (the axis has probably passed its limit since its last visit, unmeasured)
    and ``overdue`` when the next visit was due before it, with the days."""
    from models.drift import limit_passed_alert

    alerts = [a for a in [limit_passed_alert(view.basis, as_of)] if a is not None]
    late = (as_of - view.next_visit_due).days
    if late > 0:  # (view.days_overdue)
        alerts.append({"kind": "overdue", "message": (
            f"next visit was due on {view.next_visit_due.isoformat()} "
            f"({view.next_visit_reason.replace('_', ' ')}): {late} days overdue as of "
            f"{as_of.isoformat()}")})
    return alerts


def worst_first(view: AxisView) -> tuple:
    """Sort key: above the threshold, past the limit unmeasured, other alerts, none; then the
    earliest next visit due, the earliest crossing (none last), the highest backlash now,
    machine and axis."""
    kinds = {a["kind"] for a in view.alerts}
    group = (0 if "above_threshold" in kinds else 1 if "limit_passed_unmeasured" in kinds
             else 2 if kinds else 3)
    crossing = view.crossing_days[0]
    return (group, view.next_visit_due, crossing is None, crossing or 0.0,
            -float(view.last["backlash_um"]), view.machine_id, view.axis)


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


# --------------------------------------------------------------------------- per-axis rules
def next_visit(s, interval_days: float, fleet_rate: dict | None = None,
               by=None) -> tuple[dt.date, str]:
    """When the axis is next due and which rule set it (module docstring): ``above_threshold``
    (the last visit's date: due now), ``crossing`` (the early end of the crossing interval,
    before the interval ends), ``fleet_rate`` (the day the last level plus the fleet's wear
    rate ``fleet_rate`` reaches the threshold, before the interval ends) or ``interval``
    (last visit + ``interval_days``). The crossing is ``by``'s (the analysis with the trace
    days) when given; the last visit is always the laser's."""
    import pandas as pd

    last = s.visits["date"].iloc[-1]
    by_interval = _day(last + pd.Timedelta(days=float(interval_days)))
    level = float(s.visits["backlash_um"].iloc[-1])
    if s.threshold_um is not None and level >= s.threshold_um:
        return _day(last), "above_threshold"
    if s.threshold_um is not None and fleet_rate is not None and fleet_rate["per_day"] > 0:
        when = _day(last + pd.Timedelta(days=(s.threshold_um - level) / fleet_rate["per_day"]))
        if when < by_interval:
            return when, "fleet_rate"
    by = by or s
    early = by.crossing[1] if by.crossing[1] is not None else by.crossing[0]
    if early is not None:
        when = max(dt.date.fromisoformat(by.date_at(early)), _day(last))
        if when < by_interval:
            return when, "crossing"
    return by_interval, "interval"


def _forecast_end(s, interval_days: float) -> float:
    """Months since the first visit up to which the forecast is drawn: one interval past the
    last visit, or up to the crossing date, at most ``FORECAST_CAP_MONTHS`` past the last
    visit."""
    from features.visits import DAYS_PER_MONTH

    t_last = float(s.visits["t_month"].iloc[-1])
    end = t_last + interval_days / DAYS_PER_MONTH
    if s.crossing[0] is not None:
        end = max(end, min(s.crossing[0], t_last + FORECAST_CAP_MONTHS))
    return end


def _days_between(origin, later) -> float:
    """Days [d] from ``origin`` to ``later`` (two timestamps)."""
    return (later - origin).total_seconds() / 86400.0


def _shifted(curve: dict | None, days: float) -> dict | None:
    """A forecast or trend line drawn from another origin, ``days`` after the laser's first
    visit: its days counted from the laser's first visit."""
    if curve is None or days == 0:
        return curve
    return {**curve, "days": curve["days"] + days}


def forecast(s, end_month: float) -> dict | None:
    """The forecast from the last visit to ``end_month`` (``DriftSeries.forecast_curve``), in
    days since the first visit: ``low``/``high`` the interval of the next measurement (the
    band the pages draw), ``lost_motion_low``/``_high`` the axis's lost motion's; None
    without an interval (fewer than three visits since the last change point)."""
    from features.visits import DAYS_PER_MONTH

    curve = s.forecast_curve(end_month, FORECAST_STEPS)
    if curve is None:
        return None
    return {"days": curve["t_month"] * DAYS_PER_MONTH, "fit": curve["fit"],
            "low": curve["measurement_low"], "high": curve["measurement_high"],
            "lost_motion_low": curve["lost_motion_low"],
            "lost_motion_high": curve["lost_motion_high"]}


def trend_line(s, end_month: float) -> dict | None:
    """The Theil-Sen line from the first visit of the last segment to ``end_month``."""
    import numpy as np

    from features.visits import DAYS_PER_MONTH

    tr = s.trend
    if not np.isfinite(tr.get("slope", np.nan)):
        return None
    t = np.array([float(s.visits["t_month"].iloc[s.segment_start]), end_month])
    return {"days": t * DAYS_PER_MONTH, "fit": tr["intercept"] + tr["slope"] * t}


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


def _rows(frame, keys) -> dict:
    """Row positions of ``frame`` by the text of its ``keys`` columns."""
    groups = frame.groupby(list(keys), sort=False, observed=True).indices
    return {tuple(map(str, k)): rows for k, rows in groups.items()}


def _take(frame, rows: dict, key: tuple):
    """The rows of ``frame`` under ``key``, or None."""
    return frame.iloc[rows[key]] if key in rows else None


def wear_map(s, parts: _Parts) -> tuple[dict | None, str]:
    """The wear-rate map w(x) [um per 1000 h] of the axis, fitted by ``models.wear.wear_map.WearMap``
    on its interior backlash points since the last change point (position, operating hours and,
    when it varies, feed); (None, why) when that cannot be done."""
    import numpy as np
    import pandas as pd

    if parts.hours is None:
        return None, "the readings carry no operating hours: no wear-rate map"
    kept = set(s.visits["visit"].astype(str).iloc[s.segment_start:])
    if len(kept) < MIN_WEAR_VISITS:
        return None, (f"{len(kept)} visit(s) since the last change point; a wear-rate map needs "
                      f"{MIN_WEAR_VISITS}")
    points = parts.points_of((s.machine_id, s.axis))
    points = points[points["visit"].astype(str).isin(kept)] if points is not None else None
    if points is None or points.empty:
        return None, "no interior backlash points since the last change point"
    hours = [parts.hours.get((s.machine_id, s.axis, str(v)), np.nan) for v in points["visit"]]
    X = pd.DataFrame({"target": points["target"].to_numpy(float),
                      "operating_hours": np.asarray(hours, float)})
    if points["feed_mm_min"].nunique() > 1:
        X["feed_mm_min"] = points["feed_mm_min"].to_numpy(float)
    if X["operating_hours"].isna().any() or X["operating_hours"].nunique() < 2:
        return None, "operating hours missing or constant since the last change point"
    return _fit_wear(X, points["backlash_um"].to_numpy(float), sorted(kept)), ""


def _fit_wear(X, y, visits: list[str]) -> dict:
    from models.wear.wear_map import WearMap

    model = WearMap().fit(X, y)
    rate = model.wear_rate_map()
    return {"position_mm": rate["position_mm"].to_numpy(),
            "rate": rate["wear_rate_um_per_1000h"].to_numpy(),
            "low": rate["wear_rate_low"].to_numpy(), "high": rate["wear_rate_high"].to_numpy(),
            "n_points": len(y), "visits": visits, "n_control": str(model.n_control_)}


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
