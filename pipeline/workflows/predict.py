"""Predict backlash with a trained model: at every interior target of new tests (linear tests
suffice), or at the points of a plan (a visit not measured yet: targets and conditions).

>>> import backlash as bl
>>> forecast = bl.predict("model/", plan="plan.csv")           # doctest: +SKIP
>>> forecast.predictions[["target", "backlash_um", "backlash_low_um"]]   # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from features.readings.errors import InputError, note
from models.registry import TrainedModel
from pipeline.results import Result
from pipeline.steps.parameters import FORMAT, READINGS, Param, python_only, readings
from pipeline.workflows import readings_of, source_of

if TYPE_CHECKING:
    import pandas as pd

KEYS = ("machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target")
INTERVAL = ("backlash_low_um", "backlash_high_um")
# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (  # the model answers for the axis it was trained on (M01 X) only
    ["{model}", "{two}", "--axis", "X", "--out", "{side}/p.csv"],
    {"model": "{model}", "data": "{two}", "axis": "X", "out": "{side}/p.csv"},
)

PARAMETERS = {
    "model": Param((str, os.PathLike, TrainedModel), "model directory written by backlash "
                   "train", flag="DIR"),
    "data": readings("readings file (linear tests suffice) or a plan table (target and "
                     "conditions, no deviations)", accepts=(*READINGS, None)),
    "plan": python_only(*READINGS, None),  # the command line reads a plan as its DATA
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "predictions to write", metavar="PRED.csv",
                 required=True, output="file"),
    "store": Param((str, os.PathLike, None), "fleet store (folder or postgresql:// URL) to "
                   "record the forecast in, per machine axis; backlash fleet shows the last one",
                   metavar="STORE"),
}


@dataclass
class PredictionResult(Result):
    """Predicted backlash [um] per point.

    Attributes
    ----------
    predictions : DataFrame
        The point's keys (or the plan's columns) and ``backlash_um``; a predictor with an
        interval adds ``backlash_low_um`` and ``backlash_high_um`` (95 %). Negative
        predictions are clipped at 0 (backlash is a magnitude). ``extrapolated`` names the
        point's inputs outside the ranges the model was trained on (``feed_mm_min;target``),
        empty when none (``models.serving.trained_ranges``); a fleet model's ``borrowed``
        says how it forecast a machine axis it was not trained on (empty for its own). With a
        rotary axis among the points a ``unit`` column says each row's unit (``arcsec`` for a
        rotary axis).
    model : str
        Registry name of the predictor.
    recorded : pipeline.store.records.Recorded or None
        What was recorded in the fleet store (``store``), else None.
    """

    predictions: pd.DataFrame
    model: str
    recorded: object = None

    @property
    def has_interval(self) -> bool:
        return INTERVAL[0] in self.predictions

    def write(self, out) -> dict[str, Path]:
        """Write the predictions as a CSV file ``out``."""
        from features.readings.fileio import atomic_path

        if not str(out).lower().endswith(".csv"):
            raise InputError("expected a .csv file name", file=out, parameter="out")
        with atomic_path(out) as tmp:
            self.predictions.to_csv(tmp, index=False)
        self.files = {"predictions": Path(out)}
        return self.files

    def to_json(self) -> dict:
        from features.readings.fileio import clean_nan

        out = self.predictions
        dates = {c: str for c in out.columns if str(out[c].dtype).startswith("datetime")}
        return clean_nan({"model": self.model, "predictions": out.astype(dates)
                          .to_dict("records")})

    def tracking_record(self):
        from pipeline.results import TrackingRecord

        values = self.predictions["backlash_um"]
        return TrackingRecord(
            experiment="predict", run_name=f"predict {self.model}",
            params={"model": self.model, "points": len(values), "interval": self.has_interval},
            metrics={"backlash_min_um": values.min(), "backlash_mean_um": values.mean(),
                     "backlash_max_um": values.max()},
            artifacts=list(self.files.values()))


def predict(model, data=None, *, plan=None, format: str = "auto",
            store=None) -> PredictionResult:
    """Backlash [um] from a trained model at the points of new tests or of a plan.

    Parameters
    ----------
    model : str, path-like or TrainedModel
        A model directory written by ``train`` (or the model ``load_model`` returns).
    data : str, path-like or DataFrame, optional
        Readings (linear tests suffice: they give the deviation inputs). A CSV/Parquet file
        without deviations is read as a plan.
    plan : str, path-like or DataFrame, optional
        A plan table: targets and conditions of a visit not measured yet
        (``features.readings.plan``). Give ``data`` or ``plan``.
    format : str
        Input layout of ``data`` (default: detect).
    store : str or path-like, optional
        A fleet store (folder or ``postgresql://`` URL) to record the forecast in, one record
        per machine axis and visit (``pipeline.store.records.forecast_records``): the points,
        the day (``started_at``) and operating hours it is for, the model and, for a wear map,
        its wear-rate map. Recording the same forecast again changes nothing.

    Returns
    -------
    PredictionResult
        Every input with points outside the range the model was trained on gets a note
        naming the input, the points and the trained range (a ``BacklashWarning``, also in
        ``notes``), and the points say which in ``extrapolated``. A forecasting model (the wear
        map) extrapolates in operating hours by design: its hours get a note (with the
        extrapolation factor) only beyond ``models.serving.FORECAST_HORIZON`` training spans
        past the last trained hour.

    Raises
    ------
    InputError
        Neither or both of ``data`` and ``plan``; a point the model may not answer for (a
        machine axis it was not trained on, an axis of another unit; a fleet model forecasts
        another axis of a unit it has a fleet of, with a note: ``models.serving.answerable``),
        or a model that does not record which axes it was trained on; a ``store`` that does
        not exist or cannot be written, or points without ``machine_id`` and ``axis`` to
        record them by (nothing is recorded).
    """
    import pandas as pd

    from features.readings.plan import is_plan, plan_points, read_plan
    from features.table import prediction_inputs
    from models.registry import load_model
    from models.serving import answerable, predictions

    if (data is None) == (plan is None):
        raise InputError("give the readings (data) or a plan, not both", parameter="data")
    if store is not None:  # before any work: a store that cannot take the records
        from pipeline.store.records import open_for_records

        store = open_for_records(store)
    trained = model if isinstance(model, TrainedModel) else load_model(model)
    if plan is None and isinstance(data, (str, os.PathLike)) and format in (
            "auto", "canonical") and is_plan(data):
        plan = data
    if plan is not None:
        source = str(plan) if isinstance(plan, (str, os.PathLike)) else "plan"
        table = (read_plan(plan) if isinstance(plan, (str, os.PathLike))
                 else plan_points(plan, source))
        rows = range(1, len(table) + 1) if source == "plan" else None  # a frame's rows
        answerable(trained, table, source, rows, parameter="model")  # before what it lacks
        inputs = plan_inputs(table, trained, source)
        keys = list(table.columns)
    else:
        readings = readings_of(data, format)
        source = source_of(data, readings)
        inputs = prediction_inputs(readings, trained.feature_names_)
        keys, rows = list(KEYS), None
        check_forecast(trained, inputs, source, plan=False)
    predicted, lines = predictions(trained, inputs, source, rows, parameter="model")
    out = with_units(pd.concat([inputs[keys].reset_index(drop=True), predicted], axis=1))
    for line in lines:
        note(line)
    result = PredictionResult(predictions=out, model=trained.name, notes=lines)
    if store is not None:
        points = out.copy()
        if "operating_hours" not in points and "operating_hours" in inputs:
            points["operating_hours"] = inputs["operating_hours"].to_numpy(float)
        if plan is None and "started_at" in readings:
            points["started_at"] = _visit_starts(readings, inputs)
        result.recorded = record_forecast(store, points, trained, model, source)
    return result


def with_units(out: pd.DataFrame) -> pd.DataFrame:
    """``out`` with a ``unit`` column before ``backlash_um`` when a rotary axis is among its
    points: their backlash is in arcsec (``features.readings.schema.deviation_unit``), the
    columns keep their names."""
    from features.readings.schema import deviation_unit, is_rotary

    axes = out["axis"].astype(str) if "axis" in out else None
    if axes is None or not axes.map(is_rotary).any():
        return out
    out = out.copy()
    out.insert(out.columns.get_loc("backlash_um"), "unit", axes.map(deviation_unit))
    return out


def _visit_starts(readings: pd.DataFrame, inputs: pd.DataFrame):
    """Per point of ``inputs``, the start of its visit (the earliest ``started_at`` of the
    machine axis's tests of that visit)."""
    keys = ["machine_id", "axis", "visit"]
    starts = readings.groupby(keys, observed=True)["started_at"].min()
    first = {tuple(map(str, k)): v for k, v in starts.items()}
    return [first.get(k) for k in inputs[keys].astype(str).itertuples(index=False, name=None)]


def record_forecast(store, points: pd.DataFrame, trained, model, source: str):
    """Record the forecast ``points`` in ``store`` (``pipeline.store.records``), naming the model by
    its registry name, its directory and the SHA-256 of its ``model.json``; a wear map's
    wear-rate map per machine axis goes with it."""
    from pipeline.store.records import forecast_records, record

    model_dir, sha = None, None
    if isinstance(model, (str, os.PathLike)):
        from models.persistence import digest
        from models.registry import MODEL_FILE

        model_dir, sha = str(model), digest(Path(model) / MODEL_FILE)
    records = forecast_records(points, model=trained.name, source=source, model_dir=model_dir,
                               model_sha256=sha, wear_rates=wear_rates(trained))
    return record(store, "forecast", records)


def wear_rates(trained) -> dict | None:
    """The wear-rate map w(x) [um per 1000 h] of a wear-map model by (machine_id, axis) (key
    None: a single map for any axis), or None for a model without one."""
    import numpy as np

    estimator = trained.estimator
    if not hasattr(estimator, "wear_rate_map") or not getattr(estimator, "use_hours_", True):
        return None
    frame = estimator.wear_rate_map()
    groups = (frame.groupby(["machine_id", "axis"], sort=True) if "machine_id" in frame
              else [(None, frame)])

    def plain(values):
        return [float(v) if np.isfinite(v) else None for v in np.asarray(values, float)]

    return {None if key is None else tuple(map(str, key)): {
        "position_mm": plain(g["position_mm"]), "rate": plain(g["wear_rate_um_per_1000h"]),
        "low": plain(g["wear_rate_low"]), "high": plain(g["wear_rate_high"])}
        for key, g in groups}


def plan_inputs(plan: pd.DataFrame, model, source: str) -> pd.DataFrame:
    """Model inputs at the plan's points (``models.serving.filled_inputs``: what the plan
    lacks and the estimator does not use takes its training mean, a missing condition is NaN,
    a missing deviation is one error line), checked for how far it forecasts."""
    from models.serving import filled_inputs

    inputs = filled_inputs(model, plan, source)
    check_forecast(model, inputs, source, plan=True)
    return inputs


def check_forecast(model, inputs: pd.DataFrame, source: str, plan: bool) -> None:
    """A model trained on one spread of operating hours cannot forecast others."""
    if plan and getattr(model.estimator, "can_forecast_", True) is False:
        hours = model.input_ranges_.get("operating_hours")
        raise InputError(f"model {model.name!r} was trained on a single visit (no spread in "
                         f"operating hours{f', {hours[0]:g} h only' if hours else ''}): it cannot "
                         "forecast; train on several visits", file=source,
                         column="operating_hours")
    if "operating_hours" not in inputs or "operating_hours" not in model.input_ranges_:
        return
    low, high = model.input_ranges_["operating_hours"]
    hours = inputs["operating_hours"].astype(float)
    single = getattr(model.estimator, "can_forecast_", True) is False or high <= low
    if single and (plan or (hours != low).any()):
        raise InputError(f"model {model.name!r} was trained on a single visit (operating "
                         f"hours {low:g} h only): it cannot forecast other hours; train on "
                         "several visits", file=source, column="operating_hours")
