"""Named predictors, and saving/loading a trained one without unpickling untrusted files.

Every entry is a scikit-learn style estimator working on the feature table
(``features.table``), so cross-validation, permutation importance and Optuna objectives
treat the network, the physics baselines and the comparators alike.

A trained model directory holds ``model.json`` (name, features, target definition,
validation error, training input ranges, data hash), ``training_inputs.csv`` (for input-drift
tests) and the fitted estimator: a torch state dict (loaded with ``weights_only=True``) for
estimators that save themselves, otherwise a skops file loaded with only the scikit-learn,
numpy, scipy and project types trusted.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import InputError
from models.persistence import load_estimator, save_estimator

# name: (one-line description, factory(random_state) -> unfitted estimator)
RECOMMENDED = "effect-model"
DESCRIPTIONS = {
    "hybrid": "effect-model physics fit plus a small network on its residual",
    "shallow-lm": "paper network 8-8-8-1 tanh, Levenberg-Marquardt like MATLAB trainlm",
    "shallow-adam": "paper network 8-8-8-1 tanh, Adam with early stopping",
    "effect-model": "least-squares fit of the twin's lost-motion effects (recommended)",
    "constant": "constant backlash (mean of the training targets)",
    "linear-temperature": "backlash linear in machine temperature",
    "bezier": "Bezier curve of degree 4 over position, 5 control points (least squares)",
    "bspline": "B-spline of degree 2 over position, 5 coefficients (least squares)",
    "knn": "k-nearest-neighbour regressor on standardised inputs (distance weighted)",
    "gbr": "gradient boosting regressor",
    "ridge": "ridge regression on standardised inputs (alpha by cross-validation)",
}


def names() -> list[str]:
    return list(DESCRIPTIONS)


def check_name(name: str) -> None:
    if name not in DESCRIPTIONS:
        raise InputError(f"unknown model {name!r}; expected one of {', '.join(names())}",
                         column="--model")


def make(name: str, random_state: int = 0, **params):
    """An unfitted estimator by registry name; ``params`` override its defaults."""
    check_name(name)
    estimator = _factories()[name](random_state)
    return estimator.set_params(**params) if params else estimator


def _network(**params):
    from models.network import ShallowNetwork

    return ShallowNetwork(**params)


def _factories() -> dict:
    from sklearn.ensemble import GradientBoostingRegressor
    from sklearn.linear_model import RidgeCV
    from sklearn.neighbors import KNeighborsRegressor
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from models import baselines
    from models.effect_model import EffectModelBaseline

    return {
        "hybrid": lambda seed: baselines.PhysicsHybrid(
            physics=EffectModelBaseline(),
            residual=_network(hidden_sizes=(8, 8), trainer="lm", random_state=seed)),
        "shallow-lm": lambda seed: _network(trainer="lm", random_state=seed),
        "shallow-adam": lambda seed: _network(trainer="adam", random_state=seed),
        "effect-model": lambda seed: EffectModelBaseline(),
        "constant": lambda seed: baselines.ConstantBacklash(),
        "linear-temperature": lambda seed: baselines.LinearInTemperature(),
        "bezier": lambda seed: baselines.BezierPosition(),
        "bspline": lambda seed: baselines.BSplinePosition(),
        "knn": lambda seed: make_pipeline(
            StandardScaler(), KNeighborsRegressor(n_neighbors=5, weights="distance")),
        "gbr": lambda seed: GradientBoostingRegressor(random_state=seed),
        "ridge": lambda seed: make_pipeline(StandardScaler(), RidgeCV(alphas=(0.01, 0.1, 1, 10))),
    }


@dataclass
class TrainedModel:
    """A fitted estimator with what monitoring needs to know about its training."""

    name: str
    estimator: object
    feature_names_: list[str]
    target_kind: str
    validation_rmse_: float
    input_ranges_: dict[str, tuple[float, float]]
    training_inputs_: object = None  # DataFrame of the training inputs
    meta: dict = field(default_factory=dict)

    def predict(self, X):
        return self.estimator.predict(X[self.feature_names_])


def save_model(model: TrainedModel, directory) -> Path:
    """Write a trained model directory (see module docstring)."""
    from features.readings.fileio import atomic_path, write_json

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    spec = save_estimator(model.estimator, directory, "estimator")
    if model.training_inputs_ is not None:
        with atomic_path(directory / "training_inputs.csv") as tmp:
            model.training_inputs_.to_csv(tmp, index=False)
    write_json(directory / "model.json", {
        "name": model.name, "estimator_format": spec["format"],
        "estimator_class": spec["class"],
        "features": model.feature_names_, "target_kind": model.target_kind,
        "validation_rmse_um": model.validation_rmse_,
        "input_ranges": {k: list(v) for k, v in model.input_ranges_.items()},
        **model.meta,
    })
    return directory


def load_model(directory) -> TrainedModel:
    """Read a model directory written by ``save_model``; refuse anything unexpected."""

    import pandas as pd

    directory = Path(directory)
    meta_path = directory / "model.json"
    if not meta_path.is_file():
        raise InputError("not a trained model directory: no model.json", file=directory)
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"model.json is not valid JSON: {err}", file=meta_path) from None
    fmt = meta.get("estimator_format")
    estimator = load_estimator(directory, {
        "format": fmt, "class": meta.get("estimator_class", ""),
        "path": "estimator" if fmt == "self" else "estimator.skops"}, where=meta_path)
    inputs_path = directory / "training_inputs.csv"
    training = pd.read_csv(inputs_path) if inputs_path.is_file() else None
    known = {"name", "estimator_format", "estimator_class", "features", "target_kind",
             "validation_rmse_um", "input_ranges"}
    return TrainedModel(
        meta["name"], estimator, list(meta["features"]), meta.get("target_kind", "auto"),
        float(meta.get("validation_rmse_um", float("nan"))),
        {k: tuple(v) for k, v in meta.get("input_ranges", {}).items()}, training,
        {k: v for k, v in meta.items() if k not in known})
