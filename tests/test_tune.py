"""Optuna tuning: local storage, several worker processes sharing one PostgreSQL study, a
tune killed mid-study and resumed, one seed giving one study, bad storage URLs."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

import mlflow
import optuna
import pytest
from test_targets import ideal_tests

from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def readings_csv(tmp_path):
    path = tmp_path / "readings.csv"
    ideal_tests(direct=True).to_csv(path, index=False)
    return path


def nested_trial_runs() -> list:
    experiment = mlflow.get_experiment_by_name("tune")
    runs = mlflow.search_runs([experiment.experiment_id], output_format="list")
    return [r for r in runs if r.info.run_name.startswith("trial ")]


def test_local_study_logs_every_trial(readings_csv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["tune", str(readings_csv), "--trials", "3", "--folds", "3", "--json"]) == 0
    best = json.loads(capsys.readouterr().out)
    assert best["best_cv_rmse_um"] > 0 and "activation" in best["best_params"]
    assert best["study"].startswith("backlash-network-")  # one study per data
    study = optuna.load_study(study_name=best["study"], storage="sqlite:///optuna.db")
    assert len(study.trials) == 3 and len(nested_trial_runs()) == 3


@pytest.mark.postgres
def test_two_workers_share_a_postgres_study(readings_csv, postgres_url, capsys):
    args = ["tune", str(readings_csv), "--trials", "4", "--folds", "3", "--workers", "2",
            "--storage", postgres_url, "--study", "shared"]
    assert main(args) == 0
    study = optuna.load_study(study_name="shared", storage=postgres_url)
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(done) == 4
    assert len({t.user_attrs["worker_pid"] for t in done}) == 2
    assert len(nested_trial_runs()) == 4
    # a second invocation (another machine) adds to the same study
    assert main(["tune", str(readings_csv), "--trials", "2", "--folds", "3",
                 "--storage", postgres_url, "--study", "shared"]) == 0
    assert len(optuna.load_study(study_name="shared", storage=postgres_url).trials) == 6


@pytest.mark.parametrize("url, words", [
    ("redis://x", "unsupported storage URL"),
    ("optuna.db", "unsupported storage URL"),
    ("sqlite:///:memory:", "one process's memory"),
    ("sqlite://", "one process's memory"),
    ("sqlite:///{tmp}/no/such/folder/optuna.db", "must be an existing folder"),
    ("sqlite:///{tmp}", "the file not a folder"),
    ("postgresql://nobody@127.0.0.1:1/none", "cannot open Optuna storage"),
])
def test_bad_storage_url_is_one_line(readings_csv, tmp_path, capsys, url, words):
    assert main(["tune", str(readings_csv), "--storage", url.format(tmp=tmp_path)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("backlash")]
    assert len(err) == 1 and words in err[0] and "--storage" in err[0], err
    assert not (tmp_path / "no").exists()


def backlash(*args: str, cwd: Path) -> subprocess.Popen:
    """``backlash ARGS`` in its own process, tracking into the test's MLflow store."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "pipeline.cli", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def read(storage: str, query: str) -> list[tuple]:
    """Rows of ``query`` on a SQLite ``storage``, read without writing: an observer that
    opened the storage through Optuna would create its schema alongside ``tune``."""
    path = storage.removeprefix("sqlite:///")
    try:
        with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=60)) as db:
            return db.execute(query).fetchall()
    except sqlite3.OperationalError:  # no file or no tables yet
        return []


def states(storage: str) -> list[str]:
    return [state for (state,) in read(storage, "SELECT state FROM trials ORDER BY number")]


def labelled(storage: str, number: int) -> bool:
    """Whether trial ``number`` carries its search's tag (recorded after its first heartbeat)."""
    return bool(read(storage, "SELECT 1 FROM trial_user_attributes a JOIN trials t "
                              f"USING (trial_id) WHERE t.number = {number} AND a.key = 'tag'"))


