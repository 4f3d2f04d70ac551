"""Optuna search over the shallow network's architecture and training settings.

Each trial draws hidden sizes (1-3 layers of 2-16 neurons), activation, trainer (LM or Adam)
and L2 regularisation, and scores them by K-fold cross-validated RMSE [um] on the feature table.
Several worker processes, or machines, share one study through its storage URL: a local
SQLite file by default, PostgreSQL for many workers. Running trials send heartbeats, so a
trial whose worker was killed is marked FAIL instead of staying RUNNING, and the sampler's
seed depends only on the given seed, the worker index and the study's size at the start.

A search stops cleanly: SIGTERM stops it the way Ctrl-C does (the running trial is marked
FAIL), worker processes die with their parent, and a signal that arrives while Optuna stores a
finished trial takes effect once that is done (``run_workers``, ``terminate_as_interrupt``).

A search (``open_search``, then ``run_search``) reports each finished trial as plain data
(``trial_summary``) to the ``on_trial`` callables it is given, in whichever worker process ran
the trial; what they do with it (log it somewhere) is their caller's business.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from features.readings.errors import InputError, Progress, report

HEARTBEAT_S = 10
SCHEMA_ATTEMPTS = 5  # tries to open a storage that other workers are creating at the same time
ACTIVATIONS = ("tanh", "relu", "sigmoid")
TRAINERS = ("lm", "adam")
STORAGE_SCHEMES = ("sqlite", "postgresql", "mysql")
STOP = threading.Event()  # set by SIGTERM or SIGINT: the search stops at its next check
INTERRUPTIBLE = {"cv_rmse", "run_workers"}  # where the signal interrupts at once (no storage)


def suggest(trial) -> dict:
    """Network parameters for one trial."""
    n_layers = trial.suggest_int("n_layers", 1, 3)
    hidden = tuple(trial.suggest_int(f"width_{i}", 2, 16) for i in range(n_layers))
    params = {"hidden_sizes": hidden,
              "activation": trial.suggest_categorical("activation", ACTIVATIONS),
              "trainer": trial.suggest_categorical("trainer", TRAINERS),
              "weight_decay": trial.suggest_float("weight_decay", 1e-7, 1e-1, log=True)}
    if params["trainer"] == "adam":
        params["learning_rate"] = trial.suggest_float("learning_rate", 1e-3, 1e-1, log=True)
    return params


def stopped(stop) -> None:
    """Raise KeyboardInterrupt if the ``stop`` event (a SIGTERM's flag) is set."""
    if stop is not None and stop.is_set():
        raise KeyboardInterrupt


def cv_rmse(X, y, params: dict, folds: int = 5, random_state: int = 0) -> np.ndarray:
    """RMSE [um] of each of ``folds`` shuffled folds for a network with ``params``."""
    from sklearn.model_selection import KFold, cross_val_score

    from models.serving import registry

    estimator = registry.make("shallow-lm", random_state, **params)
    split = KFold(folds, shuffle=True, random_state=random_state)
    return -cross_val_score(estimator, X, y, cv=split, scoring="neg_root_mean_squared_error")


def objective(X, y, folds: int, random_state: int, stop=None):
    """Optuna objective: CV RMSE [um] of the drawn network. ``stop`` (a ``threading.Event``):
    once set, a trial that starts fails at once, as if interrupted."""

    def run_trial(trial) -> float:
        stopped(stop)
        params = suggest(trial)  # storage reads and writes: a SIGTERM here only sets the flag
        stopped(stop)
        rmse = cv_rmse(X, y, params, folds, random_state)  # interrupted at once by a SIGTERM
        stopped(stop)  # a SIGTERM whose interrupt was lost (it landed in a finaliser)
        trial.set_user_attr("cv_rmse_std_um", float(rmse.std()))
        return float(rmse.mean())

    return run_trial


def open_storage(url: str, heartbeat_s: int = HEARTBEAT_S):
    """Optuna storage at ``url`` with heartbeats: each running trial's worker reports every
    ``heartbeat_s`` seconds, and a trial silent for twice that is stale (its worker was
    killed) and is marked FAIL by the next worker that opens the study."""
    import optuna

    quiet_optuna(optuna)
    if heartbeat_s < 1:
        raise ValueError(f"heartbeat_s must be at least 1 second, got {heartbeat_s}")
    connect = {"timeout": 60} if url.startswith("sqlite") else {}  # workers wait for the lock
    if url.startswith("postgresql"):
        connect = {"connect_timeout": 10}
    for attempt in range(SCHEMA_ATTEMPTS):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return optuna.storages.RDBStorage(url, heartbeat_interval=heartbeat_s,
                                                  grace_period=2 * heartbeat_s,
                                                  engine_kwargs={"connect_args": connect})
        except Exception as error:
            # two workers creating a fresh storage at once: the loser's insert of the schema
            # version (or its CREATE TABLE) collides with the winner's; the schema is there now
            if attempt == SCHEMA_ATTEMPTS - 1 or not _lost_schema_race(error):
                raise
            time.sleep(0.2 * (attempt + 1))


def quiet_optuna(optuna) -> None:
    """Optuna's log lines (``A new study created in RDB``, one per finished trial) off, errors
    aside, unless the user asked for them (``features.readings.errors.verbose``): the search
    reports through its result and its progress callback."""
    from features.readings.errors import verbose

    if not verbose():
        optuna.logging.set_verbosity(optuna.logging.ERROR)


def _lost_schema_race(error: Exception) -> bool:
    import sqlalchemy.exc

    if isinstance(error, sqlalchemy.exc.IntegrityError):
        return True
    return (isinstance(error, (sqlalchemy.exc.ProgrammingError, sqlalchemy.exc.OperationalError))
            and "already exists" in str(error))


def sampler_seed(seed: int, worker: int = 0, start: int = 0) -> int:
    """Seed of one worker's sampler, decided by ``seed`` alone: distinct per worker (so
    workers do not draw alike) and per number of trials the study held when the invocation
    started (so resuming a study does not repeat its first draws)."""
    return int(np.random.SeedSequence([seed, worker, start]).generate_state(1)[0])


def create_study(name: str, storage, seed: int, heartbeat_s: int = HEARTBEAT_S,
                 tag: str | None = None):
    """The named study (created if new) with a TPE sampler seeded by ``seed``; ``storage`` is
    a URL or an opened storage. With ``tag`` (the search's label), each trial this study runs
    is labelled with it and its worker's pid as it is created."""
    import optuna

    if isinstance(storage, str):
        storage = open_storage(storage, heartbeat_s)
    sampler = tagging_sampler(seed, tag, storage) if tag else optuna.samplers.TPESampler(seed=seed)
    return optuna.create_study(study_name=name, storage=storage, direction="minimize",
                               sampler=sampler, load_if_exists=True)


def tagging_sampler(seed: int, tag: str, storage):
    """TPE sampler that, as Optuna creates a trial and before its heartbeat thread starts,
    records the trial's first heartbeat and then labels it with ``tag`` and the worker's pid.

    A worker killed at any later moment leaves a trial that goes stale and names its search,
    so the next ``tune`` can end that search's MLflow run; labelled inside the objective, a
    trial killed between its first heartbeat and the label went stale without a name."""
    import optuna

    class TaggingSampler(optuna.samplers.TPESampler):
        def before_trial(self, study, trial) -> None:
            storage.record_heartbeat(trial._trial_id)
            storage.set_trial_user_attr(trial._trial_id, "tag", tag)
            storage.set_trial_user_attr(trial._trial_id, "worker_pid", os.getpid())
            super().before_trial(study, trial)

    return TaggingSampler(seed=seed)


def fail_stale_trials(study) -> list[int]:
    """Mark the study's stale RUNNING trials (no heartbeat for the grace period) FAIL; returns
    their numbers."""
    import optuna

    running = {t._trial_id: t.number for t in study.get_trials(
        deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        optuna.storages.fail_stale_trials(study)
    still = {t._trial_id for t in study.get_trials(
        deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))}
    return sorted(number for trial_id, number in running.items() if trial_id not in still)


def check_storage(url: str) -> str:
    """``url`` if it names a database Optuna can share between processes, else one line."""
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


def open_study(name: str, storage: str, seed: int, heartbeat_s: int):
    """The named study; every call on it must use one heartbeat (the grace period is judged by
    the process that looks, so a shorter one would fail trials whose workers are alive)."""
    try:
        study = create_study(name, storage, seed, heartbeat_s)
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


@dataclass
class Opened:
    """A study opened for a search (``open_search``).

    Attributes
    ----------
    study : optuna.Study
    storage : str
        Its storage URL.
    heartbeat_s : int
    stale : list of int
        Trials found stale (their worker was killed) and marked FAIL as it opened.
    stale_tags : set of str
        The labels of the searches those trials belonged to: searches that were killed.
    before : int
        Trials in the study before this search.
    first_data : str or None
        The data digest the study began on (None: it begins now, on this search's data).
    """

    study: object
    storage: str
    heartbeat_s: int
    stale: list[int] = field(default_factory=list)
    stale_tags: set[str] = field(default_factory=set)
    before: int = 0
    first_data: str | None = None


def open_search(name: str, storage: str, seed: int, heartbeat_s: int,
                data_sha256: str) -> Opened:
    """Open study ``name`` in ``storage`` (``check_storage``, ``open_study``) for a search on
    the data of digest ``data_sha256``: its stale trials marked FAIL, the data it began on
    recorded when it is new."""
    study = open_study(name, check_storage(storage), seed, heartbeat_s)
    stale = fail_stale_trials(study)
    tags = {t.user_attrs.get("tag") for t in study.trials if t.number in stale} - {None}
    first = study.user_attrs.get("data_sha256")
    if first is None:  # the data the study began on: a later call on other data is told
        study.set_user_attr("data_sha256", data_sha256)
    return Opened(study, storage, heartbeat_s, stale, tags, len(study.trials), first)


def trial_summary(study, trial) -> dict:
    """One finished trial as plain data: ``study`` (its name), ``number``, ``params``,
    ``value`` (mean CV RMSE [um], None when it failed), ``std`` (of the folds' RMSE),
    ``state`` (``COMPLETE``, ``FAIL``...) and ``worker_pid``."""
    attrs = trial.user_attrs
    return {"study": study.study_name, "number": trial.number, "params": dict(trial.params),
            "value": trial.value, "std": attrs.get("cv_rmse_std_um"),
            "state": trial.state.name, "worker_pid": attrs.get("worker_pid", "")}


@dataclass
class Outcome:
    """The study after a search (``run_search``).

    Attributes
    ----------
    best_params : dict
        Parameters of the study's best complete trial.
    best_value : float
        Its mean CV RMSE [um].
    best_trial : int
    counts : dict
        Trials of the study by state (``counts``).
    finished : list of dict
        This search's finished trials (``trial_summary``), by number.
    completed : int
        This search's complete trials.
    """

    best_params: dict
    best_value: float
    best_trial: int
    counts: dict
    finished: list[dict]
    completed: int


def run_search(opened: Opened, X, y, *, trials: int, workers: int = 1, folds: int = 5,
               seed: int = 0, tag: str, on_trial: tuple = (),
               progress: Progress | None = None) -> Outcome:
    """Run ``trials`` trials of the opened study in this process or shared among ``workers``
    processes (``search``), its trials labelled ``tag``.

    ``on_trial`` callables get each finished trial's ``trial_summary`` in the process that ran
    it (with several workers they travel to the workers' processes: they must pickle);
    ``progress(done, total, what)`` hears of each trial (one worker only).

    Raises
    ------
    RuntimeError
        When no trial of the study completed.
    """
    import optuna

    if workers == 1:
        done = []

        def reported(summary: dict) -> None:
            done.append(summary["number"])
            report(progress, len(done), trials, f"trial {summary['number']}")

        on_trial = (*on_trial, reported)
    search({"name": opened.study.study_name, "storage": opened.storage, "X": X, "y": y,
            "folds": folds, "seed": seed, "tag": tag, "start": opened.before,
            "heartbeat_s": opened.heartbeat_s, "on_trial": tuple(on_trial)}, trials, workers)
    study = opened.study
    count = counts(study)
    if count.get("complete", 0) == 0:
        raise RuntimeError("no trial of the study completed")
    mine = [t for t in study.trials if t.user_attrs.get("tag") == tag]
    best = study.best_trial
    return Outcome(
        best_params=best.params, best_value=best.value, best_trial=best.number, counts=count,
        finished=[trial_summary(study, t) for t in mine if t.state.is_finished()],
        completed=sum(t.state == optuna.trial.TrialState.COMPLETE for t in mine))


def counts(study) -> dict[str, int]:
    """Trials of the study by state (``complete``, ``fail``, ``running``, ``pruned``, ...)."""
    out: dict[str, int] = {}
    for trial in study.get_trials(deepcopy=False):
        name = trial.state.name.lower()
        out[name] = out.get(name, 0) + 1
    return out


def work(name: str, storage: str, X, y, trials: int, folds: int, seed: int, tag: str,
         worker: int = 0, start: int = 0, threads: int | None = None,
         on_trial: tuple = (), heartbeat_s: int = HEARTBEAT_S, stop=None) -> None:
    """One worker: run ``trials`` trials of the shared study.

    The sampler seed comes from ``seed``, the worker's index and ``start`` (trials in the study
    when the invocation began), never from the process, so one ``seed`` gives one study.
    ``on_trial`` callables get each finished trial's ``trial_summary``; ``stop`` is passed to
    the objective, and checked once they are done (a SIGTERM that arrived while the trial was
    stored or reported stops the search there).
    """
    import optuna
    import sklearn.model_selection  # noqa: F401 - imported before a SIGTERM may interrupt cv_rmse
    import torch

    import models.estimators.network  # noqa: F401

    if threads:
        torch.set_num_threads(threads)
    quiet_optuna(optuna)
    study = create_study(name, storage, sampler_seed(seed, worker, start), heartbeat_s, tag)
    stopped(stop)

    def finished(study, trial) -> None:
        summary = trial_summary(study, trial)
        for call in on_trial:
            call(summary)
        stopped(stop)

    study.optimize(objective(X, y, folds, seed, stop), n_trials=trials, callbacks=[finished])


def search(work_args: dict, trials: int, workers: int = 1) -> None:
    """Run ``trials`` trials of ``work`` (its other arguments in ``work_args``) in this process
    or shared among ``workers`` processes, SIGTERM handled as an interrupt."""
    with terminate_as_interrupt():
        if workers == 1:
            work(trials=trials, worker=0, stop=STOP, **work_args)
        else:
            shares = [trials // workers + (i < trials % workers) for i in range(workers)]
            run_workers(work_args, shares)


class terminate_as_interrupt:
    """SIGTERM and Ctrl-C (SIGINT) stop the search as an interrupt, so the running trial is
    marked FAIL on the way out instead of being left RUNNING.

    The interrupt is raised at once only where nothing is half-done: while a trial's folds are
    fitted (``cv_rmse``) or while this process waits for its workers. Anywhere else (Optuna
    storing a trial or drawing parameters, an import) the signal sets ``STOP``, and the
    objective, the callbacks and ``work`` stop at their next check: a read interrupted with
    its cursor open keeps the SQLite lock, and the trial could not then be marked FAIL."""

    def __enter__(self):
        import signal

        self._old = {}
        STOP.clear()
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGTERM, signal.SIGINT):  # Ctrl-C obeys the same rules
                self._old[signum] = signal.signal(signum, _on_terminate)
        return self

    def __exit__(self, *exc):
        import signal

        for signum, handler in self._old.items():
            signal.signal(signum, handler)
        return False


def _on_terminate(signum, frame):
    # set first: the interrupt below is lost when the signal lands in a finaliser or weakref
    # callback, and the objective and the callbacks then stop on the flag
    STOP.set()
    names = set()
    while frame is not None:
        names.add(frame.f_code.co_name)
        frame = frame.f_back
    if names & INTERRUPTIBLE:
        raise KeyboardInterrupt


def _worker(work_args: dict, trials: int, worker: int) -> None:
    """Entry point of one worker process: dies with its parent (so a killed search leaves no
    orphans running trials) and turns SIGTERM into a clean FAIL of its running trial."""
    _die_with_parent(os.getppid())
    with terminate_as_interrupt():
        try:
            work(trials=trials, worker=worker, threads=1, stop=STOP, **work_args)
        except KeyboardInterrupt:
            sys.exit(130)


def _die_with_parent(parent: int) -> None:
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG: SIGTERM when the parent dies
    except (OSError, AttributeError):
        return  # not Linux: workers finish their share after a killed parent
    if os.getppid() != parent:  # the parent died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


def run_workers(work_args: dict, shares: list[int]) -> None:
    """One spawned process per non-empty share; all stopped if this one is interrupted."""
    import multiprocessing as mp

    context = mp.get_context("spawn")
    procs = [context.Process(target=_worker, args=(work_args, n, i))
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
