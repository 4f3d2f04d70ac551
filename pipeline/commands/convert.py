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
    raw = parser.add_argument_group("a raw log (--format camonitor)")
    raw.add_argument("--channels", metavar="NAME=PV,...",
                     help="PVs of the set point, the reference and ecmc's test number: "
                          "target=PV,reference=PV[,test=PV] (default: from ecmc's PV names)")
    raw.add_argument("--reference-scale", metavar="SCALE[,OFFSET]", type=_scale,
                     help="axis position = SCALE * reference + OFFSET, in the set point's "
                          "unit (default: fitted to the set points, reported in a note)")
    raw.add_argument("--unit", choices=("mm", "um", "deg"),
                     help="unit of the set point (default: deg when its PV names an axis A, B "
                          "or C, else mm)")


def _scale(text: str) -> tuple[float, float]:
    import math

    parts = text.split(",")
    try:
        numbers = [float(p) for p in parts]
    except ValueError:
        numbers = []
    if not 1 <= len(numbers) <= 2 or not all(map(math.isfinite, numbers)) or numbers[0] == 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected SCALE or SCALE,OFFSET (finite "
                                         "numbers, SCALE not 0)")
    return numbers[0], numbers[1] if len(numbers) > 1 else 0.0


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    from features.readings.errors import InputError
    from pipeline.commands.data import run_job

    # realpath, not Path.resolve: a symbolic-link loop is the reader's one-line error
    if os.path.realpath(args.out) == os.path.realpath(args.file):
        raise InputError("--out is the input file; expected a new file name (the original "
                         "is kept)", file=args.out)
    result = run_job("convert", args, data=args.file, out=args.out, format=args.format,
                     channels=args.channels, reference_scale=args.reference_scale,
                     unit=args.unit)
    print(f"{len(result.readings)} readings in {result.tests} tests -> {args.out}",
          file=sys.stderr)
    return 0
