"""Optuna: 20 trials of the network search with 5-fold cross-validation on 432 points (the
paper plan's size), in trials per second; in-memory storage against local SQLite storage."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from bench import TINY, size

TRIALS, FOLDS, POINTS = size(20, 1), size(5, 2), size(432, 60)
# A drawn network can take a minute to fit even on a few points: a tiny run fits this one in
# every trial, since it checks that the search runs, not how fast it goes.
TINY_TRIAL = {"n_layers": 1, "width_0": 2, "activation": "tanh", "trainer": "lm",
              "weight_decay": 1e-3}


def data(seed: int = 0):
    rng = np.random.default_rng(seed)
    X = pd.DataFrame(rng.normal(size=(POINTS, 8)), columns=[f"x{i}" for i in range(8)])
    y = 3 + np.tanh(X["x0"]) + 0.5 * X["x1"] ** 2 / 4 + rng.normal(0, 0.1, POINTS)
    return X, y


def main() -> None:
    import tempfile

    import optuna

    from models.estimators import tuning

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    X, y = data()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, storage, trials in (("in-memory", None, TRIALS),
                                       ("sqlite", f"sqlite:///{tmp}/optuna.db",
                                        max(TRIALS // 4, 1))):
            study = optuna.create_study(storage=storage, sampler=optuna.samplers.TPESampler(seed=0))
            for _ in range(trials if TINY else 0):
                study.enqueue_trial(TINY_TRIAL)
            start = time.perf_counter()
            study.optimize(tuning.objective(X, y, FOLDS, 0), n_trials=trials)
            results[label] = trials / (time.perf_counter() - start)
            print(f"{label:>9}: {trials} trials x {FOLDS}-fold CV on {POINTS} points: "
                  f"{results[label]:.2f} trials/s (best CV RMSE {study.best_value:.3f})")
    print(f"sqlite / in-memory throughput ratio {results['sqlite'] / results['in-memory']:.2f}")


if __name__ == "__main__":
    main()
