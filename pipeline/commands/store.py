"""``backlash store check``: verify a fleet store against its manifest (exit 1 on a problem)."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP

# Exit code when the check finds a problem it did not mend.
PROBLEMS_EXIT = 1
SYNOPSIS = "backlash store check STORE [options]"  # the action comes before the job's STORE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("check",), help="what to do with the store")
    add_parameters(parser, "store")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("store", args)
    if args.json:
        print(result.to_json())
    else:
        for line in result.repaired:
            print(f"repaired: {line}")
        for line in result.problems:
            print(f"problem: {line}")
    verdict = "no problem" if result.ok else f"{len(result.problems)} problems"
    print(f"store {result.store}: {result.tests} tests, {result.readings} readings: {verdict}"
          + (f", {len(result.repaired)} repaired" if result.repaired else ""), file=sys.stderr)
    return 0 if result.ok else PROBLEMS_EXIT