def test_workers_creating_one_fresh_storage_at_once_all_open_it(tmp_path):
    """Workers started together on a new storage all try to create its schema; the ones that
    lose the race open what the winner made instead of failing."""
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    start = time.time() + 2  # all four past their imports before any opens the storage
    code = ("import sys, time; from models.estimators.tuning import open_storage\n"
            f"time.sleep(max(0, {start} - time.time())); open_storage(sys.argv[1], 1)")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    procs = [subprocess.Popen([sys.executable, "-c", code, storage], env=env,
                              stderr=subprocess.PIPE, text=True) for _ in range(4)]
    errors = [proc.communicate(timeout=120)[1] for proc in procs]
    assert [proc.returncode for proc in procs] == [0] * 4, errors
    assert states(storage) == []  # schema made once and readable


def test_a_storage_error_other_than_the_schema_race_is_not_retried(tmp_path, monkeypatch):
    import sqlalchemy.exc

    from models.estimators import tuning

    calls = []

    def refuse(*args, **kwargs):
        calls.append(args)
        raise sqlalchemy.exc.OperationalError("open", {}, Exception("disk I/O error"))

    monkeypatch.setattr(optuna.storages, "RDBStorage", refuse)
    with pytest.raises(sqlalchemy.exc.OperationalError, match="disk I/O"):
        tuning.open_storage(f"sqlite:///{tmp_path / 'optuna.db'}", 1)
    assert len(calls) == 1


def test_killed_tune_fails_its_trial_and_resumes_honestly(readings_csv, tmp_path, capsys):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    common = ["--folds", "2", "--storage", storage, "--heartbeat-s", "1"]
    proc = backlash("tune", str(readings_csv), "--trials", "200", *common, cwd=tmp_path)
    deadline, seen = time.monotonic() + 120, None
    while time.monotonic() < deadline:  # kill it inside a trial after one finished
        now = states(storage)
        if now.count("COMPLETE") >= 1 and now[-1:] == ["RUNNING"]:
            if seen is not None and len(now) > seen and labelled(storage, len(now) - 1):
                break  # a trial that began since the last look: far from its end
            seen = seen or len(now)
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.1)
    else:
        pytest.fail("tune did not finish a trial in 120 s")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = states(storage)
    killed = len(before) - 1 - before[::-1].index("RUNNING")
    assert before.count("RUNNING") == 1
    # the finished trials of the killed invocation are in MLflow already
    logged = {r.info.run_name: r for r in nested_trial_runs()}
    assert len(logged) == before.count("COMPLETE")
    assert all(r.info.status == "FINISHED" and "cv_rmse_um" in r.data.metrics
               for r in logged.values())

    # longer than the grace period of 2 heartbeats as SQLite judges it: its clock has whole
    # seconds, so 2.5 s can read as 2 and the trial would still look alive
    time.sleep(3.5)
    capsys.readouterr()
    assert main(["tune", str(readings_csv), "--trials", "1", "--json", *common]) == 0
    out = capsys.readouterr()
    result = json.loads(out.out)
    after = states(storage)
    assert after[killed] == "FAIL" and "RUNNING" not in after
    assert result["marked_failed"] == [killed]
    complete = before.count("COMPLETE") + 1
    assert result["trials"] == {"complete": complete, "fail": 1}
    assert f"best of {complete} complete trials in the study (1 fail)" in out.err
    assert len(nested_trial_runs()) == complete
    # the killed invocation's own run is ended as KILLED, not left RUNNING
    tune_runs = mlflow.search_runs(experiment_names=["tune"], output_format="list")
    parents = sorted((r.info.start_time, r.info.status) for r in tune_runs
                     if not r.info.run_name.startswith("trial "))
    assert [status for _, status in parents] == ["KILLED", "FINISHED"]
    # a different heartbeat would judge live workers by the wrong grace period
    capsys.readouterr()
    assert main(["tune", str(readings_csv), *common[:-1], "5"]) == 2
    err = capsys.readouterr().err
    assert "--heartbeat-s" in err and "runs with a heartbeat of 1 s" in err


