"""``backlash iso``: ISO 230-2 figures of every test in one or more readings files."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters

OUTPUTS = {"plot": "file"}  # the chart, a command-only output: checked before any work
FLAGS = {"path": "--plot"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "iso")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object per test on stdout")
    parser.add_argument("--plot", metavar="OUT.png", help="write the ISO chart (one panel per test)")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.errors import InputError
    from pipeline.commands.data import run_job

    if args.plot and not args.plot.lower().endswith(".png"):  # refused before any reading
        raise InputError("expected a .png file name", file=args.plot, parameter="path")
    result = run_job("iso", args)
    if args.plot:
        result.plot(args.plot)
    print(result.table(), file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
