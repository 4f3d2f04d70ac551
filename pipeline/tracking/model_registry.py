"""What MLflow logs of a trained predictor, as plain data: its estimator parameters, per-epoch
history, model directory, signature, input example, the registered version's tags and the
forecasting skill from a backtest (``model_record``), logged and registered as
``backlash-predictor`` by ``pipeline.tracking.runs.log_result``; the best model on a data set holds
the registry alias ``champion`` (``pipeline.tracking.runs.promote_if_best``).

Version tags (``version_tags``): ``predictor``, ``target_kind``, ``data_sha256``,
``machines``, ``axes`` (``M1/X,M1/Y,...``, cut with a count), ``n_axes`` and
``backtest_skill`` (``1 - RMSE / RMSE of persistence`` over a rolling-origin backtest on the
training data, or ``n/a: REASON``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from pipeline.tracking.runs import (
    CHAMPION,
    CHAMPION_LOCK,
    MODEL_FIGURES,
    REGISTERED_NAME,
    REQUIREMENTS,
    promote_if_best,
)

FIGURES = MODEL_FIGURES
MIN_BACKTEST_VISITS = 3  # the backtest trains on visits <= k (at least 2) and forecasts k + 1
MAX_ORIGINS = 4  # the skill's backtest forecasts the last visits only: at most 4 extra fits
MAX_TAG = 250  # characters of a list tag (``axes``, ``machines``) before it is cut
__all__ = ["CHAMPION", "CHAMPION_LOCK", "FIGURES", "REGISTERED_NAME", "REQUIREMENTS",
           "compact_list", "forecast_skill", "model_record", "promote_if_best", "version_tags"]


def model_record(fit, model_dir: Path) -> dict:
    """What ``pipeline.tracking.runs.log_model`` logs of a fit saved in ``model_dir``, as plain JSON
    data: another process that has neither the fit nor its libraries may log it
    (``pipeline.tracking.background``).

    Parameters
    ----------
    fit : models.training.Fit
        The fitted predictor and its feature table.
    model_dir : Path
        Its saved model directory (``model.json`` gives the data hash and the target kind).

    Returns
    -------
    dict
        ``estimator_params``, ``history``, ``model_dir``, ``signature`` (``inputs``: name,
        type, required; ``outputs``: column names), ``example`` (the first rows of the inputs
        the signature lists, ``split`` orient), ``backtest`` (``forecast_skill``) and ``tags``.
    """
    from models.serving import input_columns, output_columns
    from pipeline.reports.model_report import training_history

    inputs = input_columns(fit.estimator, list(fit.table.X.columns))
    info = training_history(fit.estimator)
    backtest = forecast_skill(fit)
    meta = json.loads((Path(model_dir) / "model.json").read_text(encoding="utf-8"))
    return {
        "estimator_params": {f"est_{k}": str(v)[:250]
                             for k, v in _flat_params(fit.estimator).items()},
        "history": {name: [float(v) if _finite(v) else None for v in values]
                    for name, values in info["history"].items()} if info else {},
        "model_dir": str(model_dir),
        "signature": {"inputs": inputs, "outputs": output_columns(fit.estimator)},
        "example": _example(fit, inputs).to_dict(orient="split"),
        "backtest": backtest,
        "tags": version_tags(fit, meta, backtest),
    }


def _example(fit, inputs: list[dict], rows: int = 5):
    """The first ``rows`` training rows of the columns the signature lists (numbers as float),
    with their machine axis."""
    from models.registry import with_axes

    frame = fit.inputs if fit.inputs is not None else fit.table.X
    if any(c["name"] not in frame for c in inputs):
        frame = with_axes(fit.table.X, fit.table.meta)
    example = frame[[c["name"] for c in inputs]].iloc[:rows].reset_index(drop=True)
    return example.astype({c["name"]: float for c in inputs if c["type"] == "double"})


def forecast_skill(fit, min_visits: int = MIN_BACKTEST_VISITS,
                   max_origins: int = MAX_ORIGINS) -> dict:
    """Forecasting skill of a predictor that forecasts (``models.registry`` record
    ``forecasts``) from a rolling-origin backtest on its training table (``models.backtest``).

    Parameters
    ----------
    fit : models.training.Fit
        The fitted predictor; its table (for a wear map: the visits since each axis's last
        adjustment) is the backtest's data.
    min_visits : int
        Fewer visits give no skill (the backtest trains on >= 2 visits, forecasts the next).
    max_origins : int
        The backtest forecasts the last ``max_origins`` visits only, each from every visit
        before it: its cost is at most that many extra fits of the predictor.

    Returns
    -------
    dict
        ``skill`` = 1 - RMSE / RMSE of persistence over the origins' points (rounded to 4
        decimals), ``rmse_um``, ``persistence_rmse_um`` and ``origins``; or ``skill`` None and
        ``reason`` (the predictor does not forecast, too few visits, no origin).
    """
    import numpy as np

    from features.readings.errors import InputError
    from models import backtest, evaluation, registry

    if not registry.predictor(fit.name).forecasts:
        return {"skill": None, "reason": f"{fit.name} does not forecast a plan"}
    visits = len(set(evaluation.visit_order(fit.table.meta).tolist()))
    if visits < min_visits:
        return {"skill": None, "reason": f"{visits} visit(s) in the training data; the "
                                         f"backtest needs at least {min_visits}"}
    try:
        # the trained model's own choices (a wear map's control points): no CV per origin
        chosen = getattr(fit.estimator, "chosen_params", dict)()
        results = backtest.backtest(fit.table, [fit.name],
                                    min_train_visits=max(2, visits - max_origins),
                                    params={fit.name: chosen})
        summary = backtest.summary(results).set_index("model")
    except InputError as err:
        return {"skill": None, "reason": err.message}
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:  # a fold failed to fit
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        return {"skill": None, "reason": f"the backtest failed: {first[:200]}"}
    skill = float(summary.loc[fit.name, "skill_vs_persistence"])
    if not math.isfinite(skill):
        return {"skill": None, "reason": "persistence forecasts the training data exactly"}
    return {"skill": round(skill, 4), "rmse_um": float(summary.loc[fit.name, "rmse_um"]),
            "persistence_rmse_um": float(summary.loc[backtest.PERSISTENCE, "rmse_um"]),
            "origins": int(summary.loc[fit.name, "origins"])}


def version_tags(fit, meta: dict, backtest: dict) -> dict[str, str]:
    """The registered version's tags (module docstring), all text."""
    pairs = _machine_axes(fit.table.meta)
    skill = backtest["skill"]
    return {
        "predictor": fit.name,
        "target_kind": str(meta.get("target_kind", fit.table.target_kind)),
        "data_sha256": str(meta.get("data_sha256") or "unknown"),
        "machines": compact_list(sorted({m for m, _ in pairs}), "machines"),
        "axes": compact_list([f"{m}/{a}" for m, a in pairs], "axes"),
        "n_axes": str(len(pairs)),
        "backtest_skill": f"{skill:.4f}" if skill is not None else f"n/a: {backtest['reason']}",
    }


def _machine_axes(meta) -> list[tuple[str, str]]:
    """The (machine_id, axis) pairs of the training rows, sorted."""
    if not {"machine_id", "axis"} <= set(meta):
        return []
    pairs = meta[["machine_id", "axis"]].astype(str).drop_duplicates()
    return sorted(pairs.itertuples(index=False, name=None))


def compact_list(items: list[str], noun: str, limit: int = MAX_TAG) -> str:
    """``a,b,c``; when longer than ``limit`` characters, the first items that fit and
    ``... (N noun)``, e.g. ``M01/X,M01/Y,... (36 axes)``."""
    text = ",".join(items)
    if len(text) <= limit:
        return text
    tail = f",... ({len(items)} {noun})"
    shown = []
    for item in items:
        if len(",".join([*shown, item])) + len(tail) > limit:
            break
        shown.append(item)
    return ",".join(shown) + tail


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
