"""``backlash report``: the printable test report (HTML and PDF) of readings files."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "report")
    parser.add_argument("--json", action="store_true",
                        help="print the figures of every test as JSON (as iso --json)")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("report", args)
    for role, path in result.files.items():
        print(f"{role}: {path}", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
