"""Feature ranking: time per association view against the number of backlash points, how
often the known drivers come out on top when their effect is weak, and the time and verdicts
of the conditional influence on twin campaigns of growing size."""

from __future__ import annotations

import itertools
import time
import warnings

import numpy as np
import pandas as pd

from bench import size
from features import ranking
from models import influence

POINTS = size((200, 1000, 4000), (40, 80))  # backlash points of the timed association views
SEEDS = size(10, 1)  # data sets of the drivers' hit rate and of each twin campaign
BOOT = size(50, 5)  # bootstrap resamples of a ranking and of the conditional influence
# the timed views run at their own defaults; a tiny run shuffles and resamples the least
SHUFFLES = size({}, {"n_repeats": 1})
RESAMPLES = size({}, {"n_boot": 5})
# the fleet campaigns: the preset's, or in a tiny run one axis of one machine at three visits
FLEET = size({}, {"fleet": {"machines": 1, "axes": ["X"], "visits": 3, "adjust_at": []}})
FLEET_LABEL = size("12 axes x 8 visits", "1 axis x 3 visits")

INPUTS = ("target", "deviation_down_um", "deviation_up_um", "feed_mm_min", "machine_temp_c",
          "ambient_temp_c", "pressure_hpa", "humidity_pct")


def synthetic(n: int, seed: int, effect_um: float = 1.0, bump: bool = False):
    """Eight paper inputs; backlash driven by position and feed only, noise 0.3 um.

    ``bump``: the position effect is wear peaking mid-travel (not monotone) instead of a
    slope."""
    rng = np.random.default_rng(seed)
    X = pd.DataFrame({
        "target": rng.choice(np.linspace(25.0, 325.0, 7), n),
        "deviation_down_um": rng.normal(0.0, 2.0, n),
        "deviation_up_um": rng.normal(0.0, 2.0, n),
        "feed_mm_min": rng.choice([200.0, 500.0, 1200.0], n),
        "machine_temp_c": rng.normal(22.0, 1.0, n),
        "ambient_temp_c": rng.normal(21.0, 1.0, n),
        "pressure_hpa": rng.normal(1013.0, 5.0, n),
        "humidity_pct": rng.normal(45.0, 8.0, n),
    })
    position = (np.exp(-((X["target"] - 175.0) / 60.0) ** 2) if bump
                else X["target"] / 300.0)
    y = 2.0 + effect_um * (position + X["feed_mm_min"] / 1000.0) + rng.normal(0.0, 0.3, n)
    return X, y


def _timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def main() -> None:
    print(f"{'points':>7} {'k-NN':>7} {'ANOVA':>7} {'perm':>7} {'MI':>7} {'total':>7}  [s]")
    totals = {}
    ranking.rank_features(*synthetic(60, seed=0), n_boot=5)  # imports and first calls
    for n in POINTS:
        X, y = synthetic(n, seed=0)
        classes, edges = ranking.backlash_classes(y)
        _, t_knn = _timed(ranking.knn_scores, X, classes, edges)
        _, t_anova = _timed(ranking.anova_scores, X, classes)
        _, t_perm = _timed(ranking.permutation_scores, X, y, **SHUFFLES)
        _, t_mi = _timed(ranking.mutual_info_scores, X, y)
        _, t_all = _timed(ranking.rank_features, X, y, **SHUFFLES, **RESAMPLES)
        totals[n] = t_all
        print(f"{n:>7} {t_knn:>7.2f} {t_anova:>7.2f} {t_perm:>7.2f} {t_mi:>7.2f} {t_all:>7.2f}")
    print("time ratio " + ", ".join(f"{n}/{m} points: {totals[n] / totals[m]:.1f}"
                                    for m, n in itertools.pairwise(POINTS)))

    cases = {"weak slopes (0.4 um)": {"effect_um": 0.4},
             "mid-travel wear bump (1 um)": {"effect_um": 1.0, "bump": True}}
    print(f"drivers (position, feed) ranked 1 and 2, {POINTS[0]} points, noise 0.3 um, "
          f"{SEEDS} seeds:")
    for case, params in cases.items():
        hits = dict.fromkeys(ranking.RANK_BY, 0)
        for seed in range(SEEDS):
            X, y = synthetic(POINTS[0], seed=seed, **params)
            table = ranking.rank_features(X, y, n_boot=BOOT, n_repeats=size(3, 1),
                                          random_state=seed).table
            for rule in ranking.RANK_BY:
                top = ranking.final_rank(table, rule).nsmallest(2).index
                hits[rule] += set(top) == {"target", "feed_mm_min"}
        print(f"  {case:<28} " + ", ".join(f"{rule}: {n}/{SEEDS}" for rule, n in hits.items()))

    print(f"conditional influence (verdicts), twin campaigns, {SEEDS} seeds, {BOOT} bootstrap "
          "resamples:")
    print(f"  {'campaign':<34} {'points':>7} {'time [s]':>9}  drivers found / no-path drivers")
    campaigns = {"paper (1 visit)": ("paper", {}),
                 "demo (6 visits)": ("demo", {}),
                 f"fleet ({FLEET_LABEL})": ("fleet", FLEET),
                 "fleet, one repeat, one dwell": ("fleet", {**FLEET, "plan": {
                     "repeats": 1, "dwells_s": [5.0]}})}
    for label, (preset, overrides) in campaigns.items():
        found, wrong, seconds, n = 0, 0, 0.0, 0
        for seed in range(SEEDS):
            table = _twin(preset, overrides, seed)
            result, dt = _timed(influence.conditional_influence, table.X, table.y, table.meta,
                                n_boot=BOOT, random_state=seed)
            seconds, n = seconds + dt, len(table.X)
            verdict = result.table["verdict"]
            paths = [c for c in verdict.index if result.table.loc[c, "physical_path"]]
            found += sum(verdict[c] == "driver" for c in paths)
            wrong += sum(verdict[c] == "driver" for c in verdict.index if c not in paths)
        print(f"  {label:<34} {n:>7} {seconds / SEEDS:>9.2f}  {found} / {wrong}")


def _twin(preset: str, overrides: dict, seed: int):
    from features.readings.errors import BacklashWarning
    from features.table import feature_table
    from models.physics.campaign import load_config, simulate

    readings = simulate(load_config(overrides, preset=preset), seed=seed).readings
    with warnings.catch_warnings():
        # a one-visit campaign has a single operating-hours value and a one-dwell campaign a
        # single dwell time: the table notes each, as it should
        warnings.filterwarnings("ignore", "(operating_hours|dwell_s) constant over all points",
                                BacklashWarning)
        return feature_table(readings)
