"""``backlash predict``: backlash at every interior target of new tests, or at the points of a
plan (a visit not measured yet), from a trained model."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_readings_argument

HELP = ("Predict backlash with a trained model directory from new tests or from a plan table "
        "(targets and conditions); write a CSV.")
OUTPUTS = {"out": "file"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="DIR", help="model directory written by backlash train")
    add_readings_argument(parser, help="readings file (linear tests suffice) or a plan table "
                                       "(target and conditions, no deviations)")
    parser.add_argument("--out", required=True, metavar="PRED.csv", help="predictions to write")
    parser.add_argument("--json", action="store_true", help="print the predictions as JSON")
    parser.add_argument("--store", metavar="STORE",
                        help="fleet store (folder or postgresql:// URL) to record the forecast "
                             "in, per machine axis; backlash fleet shows the last one")


def run(args: argparse.Namespace) -> int:
    from features.readings.errors import InputError
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    if not str(args.out).lower().endswith(".csv"):  # before any work
        raise InputError("expected a .csv file name", file=args.out, parameter="out")
    result = run_job("predict", args, model=args.model, data=args.data, format=args.format,
                     store=args.store, out=args.out)
    out = result.predictions
    for unit, part in (out.groupby("unit", sort=False) if "unit" in out else [("um", out)]):
        print(f"{len(part)} points, backlash {part['backlash_um'].min():.2f}-"
              f"{part['backlash_um'].max():.2f} {unit} ({result.model}"
              f"{', 95 % interval' if result.has_interval else ''}) -> {args.out}",
              file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
