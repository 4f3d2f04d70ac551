"""What MLflow logs of a trained predictor, as plain data: its estimator parameters, per-epoch
history, model directory and an input example (``model_record``), logged and registered as
``backlash-predictor`` by ``pipeline.tracking.log_result``; the best model on a data set holds
the registry alias ``champion``."""

from __future__ import annotations

import math
from pathlib import Path

from pipeline.tracking import (
    CHAMPION,
    CHAMPION_LOCK,
    MODEL_FIGURES,
    REGISTERED_NAME,
    REQUIREMENTS,
    promote_if_best,
)

FIGURES = MODEL_FIGURES
__all__ = ["CHAMPION", "CHAMPION_LOCK", "FIGURES", "REGISTERED_NAME", "REQUIREMENTS",
           "model_record", "promote_if_best"]


def model_record(fit, model_dir: Path) -> dict:
    """What ``pipeline.tracking.log_model`` logs of a fit saved in ``model_dir``, as plain JSON
    data: another process that has neither the fit nor its libraries may log it
    (``pipeline.background_run``)."""
    from models.registry import knows_axes
    from pipeline.model_report import training_history

    # a model that knows several machine axes needs each row's machine_id and axis
    example = (fit.inputs if knows_axes(fit.estimator) else fit.table.X).iloc[:5]
    info = training_history(fit.estimator)
    return {
        "estimator_params": {f"est_{k}": str(v)[:250]
                             for k, v in _flat_params(fit.estimator).items()},
        "history": {name: [float(v) if _finite(v) else None for v in values]
                    for name, values in info["history"].items()} if info else {},
        "model_dir": str(model_dir),
        "example": example.to_dict(orient="split"),
        "example_prediction": [float(v) for v in fit.estimator.predict(example)],
    }


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
