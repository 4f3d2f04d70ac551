"""MLflow logging of trained predictors: parameters, per-epoch metrics, figures, the data hash,
and the model (signature, input example) registered as ``backlash-predictor``; the best model
on a data set holds the registry alias ``champion``."""

from __future__ import annotations

import math
from pathlib import Path

REGISTERED_NAME = "backlash-predictor"
CHAMPION = "champion"
CHAMPION_LOCK = f"{REGISTERED_NAME}.champion-lock"
REQUIREMENTS = ["backlash-pipeline", "torch==2.13.0", "mlflow>=3.17,<3.18", "scikit-learn",
                "skops", "pandas", "numpy", "scipy"]


def log_fit(fit, model_dir: Path, figures: list[Path], params: dict) -> str:
    """Log one fitted model into the active run; returns the registered version."""
    from pipeline import tracking
    from pipeline.model_report import training_history

    mlflow = tracking.mlflow_module()
    mlflow.log_params(tracking.params({k: str(v)[:500] for k, v in params.items()}))
    mlflow.log_params(tracking.params({f"est_{k}": str(v)[:250] for k, v in
                                       _flat_params(fit.estimator).items()}))
    mlflow.log_metrics(tracking.metrics(fit.metrics))
    info = training_history(fit.estimator)
    if info:
        for name, values in info["history"].items():
            for epoch, value in enumerate(values):
                if _finite(value):
                    mlflow.log_metric(tracking.key(f"epoch_{name}"), float(value), step=epoch)
    for path in figures:
        mlflow.log_artifact(str(path), artifact_path="figures")
    mlflow.log_artifacts(str(model_dir), artifact_path="model_dir")
    example = fit.table.X.iloc[:5]
    logged = _log_pyfunc(fit, model_dir, example)
    return str(logged.registered_model_version)


def _log_pyfunc(fit, model_dir: Path, example):
    from mlflow.models import infer_signature

    from pipeline import tracking

    mlflow = tracking.mlflow_module()
    return mlflow.pyfunc.log_model(
        name="model", python_model=str(Path(__file__).parents[1] / "models" / "pyfunc_model.py"),
        artifacts={"model_dir": str(model_dir)},
        signature=infer_signature(example, fit.estimator.predict(example)),
        input_example=example, registered_model_name=REGISTERED_NAME,
        pip_requirements=REQUIREMENTS)  # explicit: inferring them costs seconds per model


def promote_if_best(version: str, data_hash: str, rmse_um: float) -> bool:
    """Give ``version`` the champion alias when it beats the champion on the same data set
    (or there is none yet). A champion trained on other data is left alone.

    Compare-and-set under a registry-wide lock, so two trainings finishing at once cannot
    both read the old champion and both claim the alias.
    """
    from pipeline import tracking

    with tracking.exclusive(CHAMPION_LOCK):
        return _promote(tracking.client(), version, data_hash, rmse_um)


def _promote(client, version: str, data_hash: str, rmse_um: float) -> bool:
    from mlflow.exceptions import MlflowException

    try:
        current = client.get_model_version_by_alias(REGISTERED_NAME, CHAMPION)
    except MlflowException:
        current = None
    if current is not None:
        run = client.get_run(current.run_id)
        if run.data.params.get("data_sha256") != data_hash:
            return False
        if float(run.data.metrics.get("test_rmse_um", math.inf)) <= rmse_um:
            return False
    client.set_registered_model_alias(REGISTERED_NAME, CHAMPION, version)
    return True


def _flat_params(estimator) -> dict:
    try:
        params = estimator.get_params(deep=True)
    except Exception:  # noqa: BLE001 - estimators outside scikit-learn's API log nothing here
        return {}
    return {k: v for k, v in params.items() if isinstance(v, (int, float, str, bool, tuple))}


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False
