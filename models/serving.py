"""What a served model takes and gives: its input columns and a prediction frame.

A trained model predicts from the columns ``models.registry.TrainedModel.inputs`` selects, but
a plan (a visit not measured yet) names only what the model really uses: for a wear map the
machine axis (when the model knows several), ``target``, ``operating_hours`` and the
conditions it fitted (``estimator.conditions_``), which a plan may omit. ``input_columns`` lists
exactly those, as plain data (the MLflow signature is built from it); ``prediction_frame``
fills what a plan leaves out the way ``backlash predict`` does (an input the estimator does not
use takes its training mean, a missing condition is NaN and widens the interval) and returns
``backlash_um`` with, for predictors that give one, the 95 % interval, clipped at 0.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from models.registry import AXIS_KEYS, TrainedModel, knows_axes

PREDICTION = "backlash_um"
INTERVAL = ("backlash_low_um", "backlash_high_um")


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
    """``backlash_um``, plus the interval's bounds for predictors with ``predict_interval``."""
    return [PREDICTION, *(INTERVAL if hasattr(estimator, "predict_interval") else ())]


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
        ``backlash_high_um`` (95 %); every value clipped at 0 (backlash is a magnitude), one
        row per row of ``frame`` in its order (index 0..n-1).
    """
    X = served_inputs(model, frame, source)
    estimator = model.estimator
    if hasattr(estimator, "predict_interval"):
        values = dict(zip(output_columns(estimator), estimator.predict_interval(X), strict=True))
    else:
        values = {PREDICTION: estimator.predict(X)}
    return pd.DataFrame({k: np.maximum(np.asarray(v, float), 0.0) for k, v in values.items()})
