"""Evaluation of backlash predictors: hold-out splits, scores, error against truth.

Two hold-out designs:

- ``random``: a seeded random 15 % of the points is the test set, as the paper's
  ``dividerand`` does for its test split;
- ``forward``: train on earlier visits, test on the later ones (the last quarter of the
  visits by date, at least one) — what a maintenance team meets when it predicts the next visit.

Within the training part each trainer may divide again (the LM trainer's 70/15/15
``dividerand`` validation split).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError

SPLITS = ("random", "forward")
TEST_FRACTION = 0.15
MIN_POINTS = 10


def holdout(meta: pd.DataFrame, kind: str = "random", random_state: int = 0,
            source: str = "data") -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, test) of the feature-table rows for a hold-out split."""
    n = len(meta)
    if n < MIN_POINTS:
        raise InputError(f"{n} backlash points are too few to split into training and test "
                         f"sets; expected at least {MIN_POINTS}", file=source)
    if kind == "random":
        order = np.random.default_rng(random_state).permutation(n)
        n_test = max(1, round(TEST_FRACTION * n))
        return np.sort(order[n_test:]), np.sort(order[:n_test])
    if kind == "forward":
        rank = visit_order(meta)
        visits = np.unique(rank)
        if len(visits) < 2:
            raise InputError("the forward split needs readings from at least 2 visits; "
                             "use the random split", file=source, parameter="split")
        n_test_visits = max(1, round(0.25 * len(visits)))
        test = rank >= visits[-n_test_visits]
        return np.flatnonzero(~test), np.flatnonzero(test)
    raise InputError(f"unknown split {kind!r}; expected one of {', '.join(SPLITS)}",
                     parameter="split")


def visit_order(meta: pd.DataFrame) -> np.ndarray:
    """Chronological rank of each row's visit: by first date when dates exist, else by the
    visit label in natural order (numbers as numbers)."""
    if "started_at" in meta and meta["started_at"].notna().all():
        first = meta.groupby("visit")["started_at"].transform("min")
        return first.rank(method="dense").to_numpy().astype(int)
    labels = meta["visit"].astype(str)
    numeric = pd.to_numeric(labels, errors="coerce")
    keys = sorted(labels.unique(), key=lambda v: (np.isnan(numeric[labels == v].iloc[0]),
                                                  numeric[labels == v].iloc[0], v))
    return labels.map({v: i for i, v in enumerate(keys)}).to_numpy()


def target_noise_floor(readings: pd.DataFrame, kind) -> float:
    """Standard uncertainty [um] of one measured backlash point from the repeatability.

    With pooled reading repeatability ``s`` and ``n`` cycles, a direction mean has
    variance s^2/n. The paper target z_down - z_up combines four such means
    (pendulum and linear, both directions): u = 2 s / sqrt(n). The ISO reversal value
    combines two: u = sqrt(2) s / sqrt(n). A table of both kinds (``kind`` 'mixed', or the
    points' kinds one by one) gets the root mean square over its points,
    u = sqrt(mean_k c_k^2) s / sqrt(n) with c = 2 (paper) or sqrt(2) (iso).

    Parameters
    ----------
    readings : DataFrame
        Validated readings.
    kind : {'paper', 'iso', 'mixed'} or array-like of 'paper'/'iso'
        The feature table's ``target_kind``, or the points' ``target_kind`` column. With
        'mixed' the points' kinds come from ``features.targets.backlash_targets(readings)``.
    """
    from features.readings.schema import TEST_KEYS

    groups = readings.groupby([*TEST_KEYS, "target", "direction"], sort=False)["deviation_um"]
    var, n = groups.var(ddof=1), groups.size()
    s_pooled = float(np.sqrt(np.average(var, weights=n - 1)))
    n_typical = float(np.median(n))
    return _kind_factor(readings, kind) * s_pooled / np.sqrt(n_typical)


def _kind_factor(readings: pd.DataFrame, kind) -> float:
    """c = 2 (paper) or sqrt(2) (iso); the root mean square of c over the points otherwise."""
    if isinstance(kind, str) and kind != "mixed":
        return 2.0 if kind == "paper" else float(np.sqrt(2.0))
    if isinstance(kind, str):
        from features.targets import backlash_targets

        kind = backlash_targets(readings, "auto")["target_kind"]
    c2 = np.where(np.asarray(kind) == "paper", 4.0, 2.0)
    return float(np.sqrt(np.mean(c2))) if c2.size else float(np.sqrt(2.0))


def scores(y_true, y_pred) -> dict[str, float]:
    """Seed 000's four indices: RMSE and MAE [um], R^2, MAPE [%]."""
    y_true, y_pred = np.asarray(y_true, float), np.asarray(y_pred, float)
    error = y_pred - y_true
    total = np.sum((y_true - y_true.mean()) ** 2)
    nonzero = np.abs(y_true) > 1e-9
    return {
        "rmse_um": float(np.sqrt(np.mean(error ** 2))),
        "mae_um": float(np.mean(np.abs(error))),
        "r2": float(1 - np.sum(error ** 2) / total) if total > 0 else float("nan"),
        "mape_pct": float(100 * np.mean(np.abs(error[nonzero] / y_true[nonzero])))
        if nonzero.any() else float("nan"),
    }


