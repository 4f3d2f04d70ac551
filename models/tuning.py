"""Optuna search over the shallow network's architecture and training settings.

Each trial draws hidden sizes (1-3 layers of 2-16 neurons), activation, trainer (LM or Adam)
and L2 regularisation, and scores them by K-fold cross-validated RMSE [um] on the feature table.
Several worker processes, or machines, share one study through its storage URL: a local
SQLite file by default, PostgreSQL for many workers.
"""

from __future__ import annotations

import os

import numpy as np

DEFAULT_STORAGE = "sqlite:///optuna.db"
ACTIVATIONS = ("tanh", "relu", "sigmoid")
TRAINERS = ("lm", "adam")


def suggest(trial) -> dict:
    """Network parameters for one trial."""
    n_layers = trial.suggest_int("n_layers", 1, 3)
    hidden = tuple(trial.suggest_int(f"width_{i}", 2, 16) for i in range(n_layers))
    params = {"hidden_sizes": hidden,
              "activation": trial.suggest_categorical("activation", ACTIVATIONS),
              "trainer": trial.suggest_categorical("trainer", TRAINERS),
              "weight_decay": trial.suggest_float("weight_decay", 1e-7, 1e-1, log=True)}
    if params["trainer"] == "adam":
        params["learning_rate"] = trial.suggest_float("learning_rate", 1e-3, 1e-1, log=True)
    return params


def cv_rmse(X, y, params: dict, folds: int = 5, random_state: int = 0) -> np.ndarray:
    """RMSE [um] of each of ``folds`` shuffled folds for a network with ``params``."""
    from sklearn.model_selection import KFold, cross_val_score

    from models import registry

    estimator = registry.make("shallow-lm", random_state, **params)
    split = KFold(folds, shuffle=True, random_state=random_state)
    return -cross_val_score(estimator, X, y, cv=split, scoring="neg_root_mean_squared_error")


def objective(X, y, folds: int, random_state: int, tag: str):
    def run_trial(trial) -> float:
        params = suggest(trial)
        rmse = cv_rmse(X, y, params, folds, random_state)
        trial.set_user_attr("tag", tag)
        trial.set_user_attr("worker_pid", os.getpid())
        trial.set_user_attr("cv_rmse_std_um", float(rmse.std()))
        return float(rmse.mean())

    return run_trial


def create_study(name: str, storage: str, seed: int):
    import optuna

    sampler = optuna.samplers.TPESampler(seed=seed)
    return optuna.create_study(study_name=name, storage=storage, direction="minimize",
                               sampler=sampler, load_if_exists=True)


def work(name: str, storage: str, X, y, trials: int, folds: int, seed: int, tag: str,
         threads: int | None = None, progress: bool = False) -> None:
    """One worker: run ``trials`` trials of the shared study."""
    import optuna
    import torch

    if threads:
        torch.set_num_threads(threads)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = create_study(name, storage, seed + os.getpid())  # workers must not draw alike
    study.optimize(objective(X, y, folds, seed, tag), n_trials=trials,
                   show_progress_bar=progress)
