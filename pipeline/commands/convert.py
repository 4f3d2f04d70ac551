"""``backlash convert``: any accepted layout -> a validated canonical readings table."""

from __future__ import annotations

import argparse

from pipeline.commands.data import add_readings_argument
from pipeline.workflows.convert import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "file"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, "file")
    parser.add_argument("--out", required=True, help="output file, .csv or .parquet")


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    from features.readings.errors import InputError
    from pipeline.commands.data import readings_arg
    from pipeline.workflows.convert import convert

    # realpath, not Path.resolve: a symbolic-link loop is the reader's one-line error
    if os.path.realpath(args.out) == os.path.realpath(args.file):
        raise InputError("--out is the input file; expected a new file name (the original "
                         "is kept)", file=args.out)
    result = convert(readings_arg(args, "file"), args.out, args.format)
    print(f"{len(result.readings)} readings in {result.tests} tests -> {args.out}",
          file=sys.stderr)
    return 0
