"""Team set-up on real servers: an ``mlflow server`` on loopback with a PostgreSQL backend store
and an artifact folder, Optuna studies in the same PostgreSQL; ``train``, ``compare`` and
``tune --workers 4`` talk to it only through ``MLFLOW_TRACKING_URI`` and ``--storage``."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from test_targets import ideal_tests

from pipeline.cli import main
from pipeline.tracking.model_registry import CHAMPION, REGISTERED_NAME

pytestmark = pytest.mark.postgres


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def team_server(postgres_url, tmp_path_factory):
    """``mlflow server`` (PostgreSQL backend, artifacts in a folder) on a free loopback port;
    yields (tracking URL, Optuna storage URL, artifact folder)."""
    from pg_server import create_database

    backend = create_database(postgres_url, "mlflow")
    optuna_url = create_database(postgres_url, "studies")
    artifacts = tmp_path_factory.mktemp("team-artifacts")
    port = _free_port()
    log = open(artifacts.parent / "mlflow-server.log", "w")  # noqa: SIM115 - closed below
    server = subprocess.Popen(
        [str(Path(sys.executable).with_name("mlflow")), "server", "--host", "127.0.0.1",
         "--port", str(port), "--workers", "1", "--backend-store-uri", backend,
         "--artifacts-destination", str(artifacts)],
        stdout=log, stderr=subprocess.STDOUT,
        env={**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"})
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 240
    while True:
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2) as answer:
                if answer.status == 200:
                    break
        except OSError:
            pass
        if server.poll() is not None or time.monotonic() > deadline:
            server.kill()
            log.close()
            text = (artifacts.parent / "mlflow-server.log").read_text()[-2000:]
            pytest.fail(f"mlflow server did not start:\n{text}")
        time.sleep(0.25)
    yield url, optuna_url, artifacts
    server.terminate()
    try:
        server.wait(timeout=30)
    except subprocess.TimeoutExpired:
        server.kill()
    log.close()


def test_train_compare_and_tune_share_one_server(team_server, tmp_path, monkeypatch, capsys):
    import mlflow
    import optuna

    url, studies, artifacts = team_server
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", url)
    monkeypatch.delenv("BACKLASH_ARTIFACTS")  # artifacts go where the server keeps them
    data = tmp_path / "readings.csv"
    ideal_tests(direct=True).to_csv(data, index=False)

    assert main(["train", str(data), "--out", str(tmp_path / "m"), "--model", "ridge"]) == 0
    assert main(["compare", str(data), "--models", "constant,ridge",
                 "--out", str(tmp_path / "cmp")]) == 0
    assert main(["tune", str(data), "--trials", "4", "--folds", "2", "--workers", "4",
                 "--storage", studies, "--study", "team"]) == 0

    client = mlflow.MlflowClient(url, url)

    def runs(experiment: str) -> list:
        found = client.get_experiment_by_name(experiment)
        return client.search_runs([found.experiment_id])

    assert [r.data.params["model"] for r in runs("train")] == ["ridge"]
    compared = runs("compare")
    parents = [r for r in compared if "mlflow.parentRunId" not in r.data.tags]
    assert len(parents) == 1 and {r.info.run_name for r in compared} >= {"constant", "ridge"}
    tuned = runs("tune")
    trials = [r for r in tuned if r.info.run_name.startswith("trial ")]
    (parent,) = [r for r in tuned if not r.info.run_name.startswith("trial ")]
    assert len(trials) == 4 and all(r.data.tags["mlflow.parentRunId"] == parent.info.run_id
                                    and r.info.status == "FINISHED" for r in trials)
    assert len({r.data.tags["worker_pid"] for r in trials}) >= 2
    assert all(r.info.status == "FINISHED" for r in runs("train") + compared + tuned)

    study = optuna.load_study(study_name="team", storage=studies)
    assert [t.state.name for t in study.trials] == ["COMPLETE"] * 4
    assert sorted(r.data.tags["optuna_trial"] for r in trials) == ["0", "1", "2", "3"]

    versions = client.search_model_versions(f"name='{REGISTERED_NAME}'")
    assert len(versions) == 3  # train's ridge, compare's constant and ridge
    champion = client.get_model_version_by_alias(REGISTERED_NAME, CHAMPION)
    rmse = {v.version: client.get_run(v.run_id).data.metrics["test_rmse_um"] for v in versions}
    assert rmse[champion.version] == min(rmse.values())
    # the model files went to the server's artifact folder, not to the client's disk
    stored = {p.name for p in artifacts.rglob("*") if p.is_file()}
    assert {"MLmodel", "model.json", "comparison.csv"} <= stored
    assert not (tmp_path / "mlartifacts").exists()
    served = mlflow.pyfunc.load_model(f"models:/{REGISTERED_NAME}@{CHAMPION}")
    assert served.metadata.run_id == champion.run_id
