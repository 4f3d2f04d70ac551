"""Shared test set-up: quiet MLflow, headless plots, paths to the real data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MPLBACKEND", "Agg")

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


@pytest.fixture(autouse=True)
def _isolated_tracking(tmp_path, monkeypatch):
    """Every test tracks into its own SQLite store, never into the working tree."""
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.setenv("BACKLASH_ARTIFACTS", str(tmp_path / "mlartifacts"))


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
