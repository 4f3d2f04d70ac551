"""Tune the shallow network (hidden sizes, activation, trainer, regularisation) by K-fold
cross-validation; many processes or machines share a study through its storage. The search
itself is ``models.estimators.tuning``'s; this job hands each finished trial, as its record, to the live
run the runner gives it (``live``), so a killed search keeps the trials it finished.

>>> import backlash as bl
>>> bl.tune("readings.csv", trials=20, storage="sqlite:///optuna.db").best_params  # doctest: +SKIP
"""

from __future__ import annotations

import re
import uuid
from dataclasses import dataclass, field
from numbers import Integral

from features.readings.errors import InputError, Progress
from pipeline.results import Result, TrackingRecord
from pipeline.steps.constraints import HasMethods, Interval
from pipeline.steps.parameters import (
    FEATURES,
    FORMAT,
    RANDOM_SEED,
    TARGET,
    Param,
    python_only,
    readings,
)

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
    # described by the docstring, as every parameter of the signature
    "trials": Param((_COUNT,)),
    "storage": Param((str, None)),
    "study": Param((str, None)),
    "workers": Param((_COUNT,)),
    "folds": Param((Interval(Integral, 2, None, closed="left"),)),
    "heartbeat_s": Param((_COUNT,), metavar="S"),
    # the runner's, when it tracks: the run logged while the search runs (Workflow record's
    # ``logs_while_running``); the command line's --no-track gives none
    "live": python_only(None, HasMethods(["start", "finish"])),
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
    parameters: dict = field(default_factory=dict)
    trial_records: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"best_params": self.best_params, "best_cv_rmse_um": self.best_cv_rmse_um,
                "best_trial": self.best_trial, "study": self.parameters.get("study"),
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
        """The search's run with one nested run per trial (a live run has logged those as
        they finished: it adds the rest)."""
        from pipeline.results import RunRecord

        return RunRecord(experiment="tune", run_name=run_name(self.parameters["study"]),
                         params={**self.parameters, **{f"best_{k}": v
                                                   for k, v in self.best_params.items()}},
                         metrics=self.metrics, children=list(self.trial_records))


def run_name(study: str) -> str:
    return f"tune {study}"


def trial_record(trial: dict) -> TrackingRecord:
    """What the run keeps of one finished trial (``models.estimators.tuning.trial_summary``)."""
    from pipeline.results import RunRecord

    return RunRecord(
        experiment="tune", run_name=f"trial {trial['number']}", params=dict(trial["params"]),
        metrics={"cv_rmse_um": trial["value"], "cv_rmse_std_um": trial["std"]},
        tags={"optuna_study": trial["study"], "optuna_trial": str(trial["number"]),
              "optuna_state": trial["state"], "worker_pid": str(trial["worker_pid"])},
        status="FINISHED" if trial["state"] == "COMPLETE" else "FAILED")


class TrialLogger:
    """Each finished trial's record handed to ``log`` (a live run's ``child``) at once, from
    whichever worker process ran it (so a killed search keeps what it finished); it pickles
    to the workers' processes when ``log`` does."""

    def __init__(self, log):
        self.log = log

    def __call__(self, trial: dict) -> None:
        self.log(trial_record(trial))


def tune(data, *, trials: int = 30, storage: str | None = None,
         study: str | None = None, workers: int = 1, folds: int = 5,
         heartbeat_s: int = 10, format: str = "auto", target: str = "auto",
         features: list[str] | None = None, seed: int = 0, live=None,
         progress: Progress | None = None) -> TuneResult:
    """Search the network's architecture and training settings by cross-validated RMSE.

    Parameters
    ----------
    data, format, target, features, seed
        As for ``train``.
    trials : int
        Trials to run in total (shared among the workers).
    storage : str
        Optuna storage URL (``sqlite:///FILE``, ``postgresql://USER@HOST/DB``); ``bl.tune``
        and ``backlash tune`` default to ``optuna.db`` in the tracking folder (the working
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
    live : optional
        The run logged while the search runs, which the runner gives when it tracks: started
        with the search's parameters (ending first the runs of searches that were killed), it
        takes each trial as soon as it finishes (``child``). Without one, the result's
        ``tracking_record`` holds every trial.
    progress : callable, optional
        ``progress(done, total, what)`` after each trial (one worker only).

    Returns
    -------
    TuneResult
    """
    from models.estimators import tuning
    from pipeline.steps.model_data import model_data

    if storage is None:
        raise InputError("expected a storage URL, e.g. sqlite:///optuna.db (bl.tune and "
                         "backlash tune give the default)", parameter="storage")
    tuning.check_storage(storage)
    loaded = model_data(data, format, target, features)
    table = loaded.table
    if len(table.y) < 2 * folds:
        raise InputError(f"{len(table.y)} backlash points are too few for {folds}-fold "
                         "cross-validation", file=loaded.source)
    study = study or f"{DEFAULT_STUDY}-{loaded.digest[:12]}"
    tag = uuid.uuid4().hex[:12]
    opened = tuning.open_search(study, storage, seed, heartbeat_s, loaded.digest)
    start = opened.before
    params = {"study": study, "storage": safe_url(storage), "trials": trials, "workers": workers,
              "folds": folds, "seed": seed, "data_sha256": loaded.digest,
              "target_kind": table.target_kind, "noise_floor_um": loaded.noise_floor_um,
              "trials_before": start, "tag": tag}
    notes = [(f"{trials} trials, {workers} worker(s), {folds}-fold CV on {len(table.y)} "
              f"points; study {study!r} in {safe_url(storage)} ({start} trials before)")]
    on_trial = ()
    if live is not None:  # killed searches' runs are found by their tag
        notes += live.start(TrackingRecord(experiment="tune", run_name=run_name(study),
                                           params=params), killed=opened.stale_tags)
        on_trial = (TrialLogger(live.child),)
    outcome = tuning.run_search(opened, table.X, table.y, trials=trials, workers=workers,
                                folds=folds, seed=seed, tag=tag, on_trial=on_trial,
                                progress=progress)
    if start:
        notes.append(resumed_note(study, start, opened.first_data, loaded.digest))
    if opened.stale:
        notes.append(f"trials {opened.stale} had no heartbeat (their worker was killed): "
                     "marked failed")
    return TuneResult(
        best_params=outcome.best_params, best_cv_rmse_um=outcome.best_value,
        best_trial=outcome.best_trial, trials=outcome.counts,
        completed_this_run=outcome.completed, marked_failed=opened.stale, parameters=params,
        trial_records=[trial_record(t) for t in outcome.finished], notes=notes)


def resumed_note(study: str, trials: int, first_data: str | None, digest: str) -> str:
    """The note of a study continued: its trials before this call, and whether they were run
    on other data (a name given explicitly to two data sets)."""
    other = first_data is not None and first_data != digest
    return (f"study {study!r} resumed with its {trials} earlier trials"
            + (f", run on other data (sha256 {first_data[:12]}): their scores are ranked "
               "with these" if other else ""))


def safe_url(url: str) -> str:
    """The storage URL without a password."""
    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)
