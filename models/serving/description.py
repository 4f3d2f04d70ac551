"""What is known of a trained predictor, as plain data (``describe``): its estimator parameters,
per-epoch history, serving signature, input example, forecasting skill and the tags a registry
version carries. A model job computes it with the fit and keeps it in its result, so what is
logged and registered, and which version becomes champion, never depends on whether the run
was tracked.

Tags (``version_tags``): ``predictor``, ``target_kind``, ``data_sha256``, ``machines``,
``axes`` (``M1/X,M1/Y,...``, cut with a count), ``n_axes`` and ``backtest_skill``
(``1 - RMSE / RMSE of persistence`` over a rolling-origin backtest on the training data,
``models.condition.backtest.forecast_skill``, or ``n/a: REASON``).
"""

from __future__ import annotations

import math

FIGURES = "figures"  # the folder of a model directory holding its figures
MAX_TAG = 250  # characters of a list tag (``axes``, ``machines``) before it is cut


def describe(fit, data_sha256: str | None, skill: dict) -> dict:
    """A fitted predictor as plain JSON data: another process that has neither the fit nor its
    libraries may log it.

    Parameters
    ----------
    fit : models.estimators.training.Fit
        The fitted predictor and its feature table.
    data_sha256 : str or None
        The training data's hash (``pipeline.results.data_hash``).
    skill : dict
        Its forecasting skill (``models.condition.backtest.forecast_skill``).

    Returns
    -------
    dict
        ``estimator_params``, ``history``, ``signature`` (``inputs``: name, type, required;
        ``outputs``: column names), ``example`` (the first rows of the inputs the signature
        lists, ``split`` orient), ``backtest`` (``skill``) and ``tags``.
    """
    from models.serving.signature import input_columns, output_columns

    inputs = input_columns(fit.estimator, list(fit.table.X.columns))
    info = training_history(fit.estimator)
    return {
        "estimator_params": {f"est_{k}": str(v)[:250]
                             for k, v in _flat_params(fit.estimator).items()},
        "history": {name: [float(v) if _finite(v) else None for v in values]
                    for name, values in info["history"].items()} if info else {},
        "signature": {"inputs": inputs, "outputs": output_columns(fit.estimator)},
        "example": _example(fit, inputs).to_dict(orient="split"),
        "backtest": skill,
        "tags": version_tags(fit, data_sha256, skill),
    }


def training_history(estimator) -> dict | None:
    """Per-epoch history of a network, also inside a hybrid (its residual network)."""
    for candidate in (estimator, getattr(estimator, "residual_", None)):
        history = getattr(candidate, "history_", None)
        if history:
            return {"history": history, "best_epoch": getattr(candidate, "best_epoch_", None),
                    "stop_reason": getattr(candidate, "stop_reason_", "")}
    return None


def _example(fit, inputs: list[dict], rows: int = 5):
    """The first ``rows`` training rows of the columns the signature lists (numbers as float),
    with their machine axis."""
    from models.serving.registry import with_axes

    frame = fit.inputs if fit.inputs is not None else fit.table.X
    if any(c["name"] not in frame for c in inputs):
        frame = with_axes(fit.table.X, fit.table.meta)
    example = frame[[c["name"] for c in inputs]].iloc[:rows].reset_index(drop=True)
    return example.astype({c["name"]: float for c in inputs if c["type"] == "double"})


def version_tags(fit, data_sha256: str | None, skill: dict) -> dict[str, str]:
    """The registered version's tags (module docstring), all text."""
    pairs = _machine_axes(fit.table.meta)
    value = skill["skill"]
    return {
        "predictor": fit.name,
        "target_kind": str(fit.table.target_kind),
        "data_sha256": str(data_sha256 or "unknown"),
        "machines": compact_list(sorted({m for m, _ in pairs}), "machines"),
        "axes": compact_list([f"{m}/{a}" for m, a in pairs], "axes"),
        "n_axes": str(len(pairs)),
        "backtest_skill": f"{value:.4f}" if value is not None else f"n/a: {skill['reason']}",
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
