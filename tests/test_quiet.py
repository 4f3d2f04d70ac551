"""Quiet by default: no MLflow, Optuna or alembic log line reaches the terminal from a command
or a ``bl.*`` call in a fresh folder (a fresh MLflow database) unless the user asks
(``--verbose``); where the stores go follows one rule (``--tracking-dir`` or
``BACKLASH_TRACKING_DIR``), said once. Each run is a subprocess with its own fresh folder."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parents[1]
READINGS = ROOT / "experiments" / "data" / "twin" / "readings.csv"
# what the libraries print when they are not silenced: MLflow's log format (with alembic's
# lines, which MLflow routes the same way), Optuna's, alembic's own, MLflow's messages
LIBRARY_LINE = re.compile(r"^\d{4}/\d\d/\d\d \d\d:\d\d:\d\d [A-Z]+ |^\[[DIWE] \d{4}-\d\d-\d\d"
                          r"|^(DEBUG|INFO|WARNING|ERROR) +\[|\bINFO\b|Created version '"
                          r"|Successfully registered model|A new study created|View run")


def fresh_env(**extra) -> dict:
    """This environment without any tracking location (the conftest's per-test store), so
    the command creates a fresh MLflow database where the rule says."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("MLFLOW_TRACKING_URI", "BACKLASH_ARTIFACTS", "BACKLASH_TRACKING_DIR",
                        "BACKLASH_VERBOSE", "MLFLOW_LOGGING_LEVEL")}
    return {**env, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", **extra}


def backlash(args: list[str], cwd: Path, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], cwd=cwd,
                          env=fresh_env(**env), capture_output=True, text=True, timeout=300,
                          check=False)


def library_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if LIBRARY_LINE.search(line)]


def test_train_in_a_fresh_folder_prints_no_library_line(tmp_path):
    done = backlash(["train", str(READINGS), "--model", "ridge", "--out", "model"], tmp_path)
    assert done.returncode == 0, done.stderr
    assert library_lines(done.stderr) == [] and library_lines(done.stdout) == []
    assert (tmp_path / "mlflow.db").is_file() and (tmp_path / "mlartifacts").is_dir()
    # where the store went is said once: when it was created, not on the next run
    said = [line for line in done.stderr.splitlines() if line.startswith("note: tracking")]
    assert len(said) == 1 and str(tmp_path / "mlflow.db") in said[0]
    assert "--tracking-dir" in said[0] and "BACKLASH_TRACKING_DIR" in said[0]
    # an experiment file (what make demo runs) in the same folder: the store exists now; its
    # train step registers a model in-process, where MLflow's own lazy imports once switched
    # its messages back on
    (tmp_path / "exp.toml").write_text(
        f'name = "quiet"\n\n[[steps]]\ntitle = "train"\njob = "train"\n[steps.with]\n'
        f'data = "{READINGS}"\nmodel = "ridge"\nout = "{{out}}/ridge"\n', encoding="utf-8")
    again = backlash(["run", "exp.toml"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert "note: tracking" not in again.stderr and "[1] train" in again.stderr
    assert library_lines(again.stderr) == [] and library_lines(again.stdout) == []


def test_verbose_lets_the_library_lines_through(tmp_path):
    folder = tmp_path / "runs"
    folder.mkdir()
    done = backlash(["train", str(READINGS), "--model", "ridge", "--out", "model",
                     "--verbose", "--tracking-dir", str(folder)], tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Creating initial MLflow database tables" in done.stderr
    assert "Created version '1' of model 'backlash-predictor'" in done.stderr
    # --tracking-dir put the database and the artifacts there, none in the working folder
    assert (folder / "mlflow.db").is_file() and (folder / "mlartifacts").is_dir()
    assert not (tmp_path / "mlflow.db").exists()


def test_a_tracking_dir_that_does_not_exist_is_one_line(tmp_path):
    done = backlash(["train", str(READINGS), "--model", "ridge", "--out", "model",
                     "--tracking-dir", "missing"], tmp_path)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [(
        f"backlash train: error: tracking folder {tmp_path / 'missing'} "
        "(BACKLASH_TRACKING_DIR, --tracking-dir) must be an existing folder")]
    assert not (tmp_path / "model").exists()


def test_bl_tune_is_quiet_and_keeps_its_studies_in_the_tracking_folder(tmp_path):
    folder = tmp_path / "runs"
    folder.mkdir()
    code = (f"import backlash as bl; r = bl.tune({str(READINGS)!r}, trials=2, folds=2, "
            "track=True); print(r.best_trial)")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, check=False,
                          env=fresh_env(BACKLASH_TRACKING_DIR=str(folder)))
    assert done.returncode == 0, done.stderr
    lines = library_lines(done.stderr) + library_lines(done.stdout)
    assert lines == [], lines
    assert {p.name for p in folder.iterdir()} >= {"mlflow.db", "optuna.db"}
    assert not (tmp_path / "optuna.db").exists() and not (tmp_path / "mlflow.db").exists()
