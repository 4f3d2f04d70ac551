"""Fit one named predictor on a feature table with a hold-out split and score it.

Scores on the held-out points (``test_*``), on the training points (``train_*``) and, when the
twin's truth is known, against the true backlash (``truth_*``) — the number that says whether a
model learned the physics or the noise of the measured target.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.table import FeatureTable, check_features
from models import evaluation, registry


@dataclass
class Fit:
    name: str
    estimator: object
    table: FeatureTable
    train_index: np.ndarray
    test_index: np.ndarray
    predicted_um: np.ndarray              # for every row of the table
    metrics: dict = field(default_factory=dict)
    truth_um: np.ndarray | None = None

    def trained_model(self, meta: dict | None = None) -> registry.TrainedModel:
        """The fitted estimator with what monitoring needs (input ranges, training inputs)."""
        X_train = self.table.X.iloc[self.train_index]
        ranges = {c: (float(X_train[c].min()), float(X_train[c].max())) for c in X_train}
        return registry.TrainedModel(
            self.name, self.estimator, list(self.table.X.columns), self.table.target_kind,
            self.metrics["test_rmse_um"], ranges, X_train.reset_index(drop=True),
            {"metrics": self.metrics, **(meta or {})})


def fit_model(table: FeatureTable, name: str, split: str = "random", random_state: int = 0,
              truth: pd.DataFrame | None = None, noise_floor_um: float | None = None,
              source: str = "data") -> Fit:
    """Fit ``name`` (``models.registry``) on the training part of ``split`` and score it."""
    check_features(table.X, source)
    train, test = evaluation.holdout(table.meta, split, random_state, source)
    estimator = registry.make(name, random_state)
    registry.check_inputs(name, estimator, table.X.columns, source)
    estimator.fit(table.X.iloc[train], table.y.iloc[train])
    predicted = np.asarray(estimator.predict(table.X), float)
    y = table.y.to_numpy(float)
    metrics = {f"test_{k}": v for k, v in evaluation.scores(y[test], predicted[test]).items()}
    metrics |= {f"train_{k}": v for k, v in evaluation.scores(y[train], predicted[train]).items()}
    fit = Fit(name, estimator, table, train, test, predicted, metrics)
    if truth is not None:
        fit.truth_um = evaluation.true_backlash(table.meta, truth, table.target_kind)
        known = test[np.isfinite(fit.truth_um[test])]
        if known.size:
            metrics |= {f"truth_{k}": v for k, v in
                        evaluation.scores(fit.truth_um[known], predicted[known]).items()}
            # what the measured target itself misses the truth by: the noise floor in practice
            metrics["target_truth_rmse_um"] = float(np.sqrt(np.mean(
                (y[known] - fit.truth_um[known]) ** 2)))
    if noise_floor_um is not None:
        metrics["noise_floor_um"] = float(noise_floor_um)
    return fit
