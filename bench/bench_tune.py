"""Optuna: 100 trials of the network search with 5-fold cross-validation on 432 points (the
paper plan's size), in trials per second; in-memory storage against local SQLite storage."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

TRIALS, FOLDS, POINTS = 100, 5, 432


def data(seed: int = 0):
    rng = np.random.default_rng(seed)
    X = pd.DataFrame(rng.normal(size=(POINTS, 8)), columns=[f"x{i}" for i in range(8)])
    y = 3 + np.tanh(X["x0"]) + 0.5 * X["x1"] ** 2 / 4 + rng.normal(0, 0.1, POINTS)
    return X, y


def main() -> None:
    import tempfile

    import optuna

    from models import tuning

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    X, y = data()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, storage, trials in (("in-memory", None, TRIALS),
                                       ("sqlite", f"sqlite:///{tmp}/optuna.db", TRIALS // 4)):
            study = optuna.create_study(storage=storage, sampler=optuna.samplers.TPESampler(seed=0))
            start = time.perf_counter()
            study.optimize(tuning.objective(X, y, FOLDS, 0, "bench"), n_trials=trials)
            results[label] = trials / (time.perf_counter() - start)
            print(f"{label:>9}: {trials} trials x {FOLDS}-fold CV on {POINTS} points: "
                  f"{results[label]:.2f} trials/s (best CV RMSE {study.best_value:.3f})")
    print(f"sqlite / in-memory throughput ratio {results['sqlite'] / results['in-memory']:.2f}")


if __name__ == "__main__":
    main()
