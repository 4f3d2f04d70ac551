"""``backlash tune``: Optuna search of the network's architecture and training, each trial a
nested MLflow run; many workers share a study through ``--storage``."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import add_data_arguments

HELP = ("Tune the network (hidden sizes, activation, trainer, regularisation) by "
        "cross-validation with Optuna.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_data_arguments(parser)
    parser.add_argument("--trials", type=int, default=30, help="trials to run in total "
                                                                "(default 30)")
    parser.add_argument("--storage", help="Optuna storage URL, e.g. postgresql://user@host/db "
                                          "(default: sqlite:///optuna.db)")
    parser.add_argument("--study", default="backlash-network", help="study name")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes sharing the study (default 1)")
    parser.add_argument("--folds", type=int, default=5, help="cross-validation folds (default 5)")
    parser.add_argument("--json", action="store_true", help="print the best trial as JSON")


def run(args: argparse.Namespace) -> int:
    import uuid

    from features.readings.errors import InputError
    from models import tuning
    from pipeline.commands.common import load_table

    if args.trials < 1 or args.workers < 1 or args.folds < 2:
        raise InputError("--trials and --workers must be at least 1 and --folds at least 2")
    storage = args.storage or tuning.DEFAULT_STORAGE
    if not storage.startswith(("sqlite:///", "postgresql", "mysql")):
        raise InputError(f"unsupported storage URL {storage!r}; expected sqlite:///FILE or "
                         "postgresql://...", column="--storage")
    readings, table, floor, _ = load_table(args)
    if len(table.y) < 2 * args.folds:
        raise InputError(f"{len(table.y)} backlash points are too few for {args.folds}-fold "
                         "cross-validation", file=args.data)
    tag = uuid.uuid4().hex[:12]
    study = _open_study(tuning, args.study, storage, args.seed)
    shares = [args.trials // args.workers + (i < args.trials % args.workers)
              for i in range(args.workers)]
    print(f"{args.trials} trials, {args.workers} worker(s), {args.folds}-fold CV on "
          f"{len(table.y)} points; study {args.study!r} in {_safe(storage)}", file=sys.stderr)
    if args.workers == 1:
        tuning.work(args.study, storage, table.X, table.y, args.trials, args.folds, args.seed,
                    tag, progress=sys.stderr.isatty())
    else:
        _run_workers(tuning, args, storage, table, shares, tag)
    return _log(study, tag, args, table, readings, storage, floor)


def _open_study(tuning, name, storage, seed):
    from features.readings.errors import InputError

    try:
        return tuning.create_study(name, storage, seed)
    except Exception as err:  # noqa: BLE001 - any driver error is a bad URL or server for the user
        raise InputError(f"cannot open Optuna storage: {type(err).__name__}: "
                         f"{str(err).splitlines()[0]}", column="--storage") from None


def _run_workers(tuning, args, storage, table, shares, tag) -> None:
    import multiprocessing as mp

    context = mp.get_context("spawn")
    procs = [context.Process(target=tuning.work, args=(args.study, storage, table.X, table.y,
                                                       n, args.folds, args.seed, tag, 1))
             for n in shares if n]
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    failed = [p.exitcode for p in procs if p.exitcode]
    if failed:
        raise RuntimeError(f"{len(failed)} tuning worker(s) failed (exit codes {failed})")


def _log(study, tag, args, table, readings, storage, floor) -> int:
    """Every trial of this invocation as a nested MLflow run under one tune run."""
    import mlflow
    import optuna

    from features.readings.fileio import clean_nan, dumps
    from pipeline import tracking

    study = optuna.load_study(study_name=args.study, storage=storage)
    mine = [t for t in study.trials if t.user_attrs.get("tag") == tag
            and t.state == optuna.trial.TrialState.COMPLETE]
    with tracking.run("tune", f"tune {args.study}") as parent:
        mlflow.log_params({"study": args.study, "storage": _safe(storage), "trials": args.trials,
                           "workers": args.workers, "folds": args.folds, "seed": args.seed,
                           "data_sha256": tracking.data_hash(readings),
                           "target_kind": table.target_kind, "noise_floor_um": floor})
        for trial in mine:
            with tracking.run("tune", f"trial {trial.number}", nested=True):
                mlflow.log_params(trial.params)
                mlflow.log_metrics({"cv_rmse_um": trial.value,
                                    "cv_rmse_std_um": trial.user_attrs["cv_rmse_std_um"]})
                mlflow.set_tag("worker_pid", trial.user_attrs["worker_pid"])
        best = study.best_trial
        mlflow.log_params({f"best_{k}": v for k, v in best.params.items()})
        mlflow.log_metric("best_cv_rmse_um", best.value)
    print(f"best of {len(study.trials)} trials in the study: CV RMSE {best.value:.3f} um "
          f"with {best.params}; MLflow run {parent.info.run_id}", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"best_params": best.params, "best_cv_rmse_um": best.value})))
    return 0


def _safe(url: str) -> str:
    """The storage URL without a password."""
    import re

    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)
