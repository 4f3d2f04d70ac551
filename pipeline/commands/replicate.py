"""``backlash replicate``: the backlash paper's Figs 10, 13, 14, Table 5 and k-NN accuracy on
one data set, side by side with the paper's numbers, with and without the deviation inputs."""

from __future__ import annotations

import argparse

from pipeline.commands.data import add_readings_argument
from pipeline.commands.options import zero_or_more
from pipeline.workflows.replicate import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, help="readings file with paired linear and pendulum tests")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--truth", metavar="FILE",
                        help="twin truth table: also the k-NN accuracy the true backlash "
                             "would reach in the measured classes (the ceiling set by noise)")
    parser.add_argument("--boot", type=zero_or_more, default=100,
                        help="bootstrap resamples (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("replicate", args, "replicate", data=args.data, format=args.format,
                     truth=args.truth, boot=args.boot, seed=args.seed, out=args.out)
    print(result.markdown(), file=sys.stderr)
    print(f"report: {result.files['html']}", file=sys.stderr)
    return 0
