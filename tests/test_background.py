"""The ``backlash`` program logs ``train`` from a forked child (``pipeline.tracking.background``):
the same run as in-process logging, no trace of a command that failed on its input, a run
marked FAILED when the command dies after it started, and a child's error in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import pandas as pd
import pytest

from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]
TWIN = REPO / "experiments" / "data" / "twin" / "readings.csv"


def program(*argv: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``backlash ARGV`` as its own process, like a user runs it."""
    env = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *argv], env=env,
                          capture_output=True, text=True, timeout=600, check=False)


def logged(run_id: str) -> dict:
    client = mlflow.MlflowClient()
    run = client.get_run(run_id)
    return {"params": set(run.data.params), "metrics": set(run.data.metrics),
            "figures": {a.path for a in client.list_artifacts(run_id, "figures")},
            "model_dir": {a.path for a in client.list_artifacts(run_id, "model_dir")},
            "status": run.info.status}


def run_id_of(stderr: str) -> str:
    line = next(line for line in stderr.splitlines() if "MLflow run" in line)
    return line.split("MLflow run ")[1].split(",")[0]


def test_program_logs_the_same_run_as_in_process_logging(tmp_path, capsys):
    done = program("train", str(TWIN), "--out", str(tmp_path / "forked"))
    assert done.returncode == 0, done.stderr
    assert "Downloading artifacts" not in done.stderr  # MLflow's per-file bars stay off
    forked = logged(run_id_of(done.stderr))
    assert main(["train", str(TWIN), "--out", str(tmp_path / "inline")]) == 0
    inline = logged(run_id_of(capsys.readouterr().err))
    assert forked == inline and forked["status"] == "FINISHED"
    assert forked["figures"] == {"figures/error_histogram.png", "figures/predictions.png",
                                 "figures/regression.png"}
    assert "model_dir/model.json" in forked["model_dir"]
    assert not any("figures" in path for path in forked["model_dir"])  # logged apart
    # the model logged by the child: registered, with signature and input example, serving
    # the same predictions as the saved model
    client = mlflow.MlflowClient()
    version = client.get_model_version("backlash-predictor", "1")
    assert version.run_id == run_id_of(done.stderr)
    served = mlflow.pyfunc.load_model("models:/backlash-predictor/1")
    assert served.metadata.signature is not None
    assert served.metadata.saved_input_example_info is not None
    inputs = pd.read_csv(tmp_path / "forked" / "training_inputs.csv").iloc[:4]
    from models.serving.registry import load_model

    assert list(served.predict(inputs)["backlash_um"]) == pytest.approx(
        [max(v, 0.0) for v in load_model(tmp_path / "forked").predict(inputs)])


def test_bad_input_leaves_no_store_behind(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("machine_id,axis\nM1,X\n")
    store = tmp_path / "fresh" / "mlflow.db"
    store.parent.mkdir()
    done = program("train", str(bad), "--out", str(tmp_path / "model"),
                   env={"MLFLOW_TRACKING_URI": f"sqlite:///{store}"})
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1 and "backlash train: error" in done.stderr
    assert not store.exists() and not (tmp_path / "model").exists()


SCRIPT = """
import json
import sys
from features.readings.errors import InputError
from pipeline.tracking import allow_fork, background

def log(record):
    if record.get("fail") == "input":
        raise InputError("the store refused it")
    if record.get("fail") == "bug":
        raise KeyError("oops")
    return {"seen": record["n"]}

allow_fork()
with background.BackgroundRun("child-test", log) as run:
    assert run._pid is not None, "expected a forked child"
    run.start("case " + sys.argv[1])
    run.log({"n": 1, "fail": sys.argv[1]})
    if sys.argv[1] == "die":
        raise SystemExit(7)
    print(json.dumps(run.finish()))
"""


def child(case: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT, case], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=300,
                          check=False)


def test_child_answers_with_the_merged_results_and_the_run_id():
    done = child("none")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["seen"] == 1 and logged(result["run_id"])["status"] == "FINISHED"


def test_child_errors_reach_the_command():
    done = child("input")
    assert done.returncode == 1 and "InputError: the store refused it" in done.stderr
    done = child("bug")
    assert done.returncode == 1 and "MLflow logging failed" in done.stderr
    assert "KeyError: 'oops'" in done.stderr  # the child's own traceback


def test_a_command_that_dies_after_start_leaves_a_failed_run():
    assert child("die").returncode == 7
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # the orphaned child ends the run on its own
        runs = mlflow.search_runs(experiment_names=["child-test"], output_format="list")
        if runs and runs[0].info.status != "RUNNING":
            break
        time.sleep(0.5)
    assert [r.info.status for r in runs] == ["FAILED"]
    assert json.dumps(runs[0].data.params) == "{}"
