"""MLflow glue: one place that knows the default store and where artifacts go.

Defaults: ``sqlite:///mlflow.db`` in the working directory with artifacts in ``./mlartifacts``
beside it. ``MLFLOW_TRACKING_URI`` and ``BACKLASH_ARTIFACTS`` override them. mlflow is
imported inside the functions so that the CLI starts fast.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path

DEFAULT_URI = "sqlite:///mlflow.db"
DEFAULT_ARTIFACTS = "mlartifacts"


def tracking_uri() -> str:
    return os.environ.get("MLFLOW_TRACKING_URI", DEFAULT_URI)


def artifact_root() -> Path:
    return Path(os.environ.get("BACKLASH_ARTIFACTS", DEFAULT_ARTIFACTS)).absolute()


def experiment_id(name: str) -> str:
    """Id of the named experiment, created with the project's artifact folder if new."""
    import mlflow

    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    mlflow.set_tracking_uri(tracking_uri())
    found = mlflow.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    location = (artifact_root() / name).as_uri()
    return mlflow.create_experiment(name, artifact_location=location)


@contextlib.contextmanager
def run(experiment: str, run_name: str, *, nested: bool = False, tags: dict | None = None):
    """Start an MLflow run in ``experiment``; nests under an active run when asked."""
    import mlflow

    exp_id = experiment_id(experiment)
    active = mlflow.active_run()
    nest = nested or active is not None
    with mlflow.start_run(experiment_id=exp_id, run_name=run_name, nested=nest,
                          tags=tags) as current:
        yield current


def data_hash(frame) -> str:
    """Content hash of a data frame (sha256 of its canonical CSV bytes), logged with runs."""
    payload = frame.to_csv(index=False).encode()
    return hashlib.sha256(payload).hexdigest()
