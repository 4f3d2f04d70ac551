"""``backlash compare``: every predictor on the same split, one table, logged to MLflow; or a
rolling-origin backtest of them as forecasters of the next visit."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_data_arguments

HELP = "Train every predictor (network, physics baselines, comparators) on one split; compare."
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from models.registry import help_text

    add_data_arguments(parser)
    for action in parser._actions:  # compare alone also backtests (rolling origin)
        if action.dest == "split":
            action.choices = (*action.choices, "backtest")
            action.help += "; or backtest: train on visits <= k, forecast visit k + 1, every k"
    parser.add_argument("--models", help="comma-separated predictor names (default: all); "
                                         + help_text().replace("%", "%%"))
    parser.add_argument("--out", help="folder for the comparison table and figures")
    parser.add_argument("--json", action="store_true", help="print the table as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    import tempfile

    from features.readings.fileio import dumps
    from pipeline.commands.common import parse_list
    from pipeline.commands.data import data_params, run_job

    models = parse_list(args.models, "models")  # same list syntax as --features
    backtest = args.split == "backtest"
    out = args.out or tempfile.mkdtemp(prefix=f"backlash-{'backtest' if backtest else 'compare'}-")
    result = run_job("compare", args, "origins" if backtest else "models", data=args.data,
                     out=out, models=models, split=args.split, **data_params(args))
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
        print(dumps(result.to_json()))
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
