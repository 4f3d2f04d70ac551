"""``backlash tune``: Optuna search of the network's architecture and training, each trial a
nested MLflow run logged as soon as it finishes; many workers share a study through
``--storage``; a trial whose worker was killed is marked FAIL when the study is next opened."""

from __future__ import annotations

import argparse
import sys
import threading

from pipeline.commands.common import add_data_arguments

HELP = ("Tune the network (hidden sizes, activation, trainer, regularisation) by "
        "cross-validation with Optuna.")
OUTPUTS = {}
STORAGE_SCHEMES = ("sqlite", "postgresql", "mysql")
_STOP = threading.Event()  # set by a SIGTERM that must wait for the current trial's storage


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
    parser.add_argument("--heartbeat-s", type=int, default=10, metavar="S",
                        help="running trials report every S seconds; a trial silent for 2 S "
                             "(its worker was killed) is marked failed (default 10)")
    parser.add_argument("--json", action="store_true", help="print the best trial as JSON")


def check_storage(url: str) -> str:
    """``url`` if it names a database Optuna can share between processes, else one line."""
    from features.readings.errors import InputError

    scheme = url.split("://", 1)[0].split("+", 1)[0].lower() if "://" in url else ""
    if scheme not in STORAGE_SCHEMES:
        raise InputError(f"unsupported storage URL {url!r}; expected sqlite:///FILE or "
                         "postgresql://USER@HOST/DB", column="--storage")
    if scheme == "sqlite":
        from pathlib import Path

        path = url.split("sqlite:///", 1)[1].split("?", 1)[0] if "sqlite:///" in url else ""
        if not path or path == ":memory:" or path.startswith("file::memory:"):
            raise InputError(f"storage URL {url!r} keeps the study in one process's memory, "
                             "which workers and later runs cannot share; expected "
                             "sqlite:///FILE", column="--storage")
        file = Path(path).absolute()
        if file.is_dir() or not file.parent.is_dir():
            raise InputError(f"storage URL {url!r}: {file.parent} must be an existing folder "
                             "and the file not a folder", column="--storage")
    return url


def run(args: argparse.Namespace) -> int:
    import uuid

    from features.readings.errors import InputError
    from models import tuning
    from pipeline import tracking
    from pipeline.commands.common import load_table

    if args.trials < 1 or args.workers < 1 or args.folds < 2 or args.heartbeat_s < 1:
        raise InputError("--trials, --workers and --heartbeat-s must be at least 1 and "
                         "--folds at least 2")
    storage = check_storage(args.storage or tuning.DEFAULT_STORAGE)
    tracking.check_uri()
    readings, table, floor, _ = load_table(args)
    if len(table.y) < 2 * args.folds:
        raise InputError(f"{len(table.y)} backlash points are too few for {args.folds}-fold "
                         "cross-validation", file=args.data)
    tag = uuid.uuid4().hex[:12]
    study = _open_study(tuning, args.study, storage, args.seed, args.heartbeat_s)
    _same_heartbeat(study, args.heartbeat_s)
    stale = tuning.fail_stale_trials(study)
    start = len(study.trials)
    shares = [args.trials // args.workers + (i < args.trials % args.workers)
              for i in range(args.workers)]
    print(f"{args.trials} trials, {args.workers} worker(s), {args.folds}-fold CV on "
          f"{len(table.y)} points; study {args.study!r} in {_safe(storage)} "
          f"({start} trials before)", file=sys.stderr)
    if stale:
        killed = _close_killed_runs(study, stale)
        note = f"; MLflow run(s) {', '.join(killed)} ended as KILLED" if killed else ""
        print(f"trials {stale} had no heartbeat (their worker was killed): marked failed{note}",
              file=sys.stderr)
    with tracking.run("tune", f"tune {args.study}") as parent:
        tracking.mlflow_module().log_params(tracking.params({
            "study": args.study, "storage": _safe(storage), "trials": args.trials,
            "workers": args.workers, "folds": args.folds, "seed": args.seed,
            "data_sha256": tracking.data_hash(readings), "target_kind": table.target_kind,
            "noise_floor_um": floor, "trials_before": start, "tag": tag}))
        logger = TrialLogger(parent.info.experiment_id, parent.info.run_id)
        work = {"name": args.study, "storage": storage, "X": table.X, "y": table.y,
                "folds": args.folds, "seed": args.seed, "tag": tag, "start": start,
                "callbacks": (logger,), "heartbeat_s": args.heartbeat_s}
        with _terminate_as_interrupt():
            if args.workers == 1:
                tuning.work(trials=args.trials, worker=0, progress=sys.stderr.isatty(),
                            stop=_STOP, **work)
            else:
                _run_workers(work, shares)
        return _summary(tuning, study, tag, args, stale)


