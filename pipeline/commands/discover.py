"""``backlash discover``: name the physical effect the simulation model is missing."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "discover")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("discover", args)
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
        print(result.to_json())
    return 0
