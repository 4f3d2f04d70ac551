"""Shared test set-up: quiet MLflow, headless plots, paths to the real data."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MPLBACKEND", "Agg")
# Jobs track by default (pipeline.runner.TRACK): what a module-scoped fixture logs, before
# the per-test store below exists, goes to a store of the session, never into the checkout.
_SESSION = tempfile.mkdtemp(prefix="backlash-tests-tracking-")
os.environ.setdefault("MLFLOW_TRACKING_URI", f"sqlite:///{_SESSION}/mlflow.db")
os.environ.setdefault("BACKLASH_ARTIFACTS", f"{_SESSION}/artifacts")

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / "shared" / "data" / "real"
# The demo ships byte-identical copies of the real ecmc tests; use them in a lone checkout.
ECMC = REAL_DATA / "ecmc" if (REAL_DATA / "ecmc").is_dir() else REPO / "experiments/data/ecmc"


@pytest.fixture
def ess_file() -> Path:
    return ECMC / "ess_mcu1025_ISO230.dat"


@pytest.fixture
def psi_file() -> Path:
    return ECMC / "psi_sls_stepper_ISO230.dat"


@pytest.fixture(scope="session")
def mlflow_template(tmp_path_factory) -> Path:
    """An empty MLflow store with its schema created, built once per session: creating the
    schema takes seconds, copying the file milliseconds."""
    import subprocess
    import sys

    path = tmp_path_factory.mktemp("mlflow-template") / "mlflow.db"
    code = ("import sys, mlflow; c = mlflow.MlflowClient(sys.argv[1], sys.argv[1]); "
            "c.search_experiments(max_results=1); c.search_registered_models(max_results=1)")
    subprocess.run([sys.executable, "-c", code, f"sqlite:///{path}"], check=True,
                   capture_output=True, timeout=600)
    return path


@pytest.fixture(autouse=True)
def _isolated_tracking(tmp_path_factory, monkeypatch, mlflow_template):
    """Every test tracks into its own SQLite store (a copy of the empty template) in a folder
    of its own, never into the working tree or the test's ``tmp_path``."""
    import shutil

    store = tmp_path_factory.mktemp("tracking")
    shutil.copyfile(mlflow_template, store / "mlflow.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{store / 'mlflow.db'}")
    monkeypatch.setenv("BACKLASH_ARTIFACTS", str(store / "mlartifacts"))
    mlflow = sys.modules.get("mlflow")
    if mlflow is not None:  # an earlier test set the global URI; queries follow this store
        mlflow.set_tracking_uri(os.environ["MLFLOW_TRACKING_URI"])
        mlflow.set_registry_uri(os.environ["MLFLOW_TRACKING_URI"])


@pytest.fixture(scope="session")
def postgres_url():
    """URL of a real PostgreSQL server on loopback (installed and started here)."""
    from pg_server import Unavailable, start

    try:
        url, stop = start()
    except Unavailable as why:
        print(f"\nPostgreSQL tests skipped: {why}")
        pytest.skip(f"PostgreSQL unavailable: {why}")
    yield url
    stop()
