"""``backlash predict``: backlash at every interior target of new tests from a trained model."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import FORMATS

HELP = "Predict backlash per interior target with a trained model directory; write a CSV."
COLUMNS = ("machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target",
           "backlash_um")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="DIR", help="model directory written by backlash train")
    parser.add_argument("data", help="readings file (linear tests suffice)")
    parser.add_argument("--out", required=True, metavar="PRED.csv", help="predictions to write")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")


def run(args: argparse.Namespace) -> int:
    from features.readings import read_readings
    from features.readings.errors import InputError
    from features.readings.fileio import atomic_path
    from features.table import prediction_inputs
    from models.registry import load_model

    if not str(args.out).lower().endswith(".csv"):
        raise InputError("expected a .csv file name", file=args.out, column="--out")
    model = load_model(args.model)
    inputs = prediction_inputs(read_readings(args.data, args.format), model.feature_names_)
    import numpy as np

    # a magnitude: a negative prediction is noise around zero backlash
    out = inputs[list(COLUMNS[:-1])].assign(backlash_um=np.maximum(model.predict(inputs), 0.0))
    with atomic_path(args.out) as tmp:
        out.to_csv(tmp, index=False)
    print(f"{len(out)} points, backlash {out['backlash_um'].min():.2f}-"
          f"{out['backlash_um'].max():.2f} um ({model.name}) -> {args.out}", file=sys.stderr)
    return 0
