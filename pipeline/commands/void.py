"""``backlash void``: retire tests of a fleet store from every reader (``--undo`` restores)."""

from __future__ import annotations

import argparse

from pipeline.workflows.void import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {}  # changes the store only


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE",
                        help="store folder or postgresql://USER@HOST/DB")
    parser.add_argument("--machine", required=True, metavar="ID", help="the machine")
    parser.add_argument("--axis", required=True, metavar="AXIS", help="the axis")
    parser.add_argument("--visit", metavar="VISIT", help="only the tests of this visit")
    parser.add_argument("--test-id", metavar="TEST", help="only this test")
    parser.add_argument("--reason", required=True, metavar="TEXT",
                        help="why (kept in the store's audit table with the time and the user)")
    parser.add_argument("--undo", action="store_true", help="restore the voided tests instead")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("void", args, store=args.store, machine=args.machine, axis=args.axis,
                     visit=args.visit, test_id=args.test_id, reason=args.reason, undo=args.undo)
    if args.json:
        print(dumps(result.to_json()))
    return 0
