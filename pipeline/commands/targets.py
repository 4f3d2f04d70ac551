"""``backlash targets``: backlash per point of a readings table, with its uncertainty."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP

TABLE_ROWS = 40  # rows printed; targets.csv and --json hold every point


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "targets")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the points)")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("targets", args)
    print(f"{len(result.points)} points in {result.unit}, target {result.target_kind}: "
          f"{result.target_reason}", file=sys.stderr)
    print(result.table(max_rows=TABLE_ROWS), file=sys.stderr)
    if result.coverage_factor is not None:
        print(f"backlash_U_um: expanded uncertainty, k = {result.coverage_factor:g}",
              file=sys.stderr)
    if args.out:
        print(f"wrote {result.files['targets']}", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
