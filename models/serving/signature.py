"""What a served model takes and gives: its input columns and a prediction frame.

A trained model predicts from the columns ``models.serving.registry.TrainedModel.inputs`` selects, but
a plan (a visit not measured yet) names only what the model really uses: for a wear map the
machine axis (when the model knows several), ``target``, ``operating_hours`` and the
conditions it fitted (``estimator.conditions_``), which a plan may omit. ``input_columns`` lists
exactly those, as plain data (the MLflow signature is built from it); ``prediction_frame``
fills what a plan leaves out the way ``backlash predict`` does (an input the estimator does not
use takes its training mean, a missing condition is NaN and widens the interval) and returns
``backlash_um`` with, for predictors that give one, the 95 % interval, clipped at 0, and
``extrapolated``: the inputs of each point outside the ranges the model was trained on
(``trained_ranges``).

What a model may answer for (``answerable``, the one check ``backlash predict`` and the served
model share): the machine axes it was trained on, each with its unit (``um`` for a linear axis,
``arcsec`` for a rotary one), kept in ``model.json``'s ``scope`` (``scope_of`` builds it at
training). A row of another machine axis is refused, one line naming the row, the machine axis
and what the model covers, except on a fleet model (a pooled wear map) for an axis of a unit
it has at least two axes of: that row is forecast from the fleet's distribution, and says so
in ``borrowed``. A model saved before ``scope`` was recorded answers for none: unless its
``model.json`` lists its axes (a fleet's ``axes``), predicting with it is refused until it is
trained again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.schema import deviation_unit
from models.serving.registry import AXIS_KEYS, TrainedModel, knows_axes

PREDICTION = "backlash_um"
INTERVAL = ("backlash_low_um", "backlash_high_um")
EXTRAPOLATED = "extrapolated"
BORROWED = "borrowed"  # a fleet model's rows of axes it was not trained on: how it forecast them
TEXT_OUTPUTS = (EXTRAPOLATED, BORROWED)
SCOPE = "scope"  # model.json's key: the machine axes and units the model was trained on
MIN_FLEET = 2  # axes of a unit a fleet model needs to forecast another axis of that unit
SHOWN = 6  # machine axes a refusal lists before it counts the rest
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
        ``machine_id`` and ``axis`` first (required when the model knows several machine axes
        by name, else optional: given, they are checked against what the model covers), then
        the used inputs (the conditions a plan may omit not required), then, optional, the
        other inputs it was trained on: not used to predict, but a value outside its trained
        range is flagged (``extrapolated``), as ``backlash predict`` flags it.
    """
    optional = set(optional_inputs(estimator))
    pooled = bool(knows_axes(estimator))
    used = used_inputs(estimator, features)
    return ([{"name": k, "type": "string", "required": pooled} for k in AXIS_KEYS]
            + [{"name": f, "type": "double", "required": f not in optional} for f in used]
            + [{"name": f, "type": "double", "required": False}
               for f in features if f not in used])


def output_columns(estimator) -> list[str]:
    """``backlash_um``, plus the interval's bounds for predictors with ``predict_interval``
    (numbers), then ``extrapolated`` (text) and, for a fleet model, ``borrowed`` (text)."""
    return [PREDICTION, *(INTERVAL if hasattr(estimator, "predict_interval") else ()),
            EXTRAPOLATED, *((BORROWED,) if fleet(estimator) else ())]


def fleet(estimator) -> bool:
    """Whether ``estimator`` is a fleet model: it knows several machine axes by name and
    forecasts an axis it does not know from the fleet's distribution (``unknown_axes``)."""
    return bool(knows_axes(estimator)) and hasattr(estimator, "unknown_axes")


# ----------------------------------------------------------------------------- scope

def scope_of(meta: pd.DataFrame) -> dict:
    """``model.json``'s ``scope`` of a model trained on the points of ``meta`` (their
    ``machine_id`` and ``axis``): ``machines``, ``axes`` (``machine_id``, ``axis``, ``unit``
    each, sorted) and ``units``."""
    pairs = sorted(set(meta[list(AXIS_KEYS)].astype(str).itertuples(index=False, name=None)))
    axes = [{"machine_id": m, "axis": a, "unit": deviation_unit(a)} for m, a in pairs]
    return {"machines": sorted({m for m, _ in pairs}), "axes": axes,
            "units": sorted({a["unit"] for a in axes}, reverse=True)}


def covered_axes(model: TrainedModel) -> dict[tuple[str, str], str] | None:
    """The machine axes ``model`` was trained on, with their units: from ``model.json``'s
    ``scope``, or, for a fleet model saved before it, from its ``axes``; None when the model
    does not say (saved before either was recorded)."""
    scope = model.meta.get(SCOPE)
    axes = scope["axes"] if isinstance(scope, dict) else model.meta.get("axes")
    if not axes:
        return None
    return {(str(a["machine_id"]), str(a["axis"])): a.get("unit") or deviation_unit(a["axis"])
            for a in axes}


