"""``backlash report``: the printable test report (HTML and PDF) of readings files."""

from __future__ import annotations

import argparse

from pipeline.commands.data import add_readings_argument
from pipeline.commands.iso import add_standard_argument
from pipeline.workflows.report import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
FLAGS = {"data": "FILE"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, "files", metavar="FILE", nargs="+")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="folder for iso_report.html and iso_report.pdf")
    parser.add_argument("--uncertainty", metavar="BUDGET.toml",
                        help="ISO/TR 230-9 budget: print every axis figure as value ± U")
    parser.add_argument("--drop-outliers", action="store_true",
                        help="leave flagged outliers out of the figures (still ringed on the "
                             "charts)")
    parser.add_argument("--meta", metavar="META.toml",
                        help="[report] table: operator, organisation, instrument, "
                             "instrument_serial, instrument_calibrated_on, sensors, remarks; "
                             "printed on every page above the signature block")
    add_standard_argument(parser)
    parser.add_argument("--json", action="store_true",
                        help="print the figures of every test as JSON (as iso --json)")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.fileio import dumps
    from pipeline.commands.data import one_or_all, run_job

    result = run_job("report", args, data=one_or_all(args.files), format=args.format,
                     drop_outliers=args.drop_outliers, uncertainty=args.uncertainty,
                     standard=args.standard, meta=args.meta, out=args.out)
    for role, path in result.files.items():
        print(f"{role}: {path}", file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