def scores_by_unit(y_true, y_pred, rotary, mixed: bool) -> dict[str, float]:
    """``scores`` of points from a data set that may mix linear axes (um) and rotary axes
    (arcsec): with ``mixed`` units, the linear points under the usual names and the rotary
    ones with ``_arcsec`` for ``_um`` (``r2_rotary``, ``mape_pct_rotary`` for the unitless
    ones), each only when the points hold some; one unit alone
    keeps the usual names (a rotary axis's ``deviation_um`` holds arcsec)."""
    y_true, y_pred = np.asarray(y_true, float), np.asarray(y_pred, float)
    if not mixed:
        return scores(y_true, y_pred)
    rotary = np.asarray(rotary, bool)
    out = scores(y_true[~rotary], y_pred[~rotary]) if (~rotary).any() else {}
    if rotary.any():
        out |= {k.replace("_um", "_arcsec") if "_um" in k else f"{k}_rotary": v
                for k, v in scores(y_true[rotary], y_pred[rotary]).items()}
    return out


def against_uncertainty(y_true, y_pred, U_um: float) -> dict[str, float]:
    """A predictor's error against U(B), what the measurement can resolve.

    The expanded uncertainty U(B) (k = 2, about 95 %; ISO/TR 230-9, ``features.uncertainty``)
    bounds how far a measured backlash may lie from the true one. A predictor whose 95th
    percentile of |error| against the measured values is within U(B) is as close as the
    measurement can tell; beyond it, its error is resolvable and the predictor can improve.

    Parameters
    ----------
    y_true, y_pred : array-like
        Measured and predicted backlash [um].
    U_um : float
        U(B) of the measurement [um], > 0.

    Returns
    -------
    dict
        ``U_B_um`` [um], ``test_abs_error_p95_um`` (95th percentile of |y_pred - y_true|)
        [um], ``test_rmse_over_U_B`` and ``test_abs_error_p95_over_U_B`` (ratios; <= 1:
        within what the measurement can resolve).
    """
    error = np.abs(np.asarray(y_pred, float) - np.asarray(y_true, float))
    rmse, p95 = float(np.sqrt(np.mean(error ** 2))), float(np.percentile(error, 95))
    return {"U_B_um": float(U_um), "test_abs_error_p95_um": p95,
            "test_rmse_over_U_B": rmse / U_um, "test_abs_error_p95_over_U_B": p95 / U_um}


def resolution_verdict(metrics: dict) -> str:
    """'within ...' or 'beyond what the measurement can resolve', from ``against_uncertainty``'s
    95th percentile of |error| against U(B)."""
    within = metrics["test_abs_error_p95_um"] <= metrics["U_B_um"]
    return f"{'within' if within else 'beyond'} what the measurement can resolve"


def true_backlash(meta: pd.DataFrame, truth: pd.DataFrame, kind: str | None = None) -> np.ndarray:
    """The twin's true backlash at each feature-table point, mean over the tests that show it.

    ``truth`` needs the point keys present in ``meta`` and ``true_backlash_um``. For a
    ``paper`` point (the point's ``target_kind`` in ``meta``, else ``kind``, the feature
    table's ``target_kind``) that is the pendulum test of the pair, the only one reversing at
    interior targets of a direct system, at its own temperature; for an ``iso`` point every
    test of the point. A ``mixed`` table takes each point by its own kind.
    """
    keys = [k for k in meta.columns if k in truth.columns and k not in ("started_at",)]
    out = _truth_at(meta, truth, keys)
    kinds = (meta["target_kind"].to_numpy() if "target_kind" in meta
             else np.full(len(meta), kind, dtype=object))
    paper = kinds == "paper"
    if paper.any() and "method" in truth and (truth["method"] == "pendulum").any():
        pendulum = _truth_at(meta, truth[truth["method"] == "pendulum"], keys)
        out = np.where(paper, pendulum, out)
    return out


def _truth_at(meta: pd.DataFrame, truth: pd.DataFrame, keys: list[str]) -> np.ndarray:
    """Mean ``true_backlash_um`` of ``truth`` at each row of ``meta`` (NaN where none)."""
    per_point = truth.groupby(keys, dropna=False)["true_backlash_um"].mean()
    found = meta[keys].merge(per_point.reset_index(), on=keys, how="left")
    return found["true_backlash_um"].to_numpy(float)


def read_truth(path) -> pd.DataFrame:
    """The twin's truth table (``simulate`` writes it): one line per problem, naming the file."""
    try:
        truth = pd.read_csv(path, dtype={"visit": str, "machine_id": str, "axis": str})
    except FileNotFoundError:
        raise InputError("cannot read truth table: no such file", file=path) from None
    except IsADirectoryError:
        raise InputError("cannot read truth table: a folder, expected a CSV file",
                         file=path) from None
    except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as err:
        raise InputError(f"cannot read truth table: {err}", file=path) from None
    if "true_backlash_um" not in truth:
        raise InputError("missing column true_backlash_um: expected the truth table written "
                         "by backlash simulate", file=path, column="true_backlash_um")
    return truth
