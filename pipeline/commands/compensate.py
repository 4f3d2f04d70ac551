"""``backlash compensate``: controller compensation files from ISO tests or a trained predictor."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "compensate")
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("compensate", args, "compensate")
    print("\n".join(result.summary()), file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0 if result.passed else 3
