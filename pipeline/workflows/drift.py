"""Backlash across maintenance visits: robust trend, change points, the date it crosses a
threshold, and (with a trained model) its residual and input drift.

>>> import backlash as bl
>>> result = bl.drift("readings.csv", threshold_um=4.0)   # doctest: +SKIP
>>> result.alerts                                         # doctest: +SKIP

``drift`` is the maintenance analysis of every machine axis
(``models.condition.maintenance``, the same as ``fleet``'s) and its report
(``pipeline.reports.drift_report``, which draws what the analysis computed); this module only
wires: the readings and a store's evidence through the ``Source``, the budget, the model.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from features import uncertainty as unc
from features.readings.errors import note
from models.condition.settings import DEFAULTS, MaintenanceSettings
from pipeline.results import Result, TrackingRecord, axis_alerts
from pipeline.steps.parameters import BUDGET, FORMAT, MAINTENANCE, MODEL, Param, readings
from pipeline.steps.source import Source, source_of

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--until", "2026-06-30", "--threshold-um", "8"],
    {"data": "{twin}", "until": "2026-06-30", "threshold_um": 8.0},
)

PARAMETERS = {
    "data": readings("readings with several visits (visit, started_at)"),
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "output folder for the report (optional with --json)",
                 output="folder"),
    **MAINTENANCE,  # the analysis drift and fleet share
    "model": Param((*MODEL, None), metavar="DIR"),
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
    "evidence": Param((str, list, tuple), metavar="SOURCES"),
    "store": Param((str, os.PathLike, None), metavar="STORE"),
}


@dataclass
class DriftResult(Result):
    """The drift of every machine axis with two or more visits.

    Attributes
    ----------
    series : list of models.condition.drift.DriftSeries
        One per machine axis: the visits (the axis's backlash ``backlash_um`` [um] by its
        measuring system, ``backlash_u_um`` and sigma [um], ``target_kind``; see
        ``features.visits.visit_backlash``), change points, Theil-Sen trend [um/month] since the
        last change point, threshold crossing and alerts; with a budget also each visit's
        expanded uncertainty ``backlash_U_um`` [um] and the changes ``within_uncertainty``.
    source : str
        Where the readings came from.
    readings : DataFrame
        The validated readings.
    parameters : dict
        The workflow's parameters as given (logged with the run).
    offsets : dict
        With ``evidence`` beyond the laser: per (machine_id, axis) the offset of each other
        source to the laser's backlash (``models.condition.evidence.offset``), None where it has no
        laser visit near.
    forecasts : list of models.condition.maintenance.AxisForecast
        The analysis of each series (its ``series``): trend line, forecast band, crossing and
        next visit on one time axis, up to the horizon the report draws.
    """

    series: list
    source: str
    readings: object = field(repr=False)
    parameters: dict = field(default_factory=dict)
    offsets: dict = field(default_factory=dict)
    forecasts: list = field(default_factory=list, repr=False)

    @property
    def alerts(self) -> list[dict]:
        """Every alert of every series (``kind``, ``message``, ``machine_id``, ``axis``)."""
        return axis_alerts(self.series)

    def write(self, out) -> dict[str, Path]:
        """``drift.png``, ``drift.html`` and ``drift.json`` (``pipeline.reports.drift_report``)."""
        from pipeline.reports.drift_report import write_drift_report

        self.files = write_drift_report(self.forecasts, out, source=self.source,
                                        notes=self.notes, as_of=self.parameters.get("as_of"))
        return self.files

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        series = [f.to_dict() for f in self.forecasts]
        others = [k for k in (self.parameters.get("evidence") or "laser").split(",")
                  if k != "laser"]
        for j, s in zip(series if others else (), self.series):  # each source's offset
            found = self.offsets.get((s.machine_id, s.axis), {})
            j["offsets_um"] = {k: None if found.get(k) is None else {
                "value": round(found[k]["value"], 4), "u": round(found[k]["u"], 4),
                "days_in_common": found[k]["days_in_common"]} for k in others}
        return clean_nan({"as_of": self.parameters.get("as_of"),
                          "evidence": self.parameters.get("evidence"), "series": series})

    @property
    def run_name(self) -> str:
        """The name of its MLflow run: ``drift`` and the data's file name."""
        return f"drift {os.path.basename(self.source)}"

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``drift``: parameters, per-series figures, the report files."""
        from pipeline.results import data_hash

        p = self.parameters
        model = p.get("model")
        limits = p.get("limits")
        params = {"data": self.source, "data_sha256": data_hash(self.readings),
                  "threshold_um": p.get("threshold_um"),
                  "threshold_arcsec": p.get("threshold_arcsec"),
                  "limits": "" if limits is None else str(limits) if isinstance(
                      limits, (str, os.PathLike)) else "given",
                  "model": "" if model is None else str(model) if isinstance(
                      model, (str, os.PathLike)) else type(model).__name__,
                  "alpha": p.get("alpha"), "min_jump_sigma": p.get("min_jump_sigma"),
                  "warn_months": p.get("warn_months"), "n_series": len(self.series),
                  "evidence": p.get("evidence") or "laser",
                  "uncertainty": "" if p.get("uncertainty") is None else str(
                      p["uncertainty"]) if isinstance(p["uncertainty"], (str, os.PathLike))
                  else "given"}
        metrics = {"n_alerts": float(sum(len(s.alerts) for s in self.series))}
        for s in self.series:
            key = f"{s.machine_id}_{s.axis}"  # any id: the adapter makes valid metric names
            metrics[f"backlash_um_{key}"] = float(s.visits["backlash_um"].iloc[-1])
            metrics[f"slope_um_per_month_{key}"] = s.trend.get("slope", float("nan"))
            metrics[f"n_change_points_{key}"] = float(len(s.change_points))
            if s.coverage_factor is not None:
                metrics[f"backlash_U_um_{key}"] = float(s.visits["backlash_U_um"].iloc[-1])
        return TrackingRecord("drift", self.run_name, params=params,
                              metrics=metrics, artifacts=list(self.files.values()),
                              artifact_path="drift")


def drift(data, *, format: str = "auto", threshold_um: float | None = None,
          threshold_arcsec: float | None = None, limits=None, as_of=None, model=None,
          warn_months: float = DEFAULTS.warn_months, alpha: float = DEFAULTS.alpha,
          min_jump_sigma: float = DEFAULTS.min_jump_sigma, uncertainty=None, evidence="laser",
          store=None) -> DriftResult:
    """Follow backlash across maintenance visits.

    The series of each machine axis is its backlash at each visit
    (``features.visits.visit_backlash``): the lost motion from pendulum minus linear tests with a
    direct measuring system, from the ISO reversal value |B_i| with an indirect one.

    Parameters
    ----------
    data : str, path, DataFrame or pipeline.steps.source.Source
        Readings with several visits (``visit``, ``started_at``): a file, a fleet store or a
        frame as ``read`` returns it; from the runner, a Source with the test selection. Each
        axis is computed as on the whole data within the selection's dates (a store's trace
        and ballbar records read whatever the selection) and the series of the machine axes
        the selection keeps are reported: a selection never changes what is said about an
        axis it keeps.
    format : str, default 'auto'
        Input layout of a file.
    threshold_um : float, optional
        Backlash limit of the linear axes [um]: forecast the date it is crossed.
    threshold_arcsec : float, optional
        Backlash limit of the rotary axes [arcsec].
    limits : str, path or dict, optional
        Limits per machine and axis, each in its axis's unit (``pipeline.steps.limits``); an axis
        without one takes ``threshold_um`` or ``threshold_arcsec``.
    as_of : str, date or None, default today (UTC)
        The day the drift is computed as of (``YYYY-MM-DD``): given, the tests started by
        then; a crossing date before it alerts ``limit_passed_unmeasured``.
    model : str, path or fitted predictor, optional
        Trained model (directory or object): monitor its residuals and inputs.
    warn_months : float, default 6.0
        Alert when the crossing may come within this many months of the last visit.
    alpha : float, default 0.05
        Significance level of the trend tests and intervals, in (0, 0.5).
    min_jump_sigma : float, default 3.0
        A change point must move the level by this many standard errors.
    uncertainty : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget (``experiments/data/paper_uncertainty.toml``): every visit gets
        ``backlash_U_um``, the expanded uncertainty of its backlash
        (``features.visits.axis_backlash``), and a step within the expanded uncertainty of the
        difference of two visits is a note, not an alert (``models.condition.drift``). Linear axes only.
    evidence : str or list of str, default 'laser'
        The sources of each axis's series: ``laser`` (the visits alone), ``trace`` (the lost
        motion of controller-trace days, ``monitor --store``), ``ballbar`` (the backlash of
        circular tests, ``circle --store``), a comma-separated list or ``all``. The laser
        visits are always in; another source's points are shifted by its offset to the laser
        (estimated from the days both measured, ``models.condition.evidence``) and left out, with a
        note, where it has none. The series' ``source`` column says where each point came
        from; a point of another source is named ``trace <day>`` or ``ballbar <plane>
        <visit>``.
    store : str or path, optional
        The fleet store (folder or ``postgresql://`` URL) holding the trace and ballbar
        records; default the store the readings came from (``data`` naming one).

    Returns
    -------
    DriftResult
        Its ``alerts`` are empty when nothing needs attention.

    Raises
    ------
    InputError
        Bad readings, an unreadable or non-physical budget, a budget for a rotary axis, a bad
        limits file or ``as_of``, an unknown evidence source, evidence beyond the laser
        without a fleet store. The runner (``pipeline.runner.run``, ``bl.drift``) refuses a
        parameter out of range first, naming it.
    """
    from features import iso230
    from features.targets import targets_of
    from features.visits import SERIES_KEYS, visit_backlash
    from models.condition import drift as drift_model
    from models.condition import monitoring
    from models.condition.maintenance import analyse_axes
    from models.condition.reference import reference_corrections
    from pipeline.steps.dated_view import as_of_date, dated_view, kept_view
    from pipeline.steps.evidence import sources_of
    from pipeline.steps.limits import limit_notes, read_limits

    sources = sources_of(evidence)
    source = Source.of(data, format)
    records = _evidence_records(source, store, sources)
    day = as_of_date(as_of)
    per_axis = None if limits is None else read_limits(limits)
    budget = None if uncertainty is None else unc.checked_budget(uncertainty)
    settings = MaintenanceSettings(threshold_um, threshold_arcsec, per_axis, alpha=alpha,
                                   min_jump_sigma=min_jump_sigma, warn_months=warn_months)
    predictor = model
    if isinstance(model, (str, os.PathLike)):
        from models.serving.registry import load_model

        predictor = load_model(model)
    # today as any other day: a test dated ahead (a mistyped year) is no visit yet, and
    # taken for the latest one it would hide an overdue axis
    whole, notes = dated_view(source.all_readings(), day)
    readings = kept_view(source, whole, day)
    notes += limit_notes(per_axis, threshold_um, threshold_arcsec, source.data, readings,
                         limits)
    # every axis computed as without a selection (the scatter is pooled over the fleet);
    # the selected axes reported
    stats = iso230.per_target(whole)
    points = targets_of(stats, "auto", whole.attrs.get("source", "readings"), budget,
                        parts=True)
    visits = visit_backlash(whole, stats, budget=budget, points=points)
    reference = reference_corrections(whole, points)
    k = None if budget is None else budget.coverage_factor
    offsets = {}
    if records is not None:
        from pipeline.steps.evidence import with_evidence

        visits, offsets, more = with_evidence(visits, records, sources, day, k,
                                              keeps=source.keeps)
        offsets = {key: o for key, o in offsets.items() if source.keeps(*key)}
        notes += more
    counts = source.kept(visits).groupby(list(SERIES_KEYS)).size()
    notes += [f"{m} axis {a}: a single visit, no drift analysis"
              for (m, a), c in counts.items() if c < 2]
    for text in notes:
        note(text)
    forecasts = [f for f in analyse_axes(visits, settings, as_of=day, min_visits=2,
                                         coverage_factor=k, reference=reference)
                 if source.keeps(f.machine_id, f.axis)]
    series = [f.series for f in forecasts]
    for text in drift_model.two_visit_notes(series):
        notes.append(text)
        note(text)
    if predictor is not None:
        drift_model.attach_model(series, monitoring.monitor_model(predictor, whole))
    for s in series:
        for w in s.within_uncertainty:
            text = (f"{s.machine_id} axis {s.axis}: {drift_model.WITHIN_KINDS[w['kind']]} of "
                    f"{w['jump_um']:+.2f} {s.unit} at visit "
                    f"{w['visit']} is within the measurement uncertainty (U = "
                    f"{w['U_um']:.2f} {s.unit}, k = {k:g}): not an alert")
            notes.append(text)
            note(text)
    if store is not None:  # the result names a store without its password
        from pipeline.store import redact

        store = redact(store)
    parameters = {"format": format, "threshold_um": threshold_um,
                  "threshold_arcsec": threshold_arcsec, "limits": limits,
                  "as_of": day.isoformat(), "model": model, "warn_months": warn_months,
                  "alpha": alpha, "min_jump_sigma": min_jump_sigma, "uncertainty": uncertainty,
                  "evidence": ",".join(sources), "store": store}
    return DriftResult(series, source_of(source.data, whole), readings, parameters,
                       notes=notes, offsets=offsets, forecasts=forecasts)


def _evidence_records(source: Source, store, sources: tuple) -> dict | None:
    """The trace and ballbar records ``sources`` ask for, read through ``source`` from
    ``store`` (default the store the readings came from); None for the laser alone.

    Raises
    ------
    InputError
        Sources beyond the laser without a fleet store to read them from.
    """
    if sources == ("laser",):
        return None
    from features.readings.errors import InputError
    from pipeline.steps.evidence import KEYS

    if source.records_store(store) is None:
        raise InputError("trace and ballbar evidence is read from a fleet store; give the "
                         "store as data or as store", parameter="evidence")
    return source.records(KEYS, store=store)
