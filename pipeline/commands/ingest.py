"""``backlash ingest``: validate readings files and add their tests to a fleet store."""

from __future__ import annotations

import argparse

from pipeline.commands.data import add_readings_argument
from pipeline.workflows.ingest import WORKFLOW

HELP = WORKFLOW.summary
FLAGS = {"files": "FILE"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, "files", metavar="FILE", nargs="+")
    parser.add_argument("--store", required=True, metavar="STORE",
                        help="store folder (created when new or empty) or postgresql://USER@HOST"
                             "/DB (password in ~/.pgpass or PGPASSWORD, not in the URL)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.fileio import dumps
    from pipeline.commands.data import one_or_all, run_job

    result = run_job("ingest", args, "ingest", files=one_or_all(args.files), store=args.store,
                     format=args.format)
    for f in result.inputs:
        print(f"{f['file']}: {f['tests']} tests, {f['readings']} readings: {f['added']} added, "
              f"{f['unchanged']} already stored", file=sys.stderr)
    print(f"store {result.store}: {result.tests_in_store} tests", file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