def test_a_trial_is_labelled_and_beating_from_its_creation(tmp_path):
    """A worker killed before its objective starts leaves a trial that goes stale and names
    its search: the sampler records the first heartbeat and the tag as Optuna creates it."""
    from models.estimators import tuning

    study = tuning.create_study("s", f"sqlite:///{tmp_path / 'optuna.db'}", 0, 1, tag="abc")
    with pytest.warns(UserWarning, match="Heartbeat"):  # no heartbeat thread: "killed" at once
        trial = study.ask()
    assert study.trials[0].user_attrs == {"tag": "abc", "worker_pid": os.getpid()}
    time.sleep(3.5)  # past the grace period of 2 s on SQLite's whole-second clock
    assert tuning.fail_stale_trials(study) == [trial.number]
    assert study.trials[0].state == optuna.trial.TrialState.FAIL


def test_same_seed_same_study_across_processes(readings_csv, tmp_path):
    """The sampler's seed is the user's seed, not the process: a run in another process with
    the same seed draws the same trials."""
    from models.estimators.tuning import sampler_seed

    runs = {}
    for name, where in (("a", "child"), ("b", "here")):
        storage = f"sqlite:///{tmp_path / name}.db"
        args = ["tune", str(readings_csv), "--trials", "2", "--folds", "2", "--seed", "7",
                "--storage", storage, "--study", "seeded"]
        if where == "child":
            proc = backlash(*args, cwd=tmp_path)
            _, err = proc.communicate(timeout=300)  # drains the pipes while it waits
            assert proc.returncode == 0, err[-2000:]
        else:
            assert main(args) == 0
        study = optuna.load_study(study_name="seeded", storage=storage)
        runs[name] = [(t.params, t.value) for t in study.trials]
    assert [p for p, _ in runs["a"]] == [p for p, _ in runs["b"]]
    assert [v for _, v in runs["a"]] == pytest.approx([v for _, v in runs["b"]], rel=1e-6)
    # another seed, another worker or a resumed study (trials before) draw differently
    seeds = {sampler_seed(7), sampler_seed(8), sampler_seed(7, worker=1), sampler_seed(7, start=2)}
    assert len(seeds) == 4


def test_a_swallowed_terminate_still_fails_the_running_trial(monkeypatch):
    """A SIGTERM landing in a finaliser loses its KeyboardInterrupt ("Exception ignored");
    the flag the handler sets first still fails the trial, instead of letting the search run
    on to its last trial."""
    import threading

    from models.estimators import tuning

    stop = threading.Event()

    def cv_rmse_terminated(*args):  # the signal arrives during the folds, its raise is lost
        stop.set()
        return tuning.np.array([0.1, 0.2])

    monkeypatch.setattr(tuning, "cv_rmse", cv_rmse_terminated)
    study = optuna.create_study()
    with pytest.raises(KeyboardInterrupt):
        study.optimize(tuning.objective(None, None, 2, 0, stop), n_trials=5)
    assert [t.state.name for t in study.trials] == ["FAIL"]


def test_a_sigterm_during_a_storage_read_lets_it_finish(tmp_path, monkeypatch):
    """A SIGTERM landing while the sampler reads the study only sets the flag: the read
    completes and the trial fails at the next check. Interrupted there, the read's open cursor
    kept SQLite's lock, marking the trial FAIL waited 60 s for it and failed, and the trial
    stayed RUNNING. Inside the folds a SIGTERM interrupts at once."""
    import sys

    import sqlalchemy.engine.default

    from models.estimators import tuning

    execute = sqlalchemy.engine.default.DefaultDialect.do_execute
    fired = []

    def execute_then_terminate(self, cursor, statement, *args):
        out = execute(self, cursor, statement, *args)
        if statement.lstrip().startswith("SELECT") and not fired and in_suggest():
            fired.append(statement)
            tuning._on_terminate(signal.SIGTERM, sys._getframe())
        return out

    def in_suggest() -> bool:
        frame = sys._getframe()
        while frame is not None and frame.f_code.co_name != "suggest":
            frame = frame.f_back
        return frame is not None

    monkeypatch.setattr(sqlalchemy.engine.default.DefaultDialect, "do_execute",
                        execute_then_terminate)
    monkeypatch.setattr(tuning, "STOP", tuning.threading.Event())
    study = tuning.create_study("s", f"sqlite:///{tmp_path / 'optuna.db'}", 0, 1, tag="t")
    with pytest.raises(KeyboardInterrupt):
        study.optimize(tuning.objective(None, None, 2, 0, tuning.STOP), n_trials=3)
    assert fired
    (trial,) = study.trials
    assert trial.state.name == "FAIL" and "activation" in trial.params

    def cv_rmse():  # the interruptible place
        tuning._on_terminate(signal.SIGTERM, sys._getframe())

    with pytest.raises(KeyboardInterrupt):
        cv_rmse()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_terminated_tune_fails_its_running_trial_at_once(readings_csv, tmp_path, signum):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    proc = backlash("tune", str(readings_csv), "--trials", "200", "--folds", "2",
                    "--storage", storage, cwd=tmp_path)
    deadline = time.monotonic() + 120
    while states(storage)[-1:] != ["RUNNING"]:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-2000:]
        time.sleep(0.1)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)  # drain the pipes: a full one would block the writer
    assert proc.returncode == 130, err[-2000:]
    after = states(storage)
    assert after[-1] == "FAIL" and "RUNNING" not in after


