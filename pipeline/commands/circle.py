"""``backlash circle``: ISO 230-4 circular tests (ballbar) -> G, H and the diagnosis."""

from __future__ import annotations

import argparse

from pipeline.workflows.circle import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
FLAGS = {"tolerance_um": "--tolerance", "data": "FILE"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE",
                        help="circular-test table, CSV or Parquet (docs/circle.md)")
    parser.add_argument("--out", metavar="DIR",
                        help="output folder: a polar plot per circle, circles.csv, circles.html")
    parser.add_argument("--tolerance", type=float, metavar="UM",
                        help="width of the tolerance band drawn in the plots [um]")
    parser.add_argument("--store", metavar="STORE",
                        help="fleet store (folder or postgresql:// URL) to record each axis's backlash "
                             "in (docs/fleet.md)")
    parser.add_argument("--json", action="store_true",
                        help="print G_um, H_um and the diagnosis of every circle as JSON")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("circle", args, data=args.file, tolerance_um=args.tolerance, out=args.out,
                     store=args.store)
    print(result.table(), file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.out:
        print(f"wrote {len(result.files)} files to {args.out}", file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
