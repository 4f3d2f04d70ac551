"""``backlash discover``: name the physical effect the simulation model is missing."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_readings_argument
from pipeline.workflows.discover import DEFAULT_BASELINE, WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, help="readings file (columns of docs/data-contract.md; "
                                       "measured_at for time effects)")
    parser.add_argument("--baseline", default=DEFAULT_BASELINE,
                        help="comma-separated effects of the simulation model "
                             f"(default {DEFAULT_BASELINE})")
    parser.add_argument("--out", required=True, help="output folder for the report")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("discover", args, data=args.data, out=args.out, format=args.format,
                     baseline=args.baseline, seed=args.seed)
    unit = result.discovery.unit
    for step in result.steps:
        print(f"named {step.effect} {step.parameters}: gap {step.rmse_before_um:.3f} -> "
              f"{step.rmse_after_um:.3f} {unit} (delta BIC {step.delta_bic:.0f}, CV gain "
              f"{100 * step.cv_gain:.0f} %)", file=sys.stderr)
    for group in result.ambiguous:
        print(f"ambiguous: {', '.join(group)}", file=sys.stderr)
    print(f"gap {result.rmse_before_um:.3f} -> {result.rmse_after_um:.3f} {unit}, repeatability "
          f"{result.repeatability_um:.3f} {unit}; report {result.files['html']}", file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
