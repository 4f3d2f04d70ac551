"""Predict backlash with a trained model: at every interior target of new tests (linear tests
suffice), or at the points of a plan (a visit not measured yet: targets and conditions).

>>> import backlash as bl
>>> forecast = bl.predict("model/", plan="plan.csv")           # doctest: +SKIP
>>> forecast.predictions[["target", "backlash_um", "backlash_low_um"]]   # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from features.readings.errors import InputError, note
from models.serving.registry import TrainedModel
from pipeline.results import Result
from pipeline.steps.parameters import FORMAT, READINGS, Param, python_only
from pipeline.steps.source import readings_of, source_of

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
    # both described by the docstring
    "model": Param((str, os.PathLike, TrainedModel), flag="DIR"),
    "data": Param((*READINGS, None), flag="DATA", reads_readings=True),
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
        empty when none (``models.serving.signature.trained_ranges``); a fleet model's ``borrowed``
        says how it forecast a machine axis it was not trained on (empty for its own). With a
        rotary axis among the points a ``unit`` column says each row's unit (``arcsec`` for a
        rotary axis).
    model : str
        Registry name of the predictor.
    points : DataFrame or None
        The predictions with the operating hours and the start (``started_at``) of the visit
        each point is for, where known: what a fleet store records of the forecast
        (``pipeline.store.records.record_forecast``).
    points_source : str
        Where the points came from (the readings or the plan).
    trained : TrainedModel or None
        The predictor (its registry name and, for a wear map, its wear-rate map).
    model_dir : str or None
        The model directory it was loaded from (None for a model given as an object).
    recorded : pipeline.store.records.Recorded or None
        What ``store`` recorded (the runner sets it).
    """

    predictions: pd.DataFrame
    model: str
    points: pd.DataFrame | None = field(default=None, repr=False)
    points_source: str = field(default="", repr=False)
    trained: TrainedModel | None = field(default=None, repr=False)
    model_dir: str | None = field(default=None, repr=False)
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

    def to_dict(self) -> dict:
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


def predict(model, data=None, *, plan=None, format: str = "auto") -> PredictionResult:
    """Backlash [um] from a trained model at the points of new tests or of a plan.

    Parameters
    ----------
    model : str, path-like or TrainedModel
        A model directory written by ``train`` (or the model ``load_model`` returns).
    data : str, path-like or DataFrame, optional
        Readings (linear tests suffice: they give the deviation inputs), or a fleet store (a
        folder or a postgresql:// URL, ``backlash ingest``). A CSV/Parquet file without
        deviations is read as a plan (targets and conditions).
    plan : str, path-like or DataFrame, optional
        A plan table: targets and conditions of a visit not measured yet
        (``features.readings.plan``). Give ``data`` or ``plan``.
    format : str
        Input layout of ``data`` (default: detect).

    Returns
    -------
    PredictionResult
        Every input with points outside the range the model was trained on gets a note
        naming the input, the points and the trained range (a ``BacklashWarning``, also in
        ``notes``), and the points say which in ``extrapolated``. A forecasting model (the wear
        map) extrapolates in operating hours by design: its hours get a note (with the
        extrapolation factor) only beyond ``models.serving.signature.FORECAST_HORIZON`` training spans
        past the last trained hour.

    Raises
    ------
    InputError
        Neither or both of ``data`` and ``plan``; a point the model may not answer for (a
        machine axis it was not trained on, an axis of another unit; a fleet model forecasts
        another axis of a unit it has a fleet of, with a note: ``models.serving.signature.answerable``),
        or a model that does not record which axes it was trained on.
    """
    import pandas as pd

    from features.readings.plan import is_plan, plan_points, read_plan
    from features.table import prediction_inputs
    from models.serving.registry import load_model
    from models.serving.signature import answerable, predictions

    if (data is None) == (plan is None):
        raise InputError("give the readings (data) or a plan, not both", parameter="data")
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
    points = out.copy()
    if "operating_hours" not in points and "operating_hours" in inputs:
        points["operating_hours"] = inputs["operating_hours"].to_numpy(float)
    if plan is None and "started_at" in readings:
        points["started_at"] = _visit_starts(readings, inputs)
    return PredictionResult(
        predictions=out, model=trained.name, notes=lines, points=points, points_source=source,
        trained=trained,
        model_dir=str(model) if isinstance(model, (str, os.PathLike)) else None)


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


def plan_inputs(plan: pd.DataFrame, model, source: str) -> pd.DataFrame:
    """Model inputs at the plan's points (``models.serving.signature.filled_inputs``: what the plan
    lacks and the estimator does not use takes its training mean, a missing condition is NaN,
    a missing deviation is one error line), checked for how far it forecasts."""
    from models.serving.signature import filled_inputs

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