def covered_text(covered: dict[tuple[str, str], str]) -> str:
    """What a model covers, for a message: ``M01 X, M01 Y (um)``; past ``SHOWN`` axes of a
    unit the count: ``M01 X, ..., M02 Z, ... (12 um axes); M01 A (arcsec)``."""
    parts = []
    for unit in sorted(set(covered.values()), reverse=True):
        names = [f"{m} {a}" for (m, a), u in sorted(covered.items()) if u == unit]
        shown = ", ".join(names[:SHOWN])
        parts.append(f"{shown} ({unit})" if len(names) <= SHOWN
                     else f"{shown}, ... ({len(names)} {unit} axes)")
    return "; ".join(parts)


@dataclass
class Answerable:
    """What ``answerable`` found: per row, how a fleet model forecast an axis it was not
    trained on (``borrowed``: empty when it was trained on the row's axis; None for a model
    that is no fleet model, which never borrows) and one note per unit it borrowed in."""

    borrowed: pd.Series | None
    notes: list[str] = field(default_factory=list)


def _refused(message: str, source, rows, i: int, column: str) -> InputError:
    row = None if rows is None else int(np.asarray(rows)[i])
    return InputError(message, file=source, row=row, column=column)


def answerable(model: TrainedModel, inputs: pd.DataFrame, source: str = "request",
               rows=None, parameter: str | None = None) -> Answerable:
    """Refuse the rows of ``inputs`` that ``model`` may not answer for: the one scope check of
    ``backlash predict`` and the served model.

    Parameters
    ----------
    model : TrainedModel
        The trained model; what it covers is ``covered_axes``.
    inputs : DataFrame
        The rows asked for, with ``machine_id`` and ``axis`` where given (rows without them
        are taken for the model's axes when those share one unit).
    source : str
        What an error line names (the file, ``plan``, ``request``).
    rows : array-like, optional
        Each row's number in error lines (a plan's); None names none.
    parameter : str, optional
        The caller's parameter that gave the model (named when the model does not record what
        it covers).

    Returns
    -------
    Answerable

    Raises
    ------
    InputError
        The model does not record what it covers; a row of a machine axis it was not trained
        on (a fleet model's: of a unit it has fewer than ``MIN_FLEET`` axes of), of an axis
        whose unit none of its axes has, of a machine or an axis name it does not know, or
        without a machine axis when the model's axes mix units: one line naming the first
        such row, its machine axis and what the model covers.
    """
    covered = covered_axes(model)
    if covered is None:
        raise InputError(f"model {model.name!r} does not record which machine axes it was "
                         "trained on (saved before they were recorded), so it cannot tell what "
                         "it may answer for; train it again", parameter=parameter)
    pooled = fleet(model.estimator)
    units = sorted(set(covered.values()), reverse=True)
    labels = inputs[[k for k in AXIS_KEYS if k in inputs]].astype(str).reset_index(drop=True)
    nothing = pd.Series([""] * len(labels), dtype=object) if pooled else None
    if "axis" not in labels:
        if len(units) > 1 and len(labels):
            raise _refused(f"the model covers axes in {' and '.join(units)} "
                           f"({covered_text(covered)}): each row needs machine_id and axis to "
                           "say which", source, rows, 0, "axis")
        stranger = ~labels.get("machine_id", pd.Series([], dtype=object)).isin(
            {m for m, _ in covered})
        if stranger.any():
            i = int(np.flatnonzero(stranger)[0])
            raise _refused(f"machine {labels['machine_id'][i]} is not among the machines the "
                           f"model was trained on: {covered_text(covered)}; it answers for "
                           "those only", source, rows, i, "machine_id")
        return Answerable(nothing)
    unit_of_row = labels["axis"].map(deviation_unit)
    foreign = ~unit_of_row.isin(units)
    if foreign.any():
        i = int(np.flatnonzero(foreign)[0])
        named = labels[foreign].drop_duplicates()
        names = ", ".join(" ".join(r) for r in named.itertuples(index=False, name=None))
        raise _refused(f"{names}: backlash in {unit_of_row[i]}, but the model knows only axes "
                       f"in {' and '.join(units)}: it was trained on {covered_text(covered)}; "
                       "train on axes of that kind", source, rows, i, "axis")
    if "machine_id" not in labels:
        stranger = ~labels["axis"].isin({a for _, a in covered})
        if stranger.any():
            i = int(np.flatnonzero(stranger)[0])
            raise _refused(f"axis {labels['axis'][i]} is not among the machine axes the model "
                           f"was trained on: {covered_text(covered)}; it answers for those "
                           "only", source, rows, i, "axis")
        return Answerable(nothing)
    pairs = list(labels[list(AXIS_KEYS)].itertuples(index=False, name=None))
    outside = np.array([p not in covered for p in pairs], bool)
    fleet_size = {u: sum(v == u for v in covered.values()) for u in units}
    for i in np.flatnonzero(outside):
        if not pooled or fleet_size[unit_of_row[i]] < MIN_FLEET:
            why = (f"; a fleet model forecasts another axis only from {MIN_FLEET} or more axes "
                   f"in its unit ({unit_of_row[i]})" if pooled else
                   "; it answers for those only")
            raise _refused(f"{pairs[i][0]} {pairs[i][1]} is not among the machine axes the "
                           f"model was trained on: {covered_text(covered)}{why}", source,
                           rows, int(i), "axis")
    if not pooled:
        return Answerable(None)
    borrowed, notes = nothing, []
    for unit in units:
        mine = outside & (unit_of_row == unit).to_numpy()
        if not mine.any():
            continue
        how = f"the fleet's distribution of its {fleet_size[unit]} {unit} axes"
        borrowed[mine] = how
        strangers = sorted({pairs[i] for i in np.flatnonzero(mine)})
        names = ", ".join(f"{m} {a}" for m, a in strangers[:4]) + (
            " ..." if len(strangers) > 4 else "")
        notes.append(f"{names}: not in the model's fleet; forecast from {how} (a wider "
                     "interval)")
    return Answerable(borrowed, notes)


