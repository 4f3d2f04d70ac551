"""``backlash convert``: any accepted layout -> a validated canonical readings table."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "convert")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    from features.readings.errors import InputError
    from pipeline.commands.data import run_job

    # realpath, not Path.resolve: a symbolic-link loop is the reader's one-line error
    if os.path.realpath(args.out) == os.path.realpath(args.data):
        raise InputError("--out is the input file; expected a new file name (the original "
                         "is kept)", file=args.out)
    result = run_job("convert", args)
    print(f"{len(result.readings)} readings in {result.tests} tests -> {args.out}",
          file=sys.stderr)
    if args.json:

        print(result.to_json())
    return 0
