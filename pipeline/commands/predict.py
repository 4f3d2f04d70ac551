"""``backlash predict``: backlash at every interior target of new tests, or at the points of a
plan (a visit not measured yet), from a trained model."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import FORMATS

HELP = ("Predict backlash with a trained model directory from new tests or from a plan table "
        "(targets and conditions); write a CSV.")
OUTPUTS = {"out": "file"}  # output paths by argparse dest: checked before any work
COLUMNS = ("machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target",
           "backlash_um")
INTERVAL = ("backlash_low_um", "backlash_high_um")
# a plan this many times the training span of operating hours beyond its end gets a warning
EXTRAPOLATION_WARNING = 1.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="DIR", help="model directory written by backlash train")
    parser.add_argument("data", help="readings file (linear tests suffice) or a plan table "
                                     "(target and conditions, no deviations)")
    parser.add_argument("--out", required=True, metavar="PRED.csv", help="predictions to write")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")
    parser.add_argument("--json", action="store_true", help="print the predictions as JSON")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from features.readings import read_readings
    from features.readings.errors import InputError
    from features.readings.fileio import atomic_path, clean_nan, dumps
    from features.readings.plan import is_plan, read_plan
    from features.table import prediction_inputs
    from models.registry import load_model

    if not str(args.out).lower().endswith(".csv"):
        raise InputError("expected a .csv file name", file=args.out, column="--out")
    model = load_model(args.model)
    if args.format in ("auto", "canonical") and is_plan(args.data):
        plan = read_plan(args.data)
        inputs = plan_inputs(plan, model, str(args.data))
        keys = list(plan.columns)
    else:
        inputs = prediction_inputs(read_readings(args.data, args.format), model.feature_names_)
        keys = list(COLUMNS[:-1])
        check_forecast(model, inputs, str(args.data), plan=False)
    X = inputs[model.feature_names_]
    estimator = model.estimator
    # a magnitude: a negative prediction is noise around zero backlash
    if hasattr(estimator, "predict_interval"):
        mean, low, high = estimator.predict_interval(X)
        out = inputs[keys].assign(backlash_um=np.maximum(mean, 0.0),
                                  backlash_low_um=np.maximum(low, 0.0),
                                  backlash_high_um=np.maximum(high, 0.0))
    else:
        out = inputs[keys].assign(backlash_um=np.maximum(model.predict(inputs), 0.0))
    with atomic_path(args.out) as tmp:
        out.to_csv(tmp, index=False)
    print(f"{len(out)} points, backlash {out['backlash_um'].min():.2f}-"
          f"{out['backlash_um'].max():.2f} um ({model.name}"
          f"{', 95 % interval' if 'backlash_low_um' in out else ''}) -> {args.out}",
          file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"model": model.name, "predictions": out.astype(
            {c: str for c in out.columns if str(out[c].dtype).startswith("datetime")})
            .to_dict("records")})))
    return 0


def plan_inputs(plan, model, source: str):
    """Model inputs at the plan's points: the plan's columns; inputs the estimator does not use
    take their training mean; a condition the estimator uses but the plan lacks is left missing
    (NaN), which widens the interval of a wear map; an input only a measurement can give (the
    linear test's deviations) is refused in one line."""
    import numpy as np

    from features.readings.errors import InputError

    used = set(getattr(model.estimator, "used_features_", model.feature_names_))
    optional = set(getattr(model.estimator, "conditions_", ()))
    training = model.training_inputs_
    inputs = plan.copy()
    for name in model.feature_names_:
        if name in plan:
            continue
        if name in used and name not in optional:
            why = (" a plan cannot give it: measure the linear tests, or train a forecasting "
                   "predictor (wear-map)" if name.startswith("deviation") else "")
            raise InputError(f"model {model.name!r} needs input {name!r}, which the plan "
                             f"lacks;{why or ' add the column'}", file=source, column=name)
        fill = (float(training[name].mean()) if name not in used and training is not None
                and name in training else np.nan)
        inputs[name] = fill
    check_forecast(model, inputs, source, plan=True)
    return inputs


def check_forecast(model, inputs, source: str, plan: bool) -> None:
    """A model trained on one spread of operating hours cannot forecast others; a plan far
    beyond the training hours gets a warning with the extrapolation factor."""
    from features.readings.errors import InputError

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
    if getattr(model.estimator, "can_forecast_", True) is False or high <= low:
        if plan or (hours != low).any():
            raise InputError(f"model {model.name!r} was trained on a single visit (operating "
                             f"hours {low:g} h only): it cannot forecast other hours; train on "
                             "several visits", file=source, column="operating_hours")
        return
    factor = (float(hours.max()) - high) / (high - low)
    if factor > EXTRAPOLATION_WARNING:
        print(f"warning: operating_hours up to {hours.max():g} h is {factor:.1f}x the training "
              f"span ({low:g}-{high:g} h) beyond its end; the forecast extrapolates the wear "
              "rate that far", file=sys.stderr)
