"""MLflow logging of trained predictors: parameters, per-epoch metrics, figures, the data hash,
and the model (signature, input example) registered as ``backlash-predictor``; the best model
on a data set holds the registry alias ``champion``."""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

REGISTERED_NAME = "backlash-predictor"
FIGURES = "figures"  # the folder of a model directory holding its figures
CHAMPION = "champion"
CHAMPION_LOCK = f"{REGISTERED_NAME}.champion-lock"
REQUIREMENTS = ["backlash-pipeline", "torch==2.13.0", "mlflow>=3.17,<3.18", "scikit-learn",
                "skops", "pandas", "numpy", "scipy"]


def log_fit(fit, model_dir: Path, figures: list[Path], params: dict) -> str:
    """Log one fitted model into the active run; returns the registered version."""
    log_record({"figures": [str(path) for path in figures]})
    return log_record(fit_record(fit, model_dir, params))["version"]


def fit_record(fit, model_dir: Path, params: dict) -> dict:
    """What ``log_record`` logs of a fit, as plain JSON data: another process that has neither
    the fit nor its libraries may log it (``pipeline.background_run``)."""
    from pipeline import tracking
    from pipeline.model_report import training_history

    example = fit.table.X.iloc[:5]
    info = training_history(fit.estimator)
    return {
        "params": {k: str(v)[:500] for k, v in params.items()},
        "estimator_params": {f"est_{k}": str(v)[:250]
                             for k, v in _flat_params(fit.estimator).items()},
        "metrics": tracking.metrics(fit.metrics),
        "history": {name: [float(v) if _finite(v) else None for v in values]
                    for name, values in info["history"].items()} if info else {},
        "model_dir": str(model_dir),
        "example": example.to_dict(orient="split"),
        "example_prediction": [float(v) for v in fit.estimator.predict(example)],
    }


def log_record(record: dict) -> dict:
    """Log into the active run what ``record`` holds: a ``fit_record`` (returns the registered
    ``version``) and/or ``figures``, a list of image paths."""
    from pipeline import tracking

    mlflow = tracking.mlflow_module()
    for path in record.get("figures", []):
        mlflow.log_artifact(path, artifact_path=FIGURES)
    if "model_dir" not in record:
        return {}
    mlflow.log_params(tracking.params(record["params"]))
    mlflow.log_params(tracking.params(record["estimator_params"]))
    mlflow.log_metrics(record["metrics"])  # finite, with valid names: see fit_record
    for name, values in record["history"].items():
        for epoch, value in enumerate(values):
            if value is not None:
                mlflow.log_metric(tracking.key(f"epoch_{name}"), value, step=epoch)
    with tempfile.TemporaryDirectory() as tmp:
        # A copy without figures/: the command may be drawing them there meanwhile, and they
        # are logged apart. The model's own files are complete before its record is sent.
        model_dir = shutil.copytree(record["model_dir"], Path(tmp) / "model_dir",
                                    ignore=shutil.ignore_patterns(FIGURES))
        mlflow.log_artifacts(str(model_dir), artifact_path="model_dir")
        version = _log_pyfunc(record, model_dir).registered_model_version
    return {"version": str(version)}


def _log_pyfunc(record: dict, model_dir: Path):
    """The model from code, registered, with signature and input example.

    MLflow would also check that the example serves by loading the model into this process;
    that imports the predictor's libraries into a logging process that needs none of them
    (seconds per training), and the test suite checks the served model instead."""
    import numpy as np
    import pandas as pd
    from mlflow.models import Model, infer_signature

    example = pd.DataFrame(**record["example"])
    return Model.log(
        artifact_path=None, name="model", flavor=_PyfuncFlavor, flavor_name="pyfunc.ModelFromCode",
        python_model=str(Path(__file__).parents[1] / "models" / "pyfunc_model.py"),
        artifacts={"model_dir": str(model_dir)},
        signature=infer_signature(example, np.asarray(record["example_prediction"])),
        input_example=example, registered_model_name=REGISTERED_NAME,
        pip_requirements=REQUIREMENTS,  # explicit: inferring them costs seconds per model
        validate_serving_input=False)


class _PyfuncFlavor:
    """``mlflow.pyfunc`` as a flavor of ``Model.log``: ``Model.log`` reads its
    ``validate_serving_input`` switch and passes it on, which ``pyfunc.save_model`` refuses."""

    @staticmethod
    def save_model(*, validate_serving_input: bool = True, **kwargs):
        import mlflow.pyfunc

        return mlflow.pyfunc.save_model(**kwargs)


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