def forecasts(model: TrainedModel) -> bool:
    """Whether ``model`` forecasts in operating hours (its registry record says so and it was
    trained on a spread of hours)."""
    from models.serving.registry import PREDICTORS

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


def extrapolation_notes(model: TrainedModel, inputs: pd.DataFrame) -> list[str]:
    """One note per input with points outside the trained range (``extrapolation_lines``); a
    forecasting model's operating hours only beyond its forecast horizon (``FORECAST_HORIZON``
    training spans past the last trained hour), with the extrapolation factor."""
    if not forecasts(model):
        return extrapolation_lines(model, inputs)
    lines = extrapolation_lines(model, inputs, skip=("operating_hours",))
    if "operating_hours" in inputs and "operating_hours" in model.input_ranges_:
        low, high = model.input_ranges_["operating_hours"]
        last = float(inputs["operating_hours"].astype(float).max())
        factor = (last - high) / (high - low) if high > low else 0.0
        if factor > FORECAST_HORIZON:
            lines.append(f"operating_hours up to {last:g} h is {factor:.1f}x the training "
                         f"span ({low:g}-{high:g} h) beyond its end; the forecast "
                         "extrapolates the wear rate that far")
    return lines


@dataclass
class Assessment:
    """What a model may say of some rows (``assess``): their inputs (``filled_inputs``), per
    row the inputs outside the trained ranges (``extrapolated``) and a fleet model's borrowing
    (``borrowed``, None for another model), and the notes: one per borrowing unit, one per
    input with points outside."""

    inputs: pd.DataFrame
    extrapolated: pd.Series
    borrowed: pd.Series | None
    notes: list[str] = field(default_factory=list)


def assess(model: TrainedModel, frame: pd.DataFrame, source: str = "request", rows=None,
           parameter: str | None = None) -> Assessment:
    """The one check of rows before ``model`` answers for them, shared by ``backlash predict``
    and the served model: first the scope (``answerable``: rows it may not answer for are
    refused), then the inputs (``filled_inputs``) and their extrapolation flags and notes
    (``extrapolated``, ``extrapolation_notes``)."""
    scope = answerable(model, frame, source, rows, parameter)
    filled = filled_inputs(model, frame, source)
    flat = filled.reset_index(drop=True)
    return Assessment(filled, extrapolated(model, flat), scope.borrowed,
                      [*scope.notes, *extrapolation_notes(model, flat)])


def predictions(model: TrainedModel, frame: pd.DataFrame, source: str = "request", rows=None,
                parameter: str | None = None) -> tuple[pd.DataFrame, list[str]]:
    """Predicted backlash [um] at the rows of ``frame`` (a plan or new tests' inputs), and the
    notes of ``assess``.

    Returns
    -------
    DataFrame
        ``backlash_um`` and, for a predictor with ``predict_interval``, ``backlash_low_um`` and
        ``backlash_high_um`` (95 %); every value clipped at 0 (backlash is a magnitude); then
        ``extrapolated`` (the inputs outside the trained ranges, empty when none) and, for a
        fleet model, ``borrowed`` (empty, or how it forecast an axis it was not trained on).
        One row per row of ``frame`` in its order (index 0..n-1).
    list of str
        The notes: borrowing, inputs outside their trained ranges.

    Raises
    ------
    InputError
        A row the model may not answer for (``answerable``), an input it needs and ``frame``
        lacks (``filled_inputs``).
    """
    checked = assess(model, frame, source, rows, parameter)
    X = model.inputs(checked.inputs, source)
    estimator = model.estimator
    if hasattr(estimator, "predict_interval"):
        values = dict(zip((PREDICTION, *INTERVAL), estimator.predict_interval(X), strict=True))
    else:
        values = {PREDICTION: estimator.predict(X)}
    out = pd.DataFrame({k: np.maximum(np.asarray(v, float), 0.0) for k, v in values.items()})
    out[EXTRAPOLATED] = checked.extrapolated.to_numpy()
    if checked.borrowed is not None:
        out[BORROWED] = checked.borrowed.to_numpy()
    return out, checked.notes


def prediction_frame(model: TrainedModel, frame: pd.DataFrame, source: str = "request",
                     rows=None) -> pd.DataFrame:
    """``predictions``'s frame: what the served model answers."""
    return predictions(model, frame, source, rows)[0]
