"""MLflow under concurrency and hostile names: two processes opening a fresh store at once,
two processes promoting a champion at once, machine ids MLflow refuses as metric names, and
tracking URIs that cannot work."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mlflow.utils.validation import _validate_metric_name
from test_drift import visit_readings

from pipeline.cli import main
from pipeline.tracking import model_registry
from pipeline.tracking import runs as tracking

REPO = Path(__file__).resolve().parents[1]


def start_together(scripts: list[str], cwd: Path, env: dict) -> list[subprocess.CompletedProcess]:
    """Run Python ``scripts`` in parallel processes; each does its imports, says it is ready
    and waits for the common start signal, so their critical parts really overlap."""
    go = cwd / "go"
    procs = []
    for i, body in enumerate(scripts):
        before, after = textwrap.dedent(body).split("# --- start")
        code = (f"import pathlib, sys, time\n{before}\n"
                f"pathlib.Path({str(cwd / f'ready{i}')!r}).touch()\n"
                f"while not pathlib.Path({str(go)!r}).exists():\n    time.sleep(0.005)\n"
                f"{after}")
        procs.append(subprocess.Popen([sys.executable, "-c", code], cwd=cwd,
                                      env={**env, "PYTHONPATH": str(REPO)},
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    deadline = time.monotonic() + 180
    while not all((cwd / f"ready{i}").exists() for i in range(len(scripts))):
        assert time.monotonic() < deadline, "processes never got ready"
        assert all(p.poll() is None for p in procs), [p.communicate() for p in procs]
        time.sleep(0.01)
    go.touch()
    return [subprocess.CompletedProcess(p.args, p.wait(timeout=300), *p.communicate())
            for p in procs]


def test_two_processes_create_a_fresh_store_at_once(tmp_path):
    uri = f"sqlite:///{tmp_path / 'fresh' / 'mlflow.db'}"
    (tmp_path / "fresh").mkdir()
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri}
    body = """
        import mlflow
        from pipeline.tracking import runs as tracking
        # --- start
        with tracking.run("train", "concurrent"):
            mlflow.log_metric("x", 1.0)
        """
    done = start_together([body, body], tmp_path, env)
    assert [d.returncode for d in done] == [0, 0], [d.stderr[-1500:] for d in done]
    import mlflow

    client = mlflow.MlflowClient(uri)
    experiments = [e for e in client.search_experiments() if e.name == "train"]
    assert len(experiments) == 1
    runs = client.search_runs([experiments[0].experiment_id])
    assert len(runs) == 2 and all(r.data.metrics["x"] == 1.0 for r in runs)


@pytest.mark.postgres
def test_two_processes_create_a_fresh_postgres_store_at_once(postgres_url, tmp_path):
    from pg_server import create_database

    uri = create_database(postgres_url, "fresh_tracking")
    body = """
        import mlflow
        from pipeline.tracking import runs as tracking
        # --- start
        with tracking.run("train", "concurrent"):
            mlflow.log_metric("x", 1.0)
        """
    done = start_together([body, body], tmp_path, {**os.environ, "MLFLOW_TRACKING_URI": uri})
    assert [d.returncode for d in done] == [0, 0], [d.stderr[-1500:] for d in done]
    import mlflow

    runs = mlflow.MlflowClient(uri).search_runs(
        [mlflow.MlflowClient(uri).get_experiment_by_name("train").experiment_id])
    assert len(runs) == 2


def registered_version(client, rmse: float, digest: str) -> str:
    """A finished run with ``test_rmse_um`` and a model version pointing at it."""
    import mlflow

    with tracking.run("train", f"rmse {rmse}") as run:
        mlflow.log_params({"data_sha256": digest})
        mlflow.log_metric("test_rmse_um", rmse)
    try:
        client.create_registered_model(model_registry.REGISTERED_NAME)
    except mlflow.exceptions.MlflowException:
        pass  # exists
    return client.create_model_version(model_registry.REGISTERED_NAME,
                                       f"runs:/{run.info.run_id}/model",
                                       run.info.run_id).version


def test_two_processes_promote_at_once_and_the_better_model_wins(tmp_path):
    """The worse model reads "no champion", then is slow to write: without compare-and-set
    under a lock it would overwrite the better model that was promoted meanwhile."""
    client = tracking.client()
    worse = registered_version(client, 2.0, "d" * 64)
    better = registered_version(client, 1.0, "d" * 64)
    body = """
        from mlflow import MlflowClient
        from pipeline.tracking import model_registry
        read = MlflowClient.get_model_version_by_alias
        def slow_read(self, *args):
            try:
                return read(self, *args)
            finally:
                time.sleep({pause})  # a slow store between the read and the write
        MlflowClient.get_model_version_by_alias = slow_read
        # --- start
        time.sleep({delay})
        print(model_registry.promote_if_best("{version}", "{digest}", {rmse}))
        """
    scripts = [body.format(pause=1.5, delay=0.0, version=worse, digest="d" * 64, rmse=2.0),
               body.format(pause=0.0, delay=0.3, version=better, digest="d" * 64, rmse=1.0)]
    done = start_together(scripts, tmp_path, dict(os.environ))
    assert [d.returncode for d in done] == [0, 0], [d.stderr[-1500:] for d in done]
    champion = client.get_model_version_by_alias(model_registry.REGISTERED_NAME, "champion")
    assert champion.version == better
    assert done[1].stdout.strip() == "True"
    # the lock is released: no stray registered model is left
    names = {m.name for m in client.search_registered_models()}
    assert names == {model_registry.REGISTERED_NAME}


def test_lock_of_a_killed_holder_is_broken_after_its_lease():
    client = tracking.client()
    client.create_registered_model("stale.lock")  # as left by a holder killed inside
    start = time.monotonic()
    with tracking.exclusive("stale.lock", lease_s=0.5, wait_s=10):
        waited = time.monotonic() - start
    assert 0.5 <= waited < 8
    with pytest.raises(TimeoutError):
        client.create_registered_model("held.lock")
        with tracking.exclusive("held.lock", lease_s=60, wait_s=0.3):
            pass


HOSTILE = ["M/1", "M#1", "M<1>", "machine 7", "../etc", "a//b", "x" * 300, "Fräse 3", "M'1\""]


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_names_become_valid_distinct_mlflow_keys(name):
    key = tracking.key(f"backlash_um_{name}")
    _validate_metric_name(key)  # raises on a name MLflow refuses
    assert len(key) <= 250


def test_names_differing_only_in_refused_characters_stay_distinct():
    keys = {tracking.key(f"backlash_um_{n}") for n in ("M#1", "M<1", "M 1", "M/1", "M_1")}
    assert len(keys) == 5
    assert tracking.key("backlash_um_M1_X") == "backlash_um_M1_X"  # valid names are kept


def test_drift_with_hostile_machine_ids_logs_every_series(tmp_path, capsys):
    import mlflow
    import pandas as pd

    ids = ["press/7 #2", "<lathe> 3", "mill#4"]
    frame = pd.concat([visit_readings([2.0, 2.2, 2.4, 2.6], machine=m, seed=i)
                       for i, m in enumerate(ids)])
    path = tmp_path / "visits.csv"
    frame.to_csv(path, index=False)
    code = main(["drift", str(path), "--out", str(tmp_path / "out")])
    assert code in (0, 3), capsys.readouterr().err
    run = mlflow.search_runs(experiment_names=["drift"], output_format="list")[0]
    for machine in ids:
        assert run.data.metrics[tracking.key(f"backlash_um_{machine}_X")] == pytest.approx(
            2.6, abs=0.3)


@pytest.mark.parametrize("uri, words", [
    ("sqlite:///:memory:", "in-memory store keeps nothing"),
    ("sqlite:///{tmp}/missing/mlflow.db", "must be an existing folder"),
    ("redis://somewhere", "is not a tracking store"),
])
def test_bad_tracking_uri_is_one_line_before_any_output(tmp_path, monkeypatch, capsys, uri,
                                                        words):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri.format(tmp=tmp_path))
    path = tmp_path / "visits.csv"
    visit_readings([2.0, 2.2, 2.4]).to_csv(path, index=False)
    assert main(["drift", str(path), "--out", str(tmp_path / "out")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("backlash")]
    assert len(err) == 1 and words in err[0] and "MLFLOW_TRACKING_URI" in err[0], err
    assert not (tmp_path / "out").exists() and not (tmp_path / "missing").exists()
