"""Optuna tuning: local storage, and several worker processes sharing one PostgreSQL study."""

from __future__ import annotations

import json

import mlflow
import optuna
import pytest
from test_targets import ideal_tests

from pipeline.cli import main


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
    study = optuna.load_study(study_name="backlash-network", storage="sqlite:///optuna.db")
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


def test_bad_storage_url_is_one_line(readings_csv, capsys):
    assert main(["tune", str(readings_csv), "--storage", "redis://x"]) == 2
    assert "unsupported storage URL" in capsys.readouterr().err
