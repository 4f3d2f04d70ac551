"""Tune the shallow network (hidden sizes, activation, trainer, regularisation) by K-fold
cross-validation with Optuna; many processes or machines share a study through its storage.

>>> import backlash as bl
>>> bl.tune("readings.csv", trials=20, storage="sqlite:///optuna.db").best_params  # doctest: +SKIP
"""

from __future__ import annotations

import re
import uuid
from dataclasses import dataclass, field
from numbers import Integral
from pathlib import Path

from features.readings.errors import InputError, Progress, report
from pipeline.results import Result, TrackingRecord
from pipeline.steps.parameters import (
    FEATURES,
    FORMAT,
    RANDOM_SEED,
    TARGET,
    Param,
    python_only,
    readings,
)
from pipeline.workflows import check_params
from pipeline.workflows.constraints import Interval

DEFAULT_STUDY = "backlash-network"  # the default study name: this, then the data's digest
_COUNT = Interval(Integral, 1, None, closed="left")
# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{small}", "--trials", "2", "--folds", "2", "--storage", "sqlite:///{base}/o.db"],
    {"data": "{small}", "trials": 2, "folds": 2, "storage": "sqlite:///{base}/o.db"},
)

PARAMETERS = {
    "data": readings(),
    "format": FORMAT,
    "target": TARGET,
    "features": FEATURES,
    "seed": RANDOM_SEED,
    "trials": Param((_COUNT,), "trials to run in total"),
    "storage": Param((str, None), "Optuna storage URL, e.g. postgresql://user@host/db "
                     "(default: sqlite:///optuna.db)"),
    "study": Param((str, None), f"study name (default {DEFAULT_STUDY}-DIGEST, DIGEST the first "
                   "12 hex digits of the data's SHA-256: one study per data)"),
    "workers": Param((_COUNT,), "worker processes sharing the study"),
    "folds": Param((Interval(Integral, 2, None, closed="left"),), "cross-validation folds"),
    "heartbeat_s": Param((_COUNT,), "running trials report every S seconds; a trial silent for "
                         "2 S (its worker was killed) is marked failed", metavar="S"),
    "track": python_only("boolean"),  # the runner's: the command line's --no-track
}


@dataclass
class TuneResult(Result):
    """The study after this call's trials.

    Attributes
    ----------
    best_params : dict
        Network parameters of the study's best complete trial.
    best_cv_rmse_um : float
        Its mean cross-validated RMSE [um].
    best_trial : int
    trials : dict
        Trials of the study by state (``complete``, ``fail``, ...).
    completed_this_run : int
    marked_failed : list of int
        Trials found stale (their worker was killed) and marked FAIL when the study opened.
    trial_records : list of TrackingRecord
        One per trial this call ran (nested runs when the result is logged).
    """

    best_params: dict
    best_cv_rmse_um: float
    best_trial: int
    trials: dict
    completed_this_run: int
    marked_failed: list[int]
    params: dict = field(default_factory=dict)
    trial_records: list = field(default_factory=list)
    logged: bool = False  # trials and run logged to MLflow while the search ran (track=True)

    def to_json(self) -> dict:
        return {"best_params": self.best_params, "best_cv_rmse_um": self.best_cv_rmse_um,
                "best_trial": self.best_trial, "study": self.params.get("study"),
                "trials": self.trials,
                "completed_this_run": self.completed_this_run,
                "marked_failed": self.marked_failed}

    @property
    def metrics(self) -> dict:
        return {"best_cv_rmse_um": self.best_cv_rmse_um,
                "trials_complete": self.trials.get("complete", 0),
                "trials_failed": self.trials.get("fail", 0),
                "trials_this_run": self.completed_this_run}

    def tracking_record(self):
        """The search's run with one nested run per trial; None when ``tune(track=True)``
        logged it while it ran."""
        if self.logged:
            return None
        from pipeline.results import RunRecord

        return RunRecord(experiment="tune", run_name=f"tune {self.params['study']}",
                         params={**self.params, **{f"best_{k}": v
                                                   for k, v in self.best_params.items()}},
                         metrics=self.metrics, children=list(self.trial_records))


def trial_record(study, trial) -> TrackingRecord:
    """What MLflow keeps of one finished Optuna trial."""
    from pipeline.results import RunRecord

    attrs = trial.user_attrs
    return RunRecord(
        experiment="tune", run_name=f"trial {trial.number}", params=dict(trial.params),
        metrics={"cv_rmse_um": trial.value, "cv_rmse_std_um": attrs.get("cv_rmse_std_um")},
        tags={"optuna_study": study.study_name, "optuna_trial": str(trial.number),
              "optuna_state": trial.state.name, "worker_pid": str(attrs.get("worker_pid", ""))},
        status="FINISHED" if trial.state.name == "COMPLETE" else "FAILED")


