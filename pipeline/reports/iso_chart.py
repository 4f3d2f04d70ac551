"""The ISO 230-2 chart metrologists expect: mean deviation up and down against target with
+-2s bands, the reversal value per target, and the axis figures in a box."""

from __future__ import annotations

import unicodedata

import pandas as pd

from features.readings import schema
from pipeline.reports.report_page import new_figure, save_figure

MAX_PANELS = 12
# The product's outlier rule (``features.iso230.outliers``), not one of ISO 230-2's.
OUTLIER_LABEL = "outlier (8-MAD rule)"
UP, DOWN = "#1f77b4", "#d62728"


def draw_test(ax, ax_reversal, targets: pd.DataFrame, figures: pd.Series,
              coverage: float | None = None) -> None:
    """One test: means with +-2s bands on ``ax``, B_i bars on ``ax_reversal``, figures box
    (``± U`` with the coverage factor ``coverage`` when the figures carry ``U_*_um``)."""
    t = targets.sort_values("target")
    unit = display_unit(figures["unit"])
    for side, colour, label in (("up", UP, "+ (up)"), ("down", DOWN, "- (down)")):
        mean, s = t[f"mean_{side}"], t[f"s_{side}"]
        ax.plot(t["target"], mean, "o-", color=colour, label=f"mean {label}")
        ax.fill_between(t["target"], mean - 2 * s, mean + 2 * s, color=colour, alpha=0.15,
                        label=f"±2s {label}")
    ax.plot(t["target"], t["mean_bi"], "k--", lw=1, label="bidirectional mean")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_ylabel(f"deviation [{unit}]")
    ax.set_title(f"{figures['machine_id']} {figures['axis']} visit {figures['visit']} — "
                 f"{figures['test_id']}", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    span = t["target"].max() - t["target"].min() or 1.0
    ax_reversal.bar(t["target"], t["B_i"], width=0.03 * span, color="grey")
    ax_reversal.axhline(0, color="black", lw=0.5)
    ax_reversal.set_ylabel(f"Bᵢ [{unit}]")
    ax_reversal.set_xlabel(f"target Pᵢ [{schema.position_unit(figures['axis'])}]")
    ax.figure.align_ylabels([ax, ax_reversal])  # wide B_i ticks would push its label off the page
    box = "\n".join(_box_line(figures, k) for k in SYMBOLS)
    title = f"ISO 230-2 [{unit}]" + ("" if "U_B_um" not in figures.index else " ± U"
                                     if coverage is None else f" ± U (k = {coverage:g})")
    if any(below_uncertainty(figures, key) for key in SYMBOLS):
        title += "\n* smaller than its U"
    ax.text(1.02, 1.0, f"{title}\n{box}", transform=ax.transAxes, va="top",
            family="monospace", fontsize=8,
            bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.9})


# ISO 230-2:2014 symbols of the axis figures, by their column: the arrows are the directions
# of approach (↑ positive, ↓ negative), B̄ the mean reversal value.
SYMBOLS = {"A": "A", "A_up": "A↑", "A_down": "A↓", "E": "E", "E_up": "E↑", "E_down": "E↓",
           "M": "M", "R": "R", "R_up": "R↑", "R_down": "R↓", "B": "B", "B_mean": "B̄"}


def display_unit(unit: str) -> str:
    """A deviation unit as pages print it: one spelling of the micrometre, µm."""
    return "µm" if unit == "um" else unit


def below_uncertainty(figures: pd.Series, key: str) -> bool:
    """Whether the figure's magnitude is smaller than its expanded uncertainty ``U_key_um``:
    the measurement cannot tell it from zero at the budget's coverage."""
    u = figures.get(f"U_{key}_um")
    return u is not None and pd.notna(u) and abs(figures[key]) < u


def _box_line(figures: pd.Series, key: str) -> str:
    """``A      12.345``, or ``A      12.345 ± 3.330`` when the figures carry ``U_A_um``
    (the expanded uncertainty of an ISO/TR 230-9 budget, k = 2 by default), marked ``*``
    when the figure is smaller than its U."""
    symbol = SYMBOLS[key]
    # a combining mark (the bar of B̄) takes no column of the monospace box
    line = symbol.ljust(3 + sum(unicodedata.combining(c) > 0 for c in symbol)) + \
        f"{figures[key]:9.3f}"
    u = figures.get(f"U_{key}_um")
    if u is not None and pd.notna(u):
        line += f" ± {u:.3f}" + (" *" if below_uncertainty(figures, key) else "")
    return line


def plot_tests(targets: pd.DataFrame, figures: pd.DataFrame, path) -> None:
    """Write one PNG with a panel per test (at most ``MAX_PANELS``)."""
    keys = list(schema.TEST_KEYS)
    n = len(figures)
    fig, axes = new_figure(10, 5 * n, nrows=2 * n, ncols=1, squeeze=False,
                           gridspec_kw={"height_ratios": [3, 1] * n})
    for i, (_, row) in enumerate(figures.iterrows()):
        mine = (targets[keys] == row[keys].to_numpy()).all(axis=1)
        ax, ax_reversal = axes[2 * i, 0], axes[2 * i + 1, 0]
        ax_reversal.sharex(ax)
        draw_test(ax, ax_reversal, targets.loc[mine], row)
    save_figure(fig, path)


def draw_readings(ax, readings: pd.DataFrame, outlier: pd.Series) -> None:
    """Every reading of one test on ``ax`` (dots, by direction) and the flagged outliers
    ringed and labelled, so that a kept outlier is seen as a reading, not only as a wider
    ±2s band.

    Parameters
    ----------
    readings : DataFrame
        The test's readings (``target`` [mm or deg], ``direction``, ``deviation_um``).
    outlier : Series of bool
        The flag of each reading (``features.iso230.outliers``, the product's rule: more than
        8 scale units from the median of its siblings), aligned with ``readings``.
    """
    for sign, colour in (("+", UP), ("-", DOWN)):
        mine = readings["direction"] == sign
        ax.plot(readings.loc[mine, "target"], readings.loc[mine, "deviation_um"], ".",
                color=colour, ms=3, alpha=0.6, label=f"readings {sign}")
    flagged = readings.loc[outlier.reindex(readings.index, fill_value=False)]
    if len(flagged):
        ax.plot(flagged["target"], flagged["deviation_um"], "o", mfc="none", mec="black",
                ms=9, mew=1.2, label=OUTLIER_LABEL)
        for r in flagged.itertuples():
            ax.annotate(f"{r.deviation_um:.1f}", (r.target, r.deviation_um), fontsize=6,
                        xytext=(5, 3), textcoords="offset points")
