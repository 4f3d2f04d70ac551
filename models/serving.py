"""What a served model takes and gives: its input columns and a prediction frame.

A trained model predicts from the columns ``models.registry.TrainedModel.inputs`` selects, but
a plan (a visit not measured yet) names only what the model really uses: for a wear map the
machine axis (when the model knows several), ``target``, ``operating_hours`` and the
conditions it fitted (``estimator.conditions_``), which a plan may omit. ``input_columns`` lists
exactly those, as plain data (the MLflow signature is built from it); ``prediction_frame``
fills what a plan leaves out the way ``backlash predict`` does (an input the estimator does not
use takes its training mean, a missing condition is NaN and widens the interval) and returns
``backlash_um`` with, for predictors that give one, the 95 % interval, clipped at 0, and
``extrapolated``: the inputs of each point outside the ranges the model was trained on
(``trained_ranges``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from models.registry import AXIS_KEYS, TrainedModel, knows_axes

PREDICTION = "backlash_um"
INTERVAL = ("backlash_low_um", "backlash_high_um")
EXTRAPOLATED = "extrapolated"
# A forecasting predictor extrapolates in operating hours by design: up to this many training
# spans beyond the last trained hour is its forecast horizon, not an extrapolation to flag.
FORECAST_HORIZON = 1.5


def used_inputs(estimator, features: list[str]) -> list[str]:
    """The numeric inputs ``estimator`` predicts from: its ``used_features_`` in their order
    when it knows them (the wear map: target, operating hours, conditions), else every
    feature it was fitted on."""
    used = getattr(estimator, "used_features_", None)
    return [f for f in used if f in features] if used is not None else list(features)


def optional_inputs(estimator) -> list[str]:
    """Inputs a plan may omit (``estimator.conditions_``: the wear map's condition terms)."""
    return list(getattr(estimator, "conditions_", ()))


def input_columns(estimator, features: list[str]) -> list[dict]:
    """The columns a served model takes, as plain data: ``name``, ``type`` (MLflow data type
    name: ``string`` or ``double``) and ``required``.

    Parameters
    ----------
    estimator : object
        The fitted estimator.
    features : list of str
        The feature-table columns it was fitted on (``TrainedModel.feature_names_``).

    Returns
    -------
    list of dict
        ``machine_id`` and ``axis`` first when the model knows several machine axes, then the
        used inputs; the conditions a plan may omit are not required.
    """
    optional = set(optional_inputs(estimator))
    axes = [{"name": k, "type": "string", "required": True}
            for k in (AXIS_KEYS if knows_axes(estimator) else ())]
    return axes + [{"name": f, "type": "double", "required": f not in optional}
                   for f in used_inputs(estimator, features)]


def output_columns(estimator) -> list[str]:
    """``backlash_um``, plus the interval's bounds for predictors with ``predict_interval``
    (numbers), then ``extrapolated`` (text)."""
    return [PREDICTION, *(INTERVAL if hasattr(estimator, "predict_interval") else ()),
            EXTRAPOLATED]


def forecasts(model: TrainedModel) -> bool:
    """Whether ``model`` forecasts in operating hours (its registry record says so and it was
    trained on a spread of hours)."""
    from models.registry import PREDICTORS

    record = PREDICTORS.get(model.name)
    return bool(record and record.forecasts
                and getattr(model.estimator, "can_forecast_", True) is not False)


def trained_ranges(model: TrainedModel) -> dict[str, tuple[float, float]]:
    """The range [low, high] of every input ``model`` was trained on (``input_ranges_``), in
    the inputs' units; for a forecasting model the operating hours reach ``FORECAST_HORIZON``
    training spans beyond the last trained hour (its forecast horizon)."""
    ranges = dict(model.input_ranges_)
    hours = ranges.get("operating_hours")
    if hours is not None and forecasts(model):
        low, high = hours
        ranges["operating_hours"] = (low, high + FORECAST_HORIZON * (high - low))
    return ranges


def outside(model: TrainedModel, inputs: pd.DataFrame) -> pd.DataFrame:
    """Per point of ``inputs`` and per input with a trained range, whether the value lies
    outside it (a missing value is not outside: it takes the training mean or widens the
    interval)."""
    ranges = trained_ranges(model)
    names = [n for n in inputs.columns if n in ranges]
    return pd.DataFrame({n: ~inputs[n].astype(float).between(*ranges[n]) & inputs[n].notna()
                         for n in names}, index=inputs.index, columns=names, dtype=bool)


def extrapolated(model: TrainedModel, inputs: pd.DataFrame) -> pd.Series:
    """Per point, the inputs outside the trained ranges joined by ``;`` (e.g.
    ``feed_mm_min;target``), empty when none."""
    flags = outside(model, inputs)
    flags = flags[sorted(flags.columns)]
    names = np.asarray(flags.columns, dtype=object)
    return pd.Series([";".join(names[row]) for row in flags.to_numpy(bool)],
                     index=inputs.index, dtype=object)


def extrapolation_lines(model: TrainedModel, inputs: pd.DataFrame,
                        skip: tuple[str, ...] = ()) -> list[str]:
    """One line per input (alphabetical) with points outside its trained range: the input,
    how many points, the values there and the trained range, e.g. ``feed_mm_min 20000 at 40
    of 40 points is outside the trained range 200 to 1200: the prediction extrapolates
    there``."""
    flags = outside(model, inputs)
    ranges = trained_ranges(model)
    lines = []
    for name in sorted(flags.columns):
        rows = flags[name].to_numpy(bool)
        if name in skip or not rows.any():
            continue
        values = inputs[name].astype(float)[rows]
        low, high = values.min(), values.max()
        shown = f"{low:g}" if low == high else f"{low:g} to {high:g}"
        lines.append(f"{name} {shown} at {rows.sum()} of {len(rows)} points is outside the "
                     f"trained range {ranges[name][0]:g} to {ranges[name][1]:g}: the "
                     "prediction extrapolates there")
    return lines


def filled_inputs(model: TrainedModel, frame: pd.DataFrame,
                  source: str = "request") -> pd.DataFrame:
    """``frame`` with every feature of ``model``: an input the estimator does not use takes its
    training mean (NaN without training inputs), a condition it uses but ``frame`` lacks is
    NaN (a wear map's interval widens); a used input that cannot be missing is one
    ``InputError`` line (the linear test's deviations: only a measurement gives them)."""
    used = set(used_inputs(model.estimator, model.feature_names_))
    optional = set(optional_inputs(model.estimator))
    training = model.training_inputs_
    inputs = frame.copy()
    for name in model.feature_names_:
        if name in inputs:
            continue
        if name in used and name not in optional:
            why = (" a plan cannot give it: measure the linear tests, or train a forecasting "
                   "predictor (wear-map)" if name.startswith("deviation") else " add the column")
            raise InputError(f"model {model.name!r} needs input {name!r}, which the inputs "
                             f"lack;{why}", file=source, column=name)
        unused_mean = (name not in used and training is not None and name in training)
        inputs[name] = float(training[name].mean()) if unused_mean else np.nan
    return inputs


def served_inputs(model: TrainedModel, frame: pd.DataFrame, source: str = "request"):
    """The estimator's inputs at the rows of ``frame`` (``filled_inputs``, then the columns
    ``TrainedModel.inputs`` selects)."""
    return model.inputs(filled_inputs(model, frame, source), source)


def prediction_frame(model: TrainedModel, frame: pd.DataFrame,
                     source: str = "request") -> pd.DataFrame:
    """Predicted backlash [um] at the rows of ``frame`` (a plan or new tests' inputs).

    Returns
    -------
    DataFrame
        ``backlash_um`` and, for a predictor with ``predict_interval``, ``backlash_low_um`` and
        ``backlash_high_um`` (95 %); every value clipped at 0 (backlash is a magnitude); then
        ``extrapolated`` (``extrapolated``: the inputs outside the trained ranges, empty when
        none). One row per row of ``frame`` in its order (index 0..n-1).
    """
    filled = filled_inputs(model, frame, source)
    X = model.inputs(filled, source)
    estimator = model.estimator
    if hasattr(estimator, "predict_interval"):
        values = dict(zip((PREDICTION, *INTERVAL), estimator.predict_interval(X), strict=True))
    else:
        values = {PREDICTION: estimator.predict(X)}
    out = pd.DataFrame({k: np.maximum(np.asarray(v, float), 0.0) for k, v in values.items()})
    out[EXTRAPOLATED] = extrapolated(model, filled.reset_index(drop=True)).to_numpy()
    return out
