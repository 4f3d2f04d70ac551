"""``backlash iso``: ISO 230-2 figures of every test in one or more readings files."""

from __future__ import annotations

import argparse

from features import standards
from pipeline.commands.data import add_readings_argument
from pipeline.workflows.iso import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"plot": "file"}  # output paths by argparse dest: checked before any work
FLAGS = {"path": "--plot"}


def add_standard_argument(parser: argparse.ArgumentParser) -> None:
    """``--standard``: choices and help from the records of ``features.standards``."""
    parser.add_argument("--standard", default=standards.DEFAULT, choices=standards.NAMES,
                        help=standards.help_text())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, "file", metavar="FILE", nargs="+")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object per test on stdout")
    parser.add_argument("--plot", metavar="OUT.png", help="write the ISO chart (one panel per test)")
    parser.add_argument("--drop-outliers", action="store_true",
                        help="leave flagged outlier readings out of the figures")
    parser.add_argument("--uncertainty", metavar="BUDGET.toml",
                        help="ISO/TR 230-9 budget: add U_A_um ... U_B_um (expanded "
                             "uncertainties at each test's measuring length)")
    add_standard_argument(parser)


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.errors import InputError
    from features.readings.fileio import dumps
    from pipeline.commands.data import one_or_all, run_job

    if args.plot and not args.plot.lower().endswith(".png"):  # refused before any reading
        raise InputError("expected a .png file name", file=args.plot, parameter="path")
    result = run_job("iso", args, data=one_or_all(args.file), format=args.format,
                     drop_outliers=args.drop_outliers, uncertainty=args.uncertainty,
                     standard=args.standard)
    if args.plot:
        result.plot(args.plot)
    print(result.table(), file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
