"""Figures of a trained predictor, like the backlash paper's Figs 10-13: training curve, error
histogram, predictions against the reference, and regression plots per split."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models.serving.description import training_history
from pipeline.reports.report_page import new_figure, save_figure


def plot_training(info: dict, path: Path) -> Path:
    """Fig. 10: mean squared error per epoch on the training, validation and test splits."""
    fig, ax = new_figure(6.5, 4, nrows=1, ncols=1, fixed_margins=True)
    for key, label in (("train_mse", "training"), ("val_mse", "validation"), ("test_mse", "test")):
        values = info["history"].get(key)
        if values is not None and len(values):
            ax.semilogy(np.arange(len(values)), values, label=label)
    if info.get("best_epoch") is not None:
        ax.axvline(info["best_epoch"], color="grey", ls="--",
                   label=f"best epoch {info['best_epoch']} ({info['stop_reason']})")
    ax.set_xlabel("epoch")
    ax.set_ylabel("mean squared error (scaled target)")
    ax.legend()
    ax.set_title("Training performance")
    return save_figure(fig, path)


def plot_error_histogram(fit, path: Path, U_um: float | None = None) -> Path:
    """Fig. 11: histogram of prediction errors (predicted - target) on training and test;
    with ``U_um`` [um] the band ±U(B), what the measurement can resolve."""
    error = fit.predicted_um - fit.table.y.to_numpy(float)
    fig, ax = new_figure(6.5, 4, nrows=1, ncols=1, fixed_margins=True)
    bins = np.histogram_bin_edges(error, bins=20)
    ax.hist(error[fit.train_index], bins=bins, alpha=0.6, label="training")
    ax.hist(error[fit.test_index], bins=bins, alpha=0.6, label="test")
    ax.axvline(0, color="black", lw=0.8)
    if U_um is not None:
        ax.axvspan(-U_um, U_um, color="0.5", alpha=0.15, label=f"±U(B) = {U_um:.2f} um")
    ax.set_xlabel("error = predicted - target [um]")
    ax.set_ylabel("points")
    ax.legend()
    ax.set_title("Error histogram")
    return save_figure(fig, path)


def plot_predictions(fit, path: Path) -> Path:
    """Fig. 12: backlash per test point: target, prediction and (twin) true backlash."""
    idx = fit.test_index
    order = np.arange(len(idx))
    fig, ax = new_figure(8, 4, nrows=1, ncols=1, fixed_margins=True)
    ax.plot(order, fit.table.y.to_numpy(float)[idx], "o", ms=4, label="measured target")
    ax.plot(order, fit.predicted_um[idx], "x", ms=5, label=f"predicted ({fit.name})")
    if fit.truth_um is not None:
        ax.plot(order, fit.truth_um[idx], "-", color="black", lw=1, label="true backlash")
    ax.set_xlabel("test point")
    ax.set_ylabel("backlash [um]")
    ax.legend()
    ax.set_title("Predictions against the reference (test split)")
    return save_figure(fig, path)


def plot_regression(fit, path: Path) -> Path:
    """Fig. 13: predicted against target for training, test and all points, with R."""
    y = fit.table.y.to_numpy(float)
    parts = {"training": fit.train_index, "test": fit.test_index, "all": np.arange(len(y))}
    fig, axes = new_figure(12, 4, nrows=1, ncols=3, sharex=True, sharey=True,
                           fixed_margins=True)
    lo, hi = float(min(y.min(), fit.predicted_um.min())), float(max(y.max(), fit.predicted_um.max()))
    for ax, (label, idx) in zip(axes, parts.items()):
        t, p = y[idx], fit.predicted_um[idx]
        r = np.corrcoef(t, p)[0, 1] if len(idx) > 1 and np.std(p) > 0 else float("nan")
        ax.plot(t, p, "o", ms=3, alpha=0.6)
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="y = x")
        if len(idx) > 1:
            slope, intercept = np.polyfit(t, p, 1)
            ax.plot([lo, hi], [slope * lo + intercept, slope * hi + intercept], "r-", lw=1,
                    label=f"fit {slope:.2f} x + {intercept:.2f}")
        ax.set_title(f"{label}: R = {r:.3f}")
        ax.set_xlabel("target [um]")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("predicted [um]")
    return save_figure(fig, path)


def write_figures(fit, directory, U_um: float | None = None) -> list[Path]:
    """The figures of ``fit`` in ``directory``; ``U_um``: U(B) [um] drawn on the histogram."""
    directory = Path(directory)
    paths = [plot_error_histogram(fit, directory / "error_histogram.png", U_um),
             plot_predictions(fit, directory / "predictions.png"),
             plot_regression(fit, directory / "regression.png")]
    info = training_history(fit.estimator)
    if info:
        paths.insert(0, plot_training(info, directory / "training.png"))
    return paths
