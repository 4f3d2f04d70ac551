"""``backlash void``: retire tests of a fleet store from every reader (``--undo`` restores),
and say in one line what was done."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "void")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("void", args)
    print(result.line, file=sys.stderr)  # one line per action, never the result's repr
    if args.json:
        print(result.to_json())
    return 0
