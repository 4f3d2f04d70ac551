"""`backlash run`: declarative experiment files, logged to MLflow."""

from __future__ import annotations

import pandas as pd

from pipeline.cli import main


def test_experiment_runs_steps_and_logs_one_mlflow_run(tmp_path, psi_file):
    spec = tmp_path / "exp.toml"
    spec.write_text(f"""
name = "tiny"
out = "{tmp_path / 'out'}"
[[steps]]
title = "convert"
command = "convert"
args = ["{psi_file}", "--out", "{{out}}/psi.parquet"]
""")
    assert main(["run", str(spec)]) == 0
    assert len(pd.read_parquet(tmp_path / "out" / "psi.parquet")) == 50

    import mlflow

    runs = mlflow.search_runs(experiment_names=["experiments"])
    assert list(runs["tags.mlflow.runName"]) == ["tiny"]
    assert runs["metrics.step_1_exit_code"].iloc[0] == 0
    artifacts = {a.path for a in mlflow.MlflowClient().list_artifacts(runs["run_id"].iloc[0])}
    assert {"exp.toml", "out"} <= artifacts


def test_failing_step_stops_the_experiment(tmp_path, capsys):
    spec = tmp_path / "exp.toml"
    spec.write_text(f"""
out = "{tmp_path / 'out'}"
[[steps]]
command = "convert"
args = ["{tmp_path / 'missing.csv'}", "--out", "{{out}}/x.csv"]
[[steps]]
command = "convert"
args = ["never-reached.csv", "--out", "{{out}}/y.csv"]
""")
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "missing.csv: cannot read file: no such file" in err and "never-reached" not in err


def test_unknown_step_command(tmp_path, capsys):
    spec = tmp_path / "exp.toml"
    spec.write_text('[[steps]]\ncommand = "bake"\n')
    assert main(["run", str(spec)]) == 2
    assert "step 1: unknown command 'bake'" in capsys.readouterr().err


def test_invalid_toml(tmp_path, capsys):
    spec = tmp_path / "exp.toml"
    spec.write_text("name = \n")
    assert main(["run", str(spec)]) == 2
    assert "invalid TOML" in capsys.readouterr().err


def test_experiment_without_steps(tmp_path, capsys):
    spec = tmp_path / "exp.toml"
    spec.write_text('name = "empty"\n')
    assert main(["run", str(spec)]) == 2
    assert "no [[steps]]" in capsys.readouterr().err
