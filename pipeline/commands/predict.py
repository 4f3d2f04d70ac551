"""``backlash predict``: backlash at every interior target of new tests, or at the points of a
plan (a visit not measured yet), from a trained model."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "predict")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the predictions)")


def run(args: argparse.Namespace) -> int:
    from features.readings.errors import InputError
    from pipeline.commands.data import run_job

    if not str(args.out).lower().endswith(".csv"):  # before any work
        raise InputError("expected a .csv file name", file=args.out, parameter="out")
    result = run_job("predict", args)
    out = result.predictions
    for unit, part in (out.groupby("unit", sort=False) if "unit" in out else [("um", out)]):
        print(f"{len(part)} points, backlash {part['backlash_um'].min():.2f}-"
              f"{part['backlash_um'].max():.2f} {unit} ({result.model}"
              f"{', 95 % interval' if result.has_interval else ''}) -> {args.out}",
              file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