def _same_heartbeat(study, heartbeat_s: int) -> None:
    """Every invocation on a study must use one heartbeat: the grace period is judged by the
    process that looks, so a shorter one would fail trials whose workers are alive."""
    from features.readings.errors import InputError

    recorded = study.user_attrs.get("heartbeat_s")
    if recorded is None:
        study.set_user_attr("heartbeat_s", heartbeat_s)
    elif recorded != heartbeat_s:
        raise InputError(f"study {study.study_name!r} runs with --heartbeat-s {recorded}; give "
                         f"the same (got {heartbeat_s})", column="--heartbeat-s")


def _close_killed_runs(study, stale: list[int]) -> list[str]:
    """The MLflow runs of the invocations whose trials went stale, still RUNNING because their
    process was killed, are ended as KILLED."""
    from pipeline import tracking

    tags = {t.user_attrs.get("tag") for t in study.trials if t.number in stale} - {None}
    if not tags:
        return []
    client = tracking.client()
    found = client.get_experiment_by_name("tune")
    if found is None:
        return []
    closed = []
    for run in client.search_runs([found.experiment_id], "attributes.status = 'RUNNING'"):
        if run.data.params.get("tag") in tags and "mlflow.parentRunId" not in run.data.tags:
            client.set_terminated(run.info.run_id, "KILLED")
            closed.append(run.info.run_id)
    return closed


class TrialLogger:
    """Optuna callback: each finished trial becomes a nested MLflow run under the invocation's
    run at once, from whichever worker process ran it (so a killed invocation keeps the trials
    it finished)."""

    def __init__(self, experiment_id: str, parent_run_id: str):
        self.experiment_id = experiment_id
        self.parent_run_id = parent_run_id

    def __call__(self, study, trial) -> None:
        from pipeline import tracking

        client = tracking.client()
        from mlflow.entities import Metric, Param, RunStatus
        from mlflow.utils.time import get_current_time_millis

        attrs = trial.user_attrs
        run = client.create_run(self.experiment_id, run_name=f"trial {trial.number}", tags={
            "mlflow.parentRunId": self.parent_run_id, "optuna_study": study.study_name,
            "optuna_trial": str(trial.number), "optuna_state": trial.state.name,
            "worker_pid": str(attrs.get("worker_pid", ""))})
        now = get_current_time_millis()
        values = {"cv_rmse_um": trial.value, "cv_rmse_std_um": attrs.get("cv_rmse_std_um")}
        client.log_batch(
            run.info.run_id,
            metrics=[Metric(k, v, now, 0) for k, v in tracking.metrics(values).items()],
            params=[Param(k, v) for k, v in tracking.params(trial.params).items()])
        done = trial.state.name == "COMPLETE"
        client.set_terminated(run.info.run_id, RunStatus.to_string(
            RunStatus.FINISHED if done else RunStatus.FAILED))
        if _STOP.is_set():  # a SIGTERM arrived while this trial was being stored
            raise KeyboardInterrupt


def _open_study(tuning, name, storage, seed, heartbeat_s):
    from features.readings.errors import InputError

    try:
        return tuning.create_study(name, storage, seed, heartbeat_s)
    except Exception as err:  # noqa: BLE001 - any driver error is a bad URL or server for the user
        raise InputError(f"cannot open Optuna storage: {type(err).__name__}: "
                         f"{str(err).strip().splitlines()[0] if str(err).strip() else ''}",
                         column="--storage") from None


