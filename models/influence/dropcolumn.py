"""A second, non-parametric opinion: drop-column importance of gradient boosting."""

from __future__ import annotations

import numpy as np
import pandas as pd

from models.influence.design import design_groups, nested_labels


def dropcolumn_importance(X: pd.DataFrame, y_um, meta: pd.DataFrame | None = None,
                          n_splits: int = 5, random_state: int = 0,
                          max_points: int = 2000) -> pd.DataFrame:
    """Increase of the grouped cross-validated RMSE [um] of gradient boosting when one input is
    dropped; folds grouped by visit when there are at least ``n_splits`` visits, else by run.
    Larger data are subsampled by whole groups to about ``max_points`` points.

    Returns
    -------
    DataFrame indexed by input: ``dropcolumn_um``, ``dropcolumn_std_um`` (std over folds).
    """
    from sklearn.ensemble import GradientBoostingRegressor
    from sklearn.model_selection import GroupKFold

    X = X.astype(float).reset_index(drop=True)
    y = np.asarray(y_um, float)
    labels = nested_labels(design_groups(meta, len(X)), len(X))
    groups = labels["visit"] if labels["visit"].max() + 1 >= n_splits else labels["run"]
    if len(X) > max_points:
        rng = np.random.default_rng(random_state)
        unique = np.unique(groups)
        keep = rng.choice(unique, max(n_splits, int(len(unique) * max_points / len(X))),
                          replace=False)
        rows = np.flatnonzero(np.isin(groups, keep))
        X, y, groups = X.iloc[rows].reset_index(drop=True), y[rows], groups[rows]
    folds = list(GroupKFold(min(n_splits, np.unique(groups).size)).split(X, y, groups))

    def cv_rmse(columns):
        errs = []
        for train, test in folds:
            # single-threaded on purpose: small tables, and no thread pools to oversubscribe
            model = GradientBoostingRegressor(n_estimators=150, max_depth=3, subsample=0.8,
                                              random_state=random_state)
            model.fit(X.iloc[train][columns], y[train])
            errs.append(np.sqrt(np.mean((model.predict(X.iloc[test][columns]) - y[test]) ** 2)))
        return np.array(errs)

    full = cv_rmse(list(X.columns))
    rows = {}
    for c in X.columns:
        rest = [k for k in X.columns if k != c]
        loss = (cv_rmse(rest) if rest else np.sqrt(np.mean((y - y.mean()) ** 2))) - full
        rows[c] = (float(np.mean(loss)), float(np.std(loss, ddof=1)) if len(folds) > 1
                   else np.nan)
    return pd.DataFrame.from_dict(rows, orient="index",
                                  columns=["dropcolumn_um", "dropcolumn_std_um"])