class TrialLogger:
    """Optuna callback: each finished trial becomes a nested MLflow run under the search's run
    at once, from whichever worker process ran it (so a killed search keeps what it
    finished)."""

    def __init__(self, experiment_id: str, parent_run_id: str):
        self.experiment_id = experiment_id
        self.parent_run_id = parent_run_id

    def __call__(self, study, trial) -> None:
        from models.tuning import STOP, stopped
        from pipeline.tracking.runs import log_child

        log_child(self.experiment_id, self.parent_run_id, trial_record(study, trial))
        stopped(STOP)  # a SIGTERM arrived while this trial was being stored


def tune(data, *, trials: int = 30, storage: str | None = None,
         study: str | None = None, workers: int = 1, folds: int = 5,
         heartbeat_s: int = 10, format: str = "auto", target: str = "auto",
         features: list[str] | None = None, seed: int = 0, track: bool = False,
         progress: Progress | None = None) -> TuneResult:
    """Search the network's architecture and training settings by cross-validated RMSE.

    Parameters
    ----------
    data, format, target, features, seed
        As for ``train``.
    trials : int
        Trials to run in total (shared among the workers).
    storage : str, optional
        Optuna storage URL (``sqlite:///FILE``, ``postgresql://USER@HOST/DB``); default
        ``optuna.db`` in the tracking folder (``pipeline.tracking.runs.study_storage``: the working
        directory unless ``BACKLASH_TRACKING_DIR`` names another).
    study : str, optional
        Study name; a study that exists is continued (a note says so, with its trials).
        Default ``backlash-network-<digest>``, ``<digest>`` the first 12 hex digits of the
        data's SHA-256 (``data_sha256``): two data sets never share a study, and a rotary
        campaign's trials [arcsec] are never ranked with a linear one's [um].
    workers : int
        Worker processes sharing the study.
    folds : int
        Cross-validation folds.
    heartbeat_s : int
        Running trials report every ``heartbeat_s`` seconds [s]; a trial silent for twice that
        (its worker was killed) is marked failed. Every call on a study must use the same.
    track : bool
        Log to MLflow while the search runs: the search's run first, then each trial as soon as
        it finishes (so a killed search keeps its finished trials), and end the runs of killed
        searches as KILLED. Otherwise ``pipeline.tracking.runs.log_result`` logs the result.
    progress : callable, optional
        ``progress(done, total, what)`` after each trial (one worker only).

    Returns
    -------
    TuneResult
    """
    from models import tuning
    from pipeline.steps.model_data import model_data
    from pipeline.tracking import runs as tracking

    check_params(PARAMETERS, {"data": data, "trials": trials, "storage": storage,
                              "study": study, "workers": workers, "folds": folds,
                              "heartbeat_s": heartbeat_s, "format": format, "target": target,
                              "features": features, "seed": seed, "track": track}, "tune")
    storage = check_storage(storage or tracking.study_storage())
    loaded = model_data(data, format, target, features)
    table = loaded.table
    if len(table.y) < 2 * folds:
        raise InputError(f"{len(table.y)} backlash points are too few for {folds}-fold "
                         "cross-validation", file=loaded.source)
    study = study or f"{DEFAULT_STUDY}-{loaded.digest[:12]}"
    tag = uuid.uuid4().hex[:12]
    opened = open_study(study, storage, seed, heartbeat_s)
    stale = tuning.fail_stale_trials(opened)
    first_data = opened.user_attrs.get("data_sha256")
    if first_data is None:  # the data the study began on: a later call on other data is told
        opened.set_user_attr("data_sha256", loaded.digest)
    start = len(opened.trials)
    params = {"study": study, "storage": safe_url(storage), "trials": trials, "workers": workers,
              "folds": folds, "seed": seed, "data_sha256": loaded.digest,
              "target_kind": table.target_kind, "noise_floor_um": loaded.noise_floor_um,
              "trials_before": start, "tag": tag}
    work = {"name": study, "storage": storage, "X": table.X, "y": table.y, "folds": folds,
            "seed": seed, "tag": tag, "start": start, "heartbeat_s": heartbeat_s}
    notes = [(f"{trials} trials, {workers} worker(s), {folds}-fold CV on {len(table.y)} "
              f"points; study {study!r} in {safe_url(storage)} ({start} trials before)")]
    if not track:
        result = _search(tuning, opened, work, trials, workers, progress, params, stale)
    else:
        killed = _close_killed_runs(opened, stale)
        with tracking.run("tune", f"tune {study}") as parent:
            tracking.mlflow_module().log_params(tracking.params(params))
            work["callbacks"] = (TrialLogger(parent.info.experiment_id, parent.info.run_id),)
            result = _search(tuning, opened, work, trials, workers, progress, params, stale)
            tracking.log_into({"params": {f"best_{k}": v for k, v in result.best_params.items()},
                               "metrics": result.metrics})
            result.logged = True
        if killed:
            notes.append(f"MLflow run(s) {', '.join(killed)} of killed searches ended as KILLED")
    if start:
        notes.append(resumed_note(study, start, first_data, loaded.digest))
    if stale:
        notes.append(f"trials {stale} had no heartbeat (their worker was killed): marked failed")
    result.notes = notes
    return result