def test_each_data_has_its_own_study_and_a_resumed_one_says_so(readings_csv, tmp_path):
    """The default study carries the data's digest: a second data set starts its own study
    (its trials are never ranked with the first's); the first data's study, asked again,
    is resumed and says with how many trials."""
    import pandas as pd

    import backlash as bl

    other = tmp_path / "other.csv"
    frame = pd.read_csv(readings_csv)
    frame["deviation_um"] += 1.0  # other data: another digest
    frame.to_csv(other, index=False)
    common = {"trials": 1, "folds": 2, "storage": f"sqlite:///{tmp_path / 'studies.db'}",
              "track": False}
    first, second = bl.tune(readings_csv, **common), bl.tune(other, **common)
    assert first.to_dict()["study"] != second.to_dict()["study"]
    assert first.trials == second.trials == {"complete": 1}
    assert not any("resumed" in n for n in first.notes + second.notes)
    again = bl.tune(readings_csv, **common)
    assert again.to_dict()["study"] == first.to_dict()["study"]
    assert again.trials == {"complete": 2}
    assert any("resumed with its 1 earlier trials" in n and "other data" not in n
               for n in again.notes)


def test_python_tune_logs_while_it_runs_into_the_tracking_folders_study(readings_csv, tmp_path,
                                                                         monkeypatch):
    """``bl.tune`` without a storage uses ``optuna.db`` in the tracking folder (the runner
    resolves the default the job's record declares); tracked, its run holds the search's and
    the best trial's parameters, with every trial nested under it, and ends FINISHED."""
    import backlash as bl

    folder = tmp_path / "tracking"
    folder.mkdir()
    monkeypatch.setenv("BACKLASH_TRACKING_DIR", str(folder))
    result = bl.tune(readings_csv, trials=2, folds=2)
    assert (folder / "optuna.db").is_file()
    assert result.parameters["storage"] == f"sqlite:///{folder / 'optuna.db'}"
    run = mlflow.get_run(result.tracking["run_id"])
    assert run.info.status == "FINISHED" and run.info.run_name == f"tune {result.parameters['study']}"
    assert run.data.params["tag"] == result.parameters["tag"]
    assert {f"best_{k}" for k in result.best_params} <= set(run.data.params)
    assert run.data.metrics["best_cv_rmse_um"] == pytest.approx(result.best_cv_rmse_um)
    trials = [r for r in nested_trial_runs()
              if r.data.tags.get("mlflow.parentRunId") == run.info.run_id]
    assert sorted(r.info.run_name for r in trials) == ["trial 0", "trial 1"]


def test_the_workflow_function_takes_the_storage_it_is_given(readings_csv):
    """The default storage is the runner's to resolve: the job's own function, called
    directly, opens no store it was not given."""
    from features.readings.errors import InputError
    from pipeline.workflows import workflow

    with pytest.raises(InputError) as raised:
        workflow("tune").function(readings_csv, trials=1, folds=2)
    assert raised.value.parameter == "storage"
