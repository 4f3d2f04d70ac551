"""``backlash tune``: Optuna search of the network's architecture and training, each trial a
nested MLflow run logged as soon as it finishes; many workers share a study through
``--storage``; a trial whose worker was killed is marked FAIL when the study is next opened."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_data_arguments

HELP = ("Tune the network (hidden sizes, activation, trainer, regularisation) by "
        "cross-validation with Optuna.")
OUTPUTS = {}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_data_arguments(parser)
    parser.add_argument("--trials", type=int, default=30, help="trials to run in total "
                                                                "(default 30)")
    parser.add_argument("--storage", help="Optuna storage URL, e.g. postgresql://user@host/db "
                                          "(default: sqlite:///optuna.db)")
    parser.add_argument("--study", help="study name (default backlash-network-<the first 12 "
                                        "hex digits of the data's SHA-256>: one study per data)")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes sharing the study (default 1)")
    parser.add_argument("--folds", type=int, default=5, help="cross-validation folds (default 5)")
    parser.add_argument("--heartbeat-s", type=int, default=10, metavar="S",
                        help="running trials report every S seconds; a trial silent for 2 S "
                             "(its worker was killed) is marked failed (default 10)")
    parser.add_argument("--json", action="store_true", help="print the best trial as JSON")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.common import parse_features
    from pipeline.commands.data import run_job

    result = run_job("tune", args, "trials", data=args.data, trials=args.trials,
                     storage=args.storage, study=args.study, workers=args.workers,
                     folds=args.folds, heartbeat_s=args.heartbeat_s, format=args.format,
                     target=args.target, features=parse_features(args.features),
                     seed=args.seed)
    others = ", ".join(f"{n} {state}" for state, n in sorted(result.trials.items())
                       if state != "complete")
    complete = result.trials.get("complete", 0)
    print(f"best of {complete} complete trials in the study{f' ({others})' if others else ''}: "
          f"CV RMSE {result.best_cv_rmse_um:.3f} um with {result.best_params} (trial "
          f"{result.best_trial}); this run completed {result.completed_this_run}",
          file=sys.stderr)
    for line in result.notes:
        print(f"note: {line}", file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0
