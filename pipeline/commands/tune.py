"""``backlash tune``: Optuna search of the network's architecture and training, each trial a
nested MLflow run logged as soon as it finishes; many workers share a study through
``--storage``; a trial whose worker was killed is marked FAIL when the study is next opened."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "tune")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the best trial)")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("tune", args, "trials")
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
        print(result.to_json())
    return 0
