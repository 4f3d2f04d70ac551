"""``backlash simulate``: the feed-drive twin writes a readings table and its truth."""

from __future__ import annotations

import argparse
import sys

from pipeline.workflows.simulate import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from models.physics import PRESETS

    parser.add_argument("--preset", default="paper",
                        help=f"shipped campaign: {', '.join(PRESETS)} (default paper)")
    parser.add_argument("--config", metavar="FILE.toml",
                        help="campaign configuration; overrides the preset's values")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--traces", action="store_true",
                        help="write controller traces instead (motor encoder and load scale, "
                             "wear, an adjustment): OUT/traces/ and OUT/traces_truth.csv")
    parser.add_argument("--days", type=int, default=30, help="with --traces: logged days "
                        "(default 30)")
    parser.add_argument("--rate-hz", type=float, default=200.0,
                        help="with --traces: sampling rate [Hz] (default 200)")
    parser.add_argument("--json", action="store_true",
                        help="print a summary as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    if args.traces:
        return run_traces(args)
    from pipeline.commands.data import run_job

    result = run_job("simulate", args, config=args.config, preset=args.preset, seed=args.seed,
                     out=args.out)
    if args.json:
        from features.readings.fileio import dumps

        print(dumps(result.to_json()))
    print(f"{result.summary()} -> {args.out}/readings.csv, truth.csv, truth_visits.csv, "
          "parameters.json", file=sys.stderr)
    return 0


def run_traces(args: argparse.Namespace) -> int:
    from pipeline.workflows.simulate import simulate_traces

    result = simulate_traces(seed=args.seed, days=args.days, rate_hz=args.rate_hz)
    result.write(args.out)
    if args.json:
        from features.readings.fileio import dumps

        print(dumps(result.to_json()))
    print(f"{result.summary()} -> {args.out}/traces/, traces_truth.csv", file=sys.stderr)
    return 0
