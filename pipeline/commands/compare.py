"""``backlash compare``: every predictor on the same split, one table, logged to MLflow; or a
rolling-origin backtest of them as forecasters of the next visit."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "compare")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the table)")


def run(args: argparse.Namespace) -> int:
    import tempfile

    from pipeline.commands.data import run_job

    backtest = args.split == "backtest"
    out = args.out or tempfile.mkdtemp(prefix=f"backlash-{'backtest' if backtest else 'compare'}-")
    result = run_job("compare", args, "origins" if backtest else "models", out=out)
    logged = result.tracking
    run_id = f"; MLflow run {logged['run_id']}" if logged else ""
    (print_backtest if backtest else print_table)(result, file=sys.stderr)
    if backtest:
        print(f"best forecast: {result.summary.iloc[0]['model']}{run_id}; tables -> "
              f"{result.files['backtest_summary']}", file=sys.stderr)
    else:
        print(f"best: {result.best}{' (now champion)' if logged.get('champion') else ''}"
              f"{run_id}; table -> {result.files['comparison']}", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0


def print_table(result, file) -> None:
    from pipeline.workflows.compare import COLUMNS

    cols = [c for c in COLUMNS if c in result.table]
    print(f"{result.n_points} points, target {result.target_kind}; noise floor of one measured "
          f"target {result.noise_floor_um:.3f} um", file=file)
    print(result.table[cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"),
          file=file)


def print_backtest(result, file) -> None:
    from pipeline.workflows.compare import BACKTEST_COLUMNS

    cols = [c for c in BACKTEST_COLUMNS if c in result.summary]
    print(f"{result.n_points} points, target {result.target_kind}; noise floor of one measured "
          f"target {result.noise_floor_um:.3f} um; forecast of the next visit from every "
          "earlier origin", file=file)
    print(result.summary[cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"),
          file=file)
    if any(c.startswith("cover95_") for c in cols):
        print("cover95_measured_pct, cover95_true_pct: % of the forecast points whose 95 % "
              "interval holds the measured value, the true value", file=file)
