"""``backlash convert``: any accepted layout -> a validated canonical readings table."""

from __future__ import annotations

import argparse

from pipeline.commands.common import FORMATS

HELP = "Read a readings file (canonical, paper Table 2 or ecmc), validate it, write CSV/Parquet."
OUTPUTS = {"out": "file"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="readings file: CSV, Parquet, paper Table-2 CSV or ecmc .dat")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")
    parser.add_argument("--out", required=True, help="output file, .csv or .parquet")


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from features.readings import read_readings, write_readings
    from features.readings.errors import InputError

    if Path(args.out).resolve() == Path(args.file).resolve():
        raise InputError("--out is the input file; expected a new file name (the original "
                         "is kept)", file=args.out)
    frame = read_readings(args.file, args.format)
    write_readings(frame, args.out)
    tests = frame.groupby(["machine_id", "axis", "visit", "test_id"]).ngroups
    print(f"{len(frame)} readings in {tests} tests -> {args.out}", file=sys.stderr)
    return 0
