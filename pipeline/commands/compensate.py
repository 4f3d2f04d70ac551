"""``backlash compensate``: controller compensation files from ISO tests or a trained predictor."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.workflows.compensate import PARAMETERS, WORKFLOW

HELP = WORKFLOW.summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "compensate", skip=("active",))
    active = PARAMETERS["active"]  # repeated, one file each: an action the table has no word for
    parser.add_argument("--active", action="append", metavar=active.metavar, help=active.help)
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job, selected

    # --machine as a list (``selected``); --axis stays one name (a predictor's axis)
    result = run_job("compensate", args, "compensate", **selected(args, skip=("axis",)))
    print("\n".join(result.summary()), file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0 if result.passed else 3
