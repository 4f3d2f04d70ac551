"""``backlash circle``: ISO 230-4 circular tests (ballbar) -> G, H and the diagnosis."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "circle")
    parser.add_argument("--json", action="store_true",
                        help="print G_um, H_um and the diagnosis of every circle as JSON")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("circle", args)
    print(result.table(), file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.out:
        print(f"wrote {len(result.files)} files to {args.out}", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
