"""``backlash simulate``: the feed-drive twin writes a readings table and its truth."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters

WRITTEN = {False: "readings.csv, truth.csv, truth_visits.csv, parameters.json",
           True: "traces/, traces_truth.csv"}  # by --traces


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "simulate")
    parser.add_argument("--json", action="store_true",
                        help="print a summary as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("simulate", args)
    if args.json:

        print(result.to_json())
    print(f"{result.summary()} -> {args.out}/{WRITTEN[args.traces]}", file=sys.stderr)
    return 0