def _search(tuning, opened, work, trials, workers, progress, params, stale) -> TuneResult:
    import optuna

    records = []

    def keep(study, trial):  # in this process only (one worker); others log from theirs
        records.append(trial_record(study, trial))
        report(progress, len(records), trials, f"trial {trial.number}")

    if workers == 1:
        work = {**work, "callbacks": (*work.get("callbacks", ()), keep)}
    tuning.search(work, trials, workers)
    count = tuning.counts(opened)
    if count.get("complete", 0) == 0:
        raise RuntimeError("no trial of the study completed")
    mine = [t for t in opened.trials if t.user_attrs.get("tag") == work["tag"]]
    if workers > 1:
        records = [trial_record(opened, t) for t in mine if t.state.is_finished()]
    best = opened.best_trial
    return TuneResult(
        best_params=best.params, best_cv_rmse_um=best.value, best_trial=best.number,
        trials=count, marked_failed=stale, params=params, trial_records=records,
        completed_this_run=sum(t.state == optuna.trial.TrialState.COMPLETE for t in mine))


def check_storage(url: str) -> str:
    """``url`` if it names a database Optuna can share between processes, else one line."""
    from models.tuning import STORAGE_SCHEMES

    scheme = url.split("://", 1)[0].split("+", 1)[0].lower() if "://" in url else ""
    if scheme not in STORAGE_SCHEMES:
        raise InputError(f"unsupported storage URL {url!r}; expected sqlite:///FILE or "
                         "postgresql://USER@HOST/DB", parameter="storage")
    if scheme == "sqlite":
        path = url.split("sqlite:///", 1)[1].split("?", 1)[0] if "sqlite:///" in url else ""
        if not path or path == ":memory:" or path.startswith("file::memory:"):
            raise InputError(f"storage URL {url!r} keeps the study in one process's memory, "
                             "which workers and later runs cannot share; expected "
                             "sqlite:///FILE", parameter="storage")
        file = Path(path).absolute()
        if file.is_dir() or not file.parent.is_dir():
            raise InputError(f"storage URL {url!r}: {file.parent} must be an existing folder "
                             "and the file not a folder", parameter="storage")
    return url


def resumed_note(study: str, trials: int, first_data: str | None, digest: str) -> str:
    """The note of a study continued: its trials before this call, and whether they were run
    on other data (a name given explicitly to two data sets)."""
    other = first_data is not None and first_data != digest
    return (f"study {study!r} resumed with its {trials} earlier trials"
            + (f", run on other data (sha256 {first_data[:12]}): their scores are ranked "
               "with these" if other else ""))


def open_study(name: str, storage: str, seed: int, heartbeat_s: int):
    """The named study; every call on it must use one heartbeat (the grace period is judged by
    the process that looks, so a shorter one would fail trials whose workers are alive)."""
    from models import tuning

    try:
        study = tuning.create_study(name, storage, seed, heartbeat_s)
    except Exception as err:  # noqa: BLE001 - any driver error is a bad URL or server for the user
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        raise InputError(f"cannot open Optuna storage: {type(err).__name__}: {first}",
                         parameter="storage") from None
    recorded = study.user_attrs.get("heartbeat_s")
    if recorded is None:
        study.set_user_attr("heartbeat_s", heartbeat_s)
    elif recorded != heartbeat_s:
        raise InputError(f"study {name!r} runs with a heartbeat of {recorded} s; give the same "
                         f"(got {heartbeat_s})", parameter="heartbeat_s")
    return study


def _close_killed_runs(study, stale: list[int]) -> list[str]:
    """The MLflow runs of the searches whose trials went stale, still RUNNING because their
    process was killed, are ended as KILLED."""
    from pipeline.tracking import runs as tracking

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


def safe_url(url: str) -> str:
    """The storage URL without a password."""
    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)
