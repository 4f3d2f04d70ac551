"""ISO 230-2 statistics of positioning tests, vectorised over many tests at once.

Definitions (ISO 230-2:2014, clause 2; [Mechta2022], eqs. 1-9). For a test, target P_i, cycle j
and approach direction (up = ``+``, down = ``-``), the deviation is x_ij = measured - target.

Per target, per direction (n readings):

- mean unidirectional deviation   x̄_i = (1/n) Σ_j x_ij
- estimator of the standard uncertainty (repeatability)   s_i = sqrt(Σ_j (x_ij - x̄_i)² / (n-1))
- unidirectional repeatability    R_i↑ = 4 s_i↑,  R_i↓ = 4 s_i↓
- reversal value                  B_i = x̄_i↑ - x̄_i↓   (lost motion makes it negative)
- mean bidirectional deviation    x̄_i = (x̄_i↑ + x̄_i↓) / 2
- bidirectional repeatability     R_i = max(2 s_i↑ + 2 s_i↓ + |B_i|, R_i↑, R_i↓)

Per axis (one test):

- B = max_i |B_i|,  B_mean = mean_i B_i (signed)
- R↑ = max R_i↑, R↓ = max R_i↓, R = max R_i
- E↑ = max x̄↑ - min x̄↑ (E↓ alike);  E = max(x̄↑, x̄↓) - min(x̄↑, x̄↓)
- M = max x̄_i - min x̄_i (bidirectional means)
- A↑ = max(x̄↑ + 2s↑) - min(x̄↑ - 2s↑) (A↓ alike);  A = max over both directions of
  (x̄ + 2s) minus min over both directions of (x̄ - 2s)

Figures are in um for linear axes and arcsec for rotary axes (the unit of ``deviation_um``).
Tests are grouped by ``features.readings.schema.TEST_KEYS``; every step is one pandas/numpy operation
over all tests, so 10,000 tests cost about as much as one table of their size.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from scipy.special import gammaincinv  # scipy.special, not scipy.stats: seconds less to import

from features.readings import schema
from features.readings.errors import InputError
from features.readings.validation import check_readings
from features.standards import ISO230_2

PER_TARGET_FIGURES = ("n_up", "n_down", "mean_up", "mean_down", "mean_bi", "s_up", "s_down",
                      "B_i", "R_up_i", "R_down_i", "R_i")
AXIS_FIGURES = ISO230_2.figures
# Carried from the readings to both result tables: first value per test.
TEST_COLUMNS = ("method", "repeat", "feed_mm_min", "dwell_s", "started_at", "operating_hours")
# Environment: mean over the readings at a target (per target) or over the test (per axis).
ENVIRONMENT = ("machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct")
# A reading is an outlier when it lies this many scale units from the median of its siblings.
OUTLIER_THRESHOLD = 8.0
# The readings columns the figures use (checked on entry: a hand-made frame must have them).
USED = (*schema.TEST_KEYS, "target", "direction", "deviation_um")


def _test_index(readings: pd.DataFrame) -> np.ndarray:
    return readings.groupby(list(schema.TEST_KEYS), sort=False, observed=True).ngroup().to_numpy()


def _test_table(readings: pd.DataFrame, test: np.ndarray) -> pd.DataFrame:
    """One row per test: keys, unit and carried columns, indexed by test number."""
    carried = [c for c in (*schema.TEST_KEYS, *TEST_COLUMNS) if c in readings.columns]
    tests = readings[carried].groupby(test, sort=True).first()
    tests.insert(4, "unit", tests["axis"].map(schema.deviation_unit))
    return tests


def per_target(readings: pd.DataFrame) -> pd.DataFrame:
    """Per-target ISO 230-2 figures of every test: one row per test and target.

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``features.readings.read_readings``); deviations in um (arcsec
        for rotary axes).

    Returns
    -------
    DataFrame
        ``TEST_KEYS``, ``unit``, carried test columns, ``target`` and ``PER_TARGET_FIGURES``
        [um or arcsec], plus environment means when present.

    Raises
    ------
    InputError
        ``readings`` is not a validated readings frame (``.parameter`` is ``"readings"``).
    """
    return _per_target(check_readings(readings, columns=USED))


def _per_target(readings: pd.DataFrame) -> pd.DataFrame:
    test = _test_index(readings)
    up = (readings["direction"] == "+").to_numpy()
    x = readings["deviation_um"].to_numpy(float)
    keys = [test, readings["target"].to_numpy(float)]
    stats = {}
    for name, mask in (("up", up), ("down", ~up)):
        grouped = pd.Series(x[mask]).groupby([k[mask] for k in keys])
        stats[name] = grouped.agg(["count", "mean", "std"])
    up_stats, down_stats = stats["up"].align(stats["down"], join="outer")
    table = pd.DataFrame({
        "n_up": up_stats["count"].fillna(0).astype(int), "n_down": down_stats["count"].fillna(0).astype(int),
        "mean_up": up_stats["mean"], "mean_down": down_stats["mean"],
        "s_up": up_stats["std"], "s_down": down_stats["std"],
    })
    table.index.names = ["_test", "target"]
    table["mean_bi"] = (table["mean_up"] + table["mean_down"]) / 2
    table["B_i"] = table["mean_up"] - table["mean_down"]
    table["R_up_i"] = 4 * table["s_up"]
    table["R_down_i"] = 4 * table["s_down"]
    table["R_i"] = np.fmax(2 * table["s_up"] + 2 * table["s_down"] + table["B_i"].abs(),
                           np.fmax(table["R_up_i"], table["R_down_i"]))
    env = [c for c in ENVIRONMENT if c in readings.columns]
    if env:
        table = table.join(readings[env].groupby(keys).mean().rename_axis(["_test", "target"]))
    table = table.reset_index()
    tests = _test_table(readings, test)
    table = tests.loc[table["_test"]].reset_index(drop=True).join(table.drop(columns="_test"))
    return table[[*tests.columns, "target", *PER_TARGET_FIGURES, *env]]


def axis_figures(readings: pd.DataFrame, targets: pd.DataFrame | None = None) -> pd.DataFrame:
    """Axis figures A, A_up, A_down, E, E_up, E_down, M, R, R_up, R_down, B, B_mean per test.

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``features.readings.read_readings``).
    targets : DataFrame, optional
        ``per_target(readings)`` when already computed (saves computing it again).

    Returns
    -------
    DataFrame
        One row per test: ``TEST_KEYS``, ``unit``, carried test columns, environment means
        and ``AXIS_FIGURES`` [um or arcsec].

    Raises
    ------
    InputError
        ``readings`` is not a validated readings frame, or ``targets`` lacks per-target
        figures (``.parameter`` names which).
    """
    readings = check_readings(readings, columns=USED)
    if targets is None:
        targets = _per_target(readings)
    elif not isinstance(targets, pd.DataFrame) or not {
            *schema.TEST_KEYS, *PER_TARGET_FIGURES} <= set(targets.columns):
        raise InputError("expected the per-target figures of the readings (per_target)",
                         parameter="targets")
    group = targets.groupby(list(schema.TEST_KEYS), sort=False)
    t = targets.assign(
        hi_up=targets["mean_up"] + 2 * targets["s_up"], lo_up=targets["mean_up"] - 2 * targets["s_up"],
        hi_down=targets["mean_down"] + 2 * targets["s_down"],
        lo_down=targets["mean_down"] - 2 * targets["s_down"], abs_B=targets["B_i"].abs())
    g = t.groupby(list(schema.TEST_KEYS), sort=False)
    mx = g[["hi_up", "hi_down", "mean_up", "mean_down", "mean_bi", "R_i", "R_up_i", "R_down_i",
            "abs_B"]].max()
    mn = g[["lo_up", "lo_down", "mean_up", "mean_down", "mean_bi"]].min()
    figures = pd.DataFrame({
        "A": np.fmax(mx["hi_up"], mx["hi_down"]) - np.fmin(mn["lo_up"], mn["lo_down"]),
        "A_up": mx["hi_up"] - mn["lo_up"],
        "A_down": mx["hi_down"] - mn["lo_down"],
        "E": np.fmax(mx["mean_up"], mx["mean_down"]) - np.fmin(mn["mean_up"], mn["mean_down"]),
        "E_up": mx["mean_up"] - mn["mean_up"],
        "E_down": mx["mean_down"] - mn["mean_down"],
        "M": mx["mean_bi"] - mn["mean_bi"],
        "R": mx["R_i"], "R_up": mx["R_up_i"], "R_down": mx["R_down_i"],
        "B": mx["abs_B"], "B_mean": g["B_i"].mean(),
    })
    first = [c for c in ("unit", *TEST_COLUMNS) if c in targets.columns]
    env = [c for c in ENVIRONMENT if c in targets.columns]
    head = group[first].first()
    if env:
        head = head.join(group[env].mean())
    return head.join(figures).reset_index()


def outliers(readings: pd.DataFrame, threshold: float = OUTLIER_THRESHOLD) -> pd.Series:
    """Flag readings far from their siblings (same test, target and direction).

    A reading is flagged when |x - median(others)| > threshold * scale, where ``others`` are
    its siblings without it and scale = max(1.4826 MAD(others), sigma of its test); sigma is
    the median s over the test's sibling groups, divided by the median of chi/sqrt(dof) so
    that it is unbiased for a normal reading noise.
    The test-wide floor keeps a sibling group that agrees to the last digit from flagging
    ordinary noise; leaving the reading out keeps it from hiding itself (n is only ~5).
    Returns a boolean Series aligned with ``readings``; nothing is dropped. Raises
    ``InputError`` (``.parameter`` ``"readings"``) for a frame that is not validated readings.
    """
    readings = check_readings(readings, columns=USED)
    test = _test_index(readings)
    group = pd.Series(0, index=readings.index).groupby(
        [test, readings["target"].to_numpy(), readings["direction"].to_numpy()], sort=False)
    g = group.ngroup().to_numpy()
    k = group.cumcount().to_numpy()
    x = readings["deviation_um"].to_numpy(float)
    cube = np.full((g.max() + 1, k.max() + 1), np.nan)
    cube[g, k] = x
    n = cube.shape[1]
    if n < 3:
        return pd.Series(False, index=readings.index, name="outlier")
    # others[r, i, :] = the row r without column i
    drop_self = np.array([[j for j in range(n) if j != i] for i in range(n)])
    others = cube[:, drop_self]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # padded all-NaN sibling slices
        centre = np.nanmedian(others, axis=2)
        mad = 1.4826 * np.nanmedian(np.abs(others - centre[..., None]), axis=2)
        s_group = np.nanstd(cube, axis=1, ddof=1)
    group_test = np.zeros(len(cube), dtype=int)
    group_test[g] = test
    # median of s over a test's groups, made an unbiased sigma (median of chi with n-1 dof)
    dof = np.maximum(np.sum(~np.isnan(cube), axis=1) - 1, 1)
    s_group = s_group / np.sqrt(2 * gammaincinv(dof / 2, 0.5) / dof)  # median of chi2(dof)
    s_test = pd.Series(s_group).groupby(group_test).median()
    floor = np.maximum(s_test.reindex(group_test).to_numpy(), 1e-6)
    flag = np.abs(cube - centre) > threshold * np.fmax(mad, floor[:, None])
    return pd.Series(flag[g, k], index=readings.index, name="outlier")


def drop_outliers(readings: pd.DataFrame) -> pd.DataFrame:
    """The readings without those ``outliers`` flags."""
    return readings.loc[~outliers(readings)]