class _terminate_as_interrupt:
    """SIGTERM stops the search the way Ctrl-C does, so the running trial is marked FAIL on the
    way out instead of being left RUNNING. A signal that arrives while Optuna stores a finished
    trial or draws the next one takes effect once that is done (interrupting a storage write
    would leave the trial RUNNING): the drawn trial fails at its start, the stored one is
    logged first."""

    def __enter__(self):
        import signal
        import threading

        self._old = None
        _STOP.clear()
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGTERM, _on_terminate)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


def _on_terminate(signum, frame):
    names = set()
    while frame is not None:
        names.add(frame.f_code.co_name)
        frame = frame.f_back
    if "run_trial" in names or "_optimize_sequential" not in names:
        raise KeyboardInterrupt  # inside the objective, or not optimising: stop now
    _STOP.set()  # inside Optuna's bookkeeping: the objective or TrialLogger stops next


def _worker(work: dict, trials: int, worker: int) -> None:
    """Entry point of one worker process: dies with its parent (so a killed ``tune`` leaves no
    orphans running trials) and turns SIGTERM into a clean FAIL of its running trial."""
    import os

    from models import tuning

    _die_with_parent(os.getppid())
    with _terminate_as_interrupt():
        try:
            tuning.work(trials=trials, worker=worker, threads=1, stop=_STOP, **work)
        except KeyboardInterrupt:
            sys.exit(130)


def _die_with_parent(parent: int) -> None:
    import ctypes
    import os
    import signal

    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG: SIGTERM when the parent dies
    except (OSError, AttributeError):
        return  # not Linux: workers finish their share after a killed parent
    if os.getppid() != parent:  # the parent died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


def _run_workers(work: dict, shares: list[int]) -> None:
    import multiprocessing as mp

    context = mp.get_context("spawn")
    procs = [context.Process(target=_worker, args=(work, n, i))
             for i, n in enumerate(shares) if n]
    try:
        for p in procs:
            p.start()
        for p in procs:
            p.join()
    finally:  # interrupted: stop the workers so their running trials are marked failed
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join()
    failed = [p.exitcode for p in procs if p.exitcode]
    if failed:
        raise RuntimeError(f"{len(failed)} tuning worker(s) failed (exit codes {failed})")


def _summary(tuning, study, tag, args, stale) -> int:
    """Best of the study's complete trials, with every state counted."""
    import optuna

    from features.readings.fileio import clean_nan, dumps
    from pipeline import tracking

    count = tuning.counts(study)
    mine = [t for t in study.trials if t.user_attrs.get("tag") == tag]
    mine_done = sum(t.state == optuna.trial.TrialState.COMPLETE for t in mine)
    complete = count.get("complete", 0)
    if complete == 0:
        raise RuntimeError("no trial of the study completed")
    best = study.best_trial
    mlflow = tracking.mlflow_module()
    mlflow.log_params(tracking.params({f"best_{k}": v for k, v in best.params.items()}))
    mlflow.log_metrics(tracking.metrics({
        "best_cv_rmse_um": best.value, "trials_complete": complete,
        "trials_failed": count.get("fail", 0), "trials_this_run": mine_done}))
    others = ", ".join(f"{n} {state}" for state, n in sorted(count.items())
                       if state != "complete")
    print(f"best of {complete} complete trials in the study{f' ({others})' if others else ''}: "
          f"CV RMSE {best.value:.3f} um with {best.params} (trial {best.number}); this run "
          f"completed {mine_done}", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"best_params": best.params, "best_cv_rmse_um": best.value,
                               "best_trial": best.number, "trials": count,
                               "completed_this_run": mine_done, "marked_failed": stale})))
    return 0


def _safe(url: str) -> str:
    """The storage URL without a password."""
    import re

    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)
