"""``backlash replicate``: the backlash paper's Figs 10, 13, 14, Table 5 and k-NN accuracy on
one data set, side by side with the paper's numbers, with and without the deviation inputs."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "replicate")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("replicate", args, "replicate")
    print(result.markdown(), file=sys.stderr)
    print(f"report: {result.files['html']}", file=sys.stderr)
    if args.json:

        print(result.to_json())
    return 0
