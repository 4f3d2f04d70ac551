"""Association of each input with backlash: the paper's marginal views and two checks.

Everything here is *association*, not influence: each view looks at one input at a time (or
at a predictor's use of it), so an input that merely moves with a driver over the test plan
(run order, visits, warm-up with feed) scores like the driver, and a real driver can hide
behind a larger one. Which inputs *drive* backlash, given the others, is decided in
``models.influence`` from the effect records; this module gives the paper's views beside it.

The backlash paper [BacklashNN], section 5 ranks its eight inputs with a distance-weighted
k-nearest-neighbour classifier on backlash classes (validation accuracy 98.8 %) and a one-way
ANOVA F-test per input, scored as -ln(p) (Fig. 14, Table 5). This module reproduces both and
adds two checks that see what a comparison of class means cannot:

==================  =========================================================================
score               definition and uncertainty
==================  =========================================================================
k-NN accuracy       ``StandardScaler + KNeighborsClassifier(weights="distance")`` on backlash
                    classes; mean accuracy over stratified K folds, spread = std over folds.
k-NN drop-column    per fold: accuracy with all inputs minus accuracy without this input
                    [fraction]; mean and std over the same folds.
ANOVA score         -ln(p) of the one-way F-test of the input across the backlash classes
                    (``sklearn.feature_selection.f_classif``); p from the log survival
                    function of F(dfn, dfd), so p = 1e-300 stays finite (score 690.8).
                    Spread = std over bootstrap resamples of the points.
permutation         increase of the held-out RMSE [um] of a predictor when the input is
                    shuffled (``sklearn.inspection.permutation_importance``). Unfitted
                    predictor: fitted per K fold, scored on the held-out fold; spread = std
                    over folds x shuffles. Fitted predictor: scored on the given data;
                    spread = std over shuffles.
mutual information  ``mutual_info_regression`` [nat], seeded; spread = std over random 80 %
                    subsamples (bootstrap duplicates would bias the k-neighbour estimator);
                    null level = mean + 3 std of the MI with the backlash shuffled.
==================  =========================================================================

An input has a *measurable association* (column ``influence``, kept under its old name) when
at least one view separates it from noise: ANOVA p < 0.001, permutation mean above twice its
spread and above 2 % of the strongest input's, or MI above its null level.

Final rank (default ``rank_by="consensus"``): inputs with a measurable influence first; within
each group the mean of the three per-view ranks (ANOVA score, permutation importance, MI),
ties broken by the ANOVA score. ``rank_by="anova"`` is the paper's order: ANOVA score,
largest first, compared at the three decimals of Table 5, ties broken by the permutation
importance. The paper's order is blind to an effect that is not monotone: with wear peaking
mid-travel every backlash class has the same mean position, ANOVA gives p ~ 0.7 and a
non-driver (pressure) can rank first, while permutation and MI put position on top. A plain
mean of ranks is not enough either (position last by ANOVA, first by MI averages to the
middle, behind noise inputs that sit mid-table everywhere); hence influence first.

An input that varied (almost) only between visits (within-visit share of its variance below
``features.statistics.MIN_LEVEL_SHARE``, 10 %) cannot be told apart from the visit itself: it
is reported as a proxy for the visit, whatever its score.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.statistics import MIN_LEVEL_SHARE, within_share

N_NEIGHBORS = 5
N_BINS = 4
N_SPLITS = 5
ANOVA_ALPHA = 1e-3            # p below this: the ANOVA sees the input
PERMUTATION_FLOOR = 0.02      # share of the strongest input's permutation importance
# within-visit share of variance below this: proxy for the visit (the reason is given there)
PROXY_WITHIN_SHARE = MIN_LEVEL_SHARE
RANK_BY = ("consensus", "anova")

# Names of the paper's Table 5 for the feature-table columns.
LABELS = {
    "target": "Position",
    "deviation_down_um": "Negative-direction deviation",
    "deviation_up_um": "Positive-direction deviation",
    "feed_mm_min": "Feed rate",
    "machine_temp_c": "Machine temperature",
    "ambient_temp_c": "Ambient temperature",
    "pressure_hpa": "Atmospheric pressure",
    "humidity_pct": "Air humidity",
    "dwell_s": "Dwell time",
    "operating_hours": "Operating hours",
}

@dataclass
class KnnResult:
    """Cross-validated weighted k-NN classification of backlash classes."""

    accuracy: float
    accuracy_std: float
    fold_accuracy: np.ndarray
    confusion: np.ndarray          # rows: true class, columns: predicted class
    class_edges_um: np.ndarray     # len(classes) + 1 edges [um]
    class_counts: np.ndarray
    n_neighbors: int
    n_splits: int
    majority_rate: float           # accuracy of always guessing the largest class
    unit: str = "um"               # of the class edges: arcsec on rotary axes

    @property
    def class_labels(self) -> list[str]:
        e = self.class_edges_um
        return [f"{lo:.3g}-{hi:.3g} {self.unit}" for lo, hi in itertools.pairwise(e)]


@dataclass
class Ranking:
    """Scores per input (``table``, ordered by rank) and the k-NN classification."""

    table: pd.DataFrame
    knn: KnnResult
    rank_by: str
    permutation_model: str
    n_points: int
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Machine-readable summary; ``features`` ordered by rank."""
        t = self.table
        features = [{
            "name": name, "label": row.label, "anova_score": row.anova_score,
            "anova_score_std": row.anova_score_std, "anova_f": row.anova_f,
            "permutation": row.permutation_um, "permutation_std": row.permutation_std_um,
            "mutual_info": row.mutual_info, "mutual_info_std": row.mutual_info_std,
            "mutual_info_null": row.mutual_info_null, "knn_drop": row.knn_drop,
            "knn_drop_std": row.knn_drop_std, "influence": bool(row.influence),
            "proxy_for_visit": bool(row.proxy_for_visit), "rank": int(row.rank),
            "reading": row.reading,
        } for name, row in zip(t.index, t.itertuples(index=False), strict=True)]
        knn = self.knn
        return {
            "knn_accuracy": knn.accuracy, "knn_accuracy_std": knn.accuracy_std,
            "knn_majority_rate": knn.majority_rate, "knn_neighbors": knn.n_neighbors,
            "knn_folds": knn.n_splits, "classes_um": knn.class_labels,
            "class_counts": knn.class_counts.tolist(), "confusion": knn.confusion.tolist(),
            "rank_by": self.rank_by, "permutation_model": self.permutation_model,
            "n_points": self.n_points, "notes": self.notes, "features": features,
        }


# --- inputs ---------------------------------------------------------------------------------

def check_inputs(X: pd.DataFrame, y, n_neighbors: int = N_NEIGHBORS,
                 source: str = "features") -> None:
    """Refuse what no ranking can use: NaN, constant inputs, NaN backlash, too few points.

    Raises
    ------
    InputError
        naming the input (column) and the point where known.
    """
    from features.table import check_features

    y = np.asarray(y, dtype=float)
    if len(y) != len(X):
        raise InputError(f"{len(X)} input rows but {len(y)} backlash values", file=source)
    check_features(X, source)
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise InputError(f"backlash is NaN/inf at point {bad[0] + 1}; every point needs a "
                         "backlash value", file=source, column="backlash_um")
    if len(X) <= n_neighbors:
        raise InputError(f"only {len(X)} points but k = {n_neighbors} neighbours: k-NN needs "
                         "more points than k; give a smaller k or more data", file=source,
                         parameter="k")


def backlash_classes(y_um, bins=N_BINS, source: str = "features", unit: str = "um"):
    """Backlash classes for the k-NN classifier and the ANOVA.

    Parameters
    ----------
    y_um : array-like
        Backlash per point [um].
    bins : int or sequence of float
        An int N gives N quantile classes (equal counts; tied values may merge classes).
        A sequence gives the class boundaries [um]: ``(-inf, b1), [b1, b2), ..., [bk, inf)``.

    Returns
    -------
    classes : ndarray of int
        Class 0..C-1 per point, empty classes removed.
    edges_um : ndarray
        C + 1 class edges [um], the outer ones at the smallest and largest backlash.
    """
    y = np.asarray(y_um, dtype=float)
    if np.ndim(bins) == 0:
        if int(bins) < 2:
            raise InputError(f"must be at least 2 classes; got {bins}", file=source,
                             parameter="bins")
        cuts = np.unique(np.quantile(y, np.linspace(0, 1, int(bins) + 1))[1:-1])
    else:
        cuts = np.unique(np.asarray(bins, dtype=float))
    raw = np.searchsorted(cuts, y, side="right")
    used, classes = np.unique(raw, return_inverse=True)
    if used.size < 2:
        raise InputError(f"all {len(y)} points fall into one backlash class "
                         f"({y.min():.3g}-{y.max():.3g} {unit}): a ranking needs backlash that "
                         "varies (check the data or the class boundaries)", file=source,
                         column="backlash_um", parameter="bins")
    inner = cuts[used[1:] - 1]
    return classes, np.concatenate([[y.min()], inner, [y.max()]])


def within_visit_share(X: pd.DataFrame, groups) -> pd.Series:
    """Share of each input's variance found within visits: SS_within / SS_total
    (``features.statistics.within_share``).

    Near 0: the input was constant within each visit and only differs between them.
    NaN when there is a single visit or the input does not vary.
    """
    share = within_share(X.to_numpy(float), np.asarray(groups))
    return pd.Series(share, index=X.columns, name="within_visit_share")


# --- the four views -------------------------------------------------------------------------

def anova_neg_log_p(f_stat, dfn, dfd) -> np.ndarray:
    """ANOVA score -ln(p) of an F statistic, finite even where p underflows.

    .. math::

        s = -\\ln p, \\quad p = \\Pr[F_{dfn, dfd} > F] = I_x(d_2/2, d_1/2),
        \\quad x = \\frac{d_2}{d_2 + d_1 F}

    Where ``scipy.stats.f.logsf`` still resolves p (p > 1e-260) it is used; below, where it
    returns -inf, the small-x series of the regularised incomplete beta function is taken in
    log form: ln I_x(a, b) = a ln x + ln 2F1(a, 1 - b; a + 1; x) - ln a - ln B(a, b)
    (hypergeometric form of the incomplete beta function, DLMF section 8.17).
    Seed 004, Table 5 reports -log(p).

    Parameters
    ----------
    f_stat : array-like
        F statistics [-].
    dfn, dfd : float
        Degrees of freedom between classes (C - 1) and within classes (n - C).
    """
    from scipy import special, stats

    f_stat = np.asarray(f_stat, dtype=float)
    direct = stats.f.logsf(f_stat, dfn, dfd)
    a, b = dfd / 2.0, dfn / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        x = dfd / (dfd + dfn * f_stat)
        series = (a * np.log(x) + np.log(special.hyp2f1(a, 1.0 - b, a + 1.0, x))
                  - np.log(a) - special.betaln(a, b))
    return -np.where(direct > -600.0, direct, series)


def anova_scores(X: pd.DataFrame, classes, n_boot: int = 200,
                 random_state: int = 0) -> pd.DataFrame:
    """One-way ANOVA of each input across backlash classes: F, -ln(p) and its bootstrap std.

    Returns
    -------
    DataFrame indexed by input: ``anova_f``, ``anova_score`` (-ln p), ``anova_score_std``.
    """
    from sklearn.feature_selection import f_classif

    values = X.to_numpy(dtype=float)
    classes = np.asarray(classes)

    def score(rows):
        c = classes[rows]
        n_classes = np.unique(c).size
        with warnings.catch_warnings():  # a resample may hold an input constant: F is NaN
            warnings.simplefilter("ignore")
            f_stat, _ = f_classif(values[rows], c)
        return f_stat, anova_neg_log_p(f_stat, n_classes - 1, len(rows) - n_classes)

    f_stat, neg_log_p = score(np.arange(len(values)))
    rng = np.random.default_rng(random_state)
    draws = rng.integers(0, len(values), size=(n_boot, len(values)))
    boot = np.array([score(rows)[1] for rows in draws]) if n_boot else np.full((1, 1), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spread = np.nanstd(np.where(np.isfinite(boot), boot, np.nan), axis=0, ddof=1)
    return pd.DataFrame({"anova_f": f_stat, "anova_score": neg_log_p,
                         "anova_score_std": spread}, index=X.columns)


def knn_classifier(n_neighbors: int = N_NEIGHBORS):
    """The paper's weighted k-NN: standardised inputs, neighbours weighted by 1/distance."""
    from sklearn.neighbors import KNeighborsClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    return make_pipeline(StandardScaler(),
                         KNeighborsClassifier(n_neighbors=n_neighbors, weights="distance"))


def knn_scores(X: pd.DataFrame, classes, edges_um, n_neighbors: int = N_NEIGHBORS,
               n_splits: int = N_SPLITS, random_state: int = 0,
               source: str = "features", unit: str = "um") -> tuple[KnnResult, pd.DataFrame]:
    """Stratified-CV accuracy of the weighted k-NN and its drop-column accuracy loss per input.

    Returns
    -------
    KnnResult, and a DataFrame indexed by input with ``knn_drop`` and ``knn_drop_std``
    (accuracy with all inputs minus accuracy without the input, mean and std over folds).
    """
    from sklearn.metrics import confusion_matrix
    from sklearn.model_selection import StratifiedKFold

    classes = np.asarray(classes)
    counts = np.bincount(classes)
    folds = min(n_splits, int(counts.min()))
    if folds < 2:
        raise InputError(f"backlash class {edges_um[counts.argmin()]:.3g}-"
                         f"{edges_um[counts.argmin() + 1]:.3g} {unit} holds a single point; "
                         "cross-validation needs two per class; give fewer classes",
                         file=source, column="backlash_um", parameter="bins")
    smallest_train = len(classes) - int(np.ceil(len(classes) / folds))
    if smallest_train < n_neighbors:
        raise InputError(f"a training fold holds {smallest_train} points, fewer than "
                         f"k = {n_neighbors} neighbours; give a smaller k or more data",
                         file=source, parameter="k")
    splits = list(StratifiedKFold(folds, shuffle=True, random_state=random_state)
                  .split(X, classes))
    values = X.to_numpy(dtype=float)
    columns = [np.arange(values.shape[1])] + [np.delete(np.arange(values.shape[1]), j)
                                              for j in range(values.shape[1])]
    accuracy = np.empty((len(columns), folds))
    predicted = np.empty_like(classes)
    for f, (train, test) in enumerate(splits):
        for c, cols in enumerate(columns):
            model = knn_classifier(n_neighbors).fit(values[np.ix_(train, cols)], classes[train])
            guess = model.predict(values[np.ix_(test, cols)])
            accuracy[c, f] = np.mean(guess == classes[test])
            if c == 0:
                predicted[test] = guess
    loss = accuracy[0] - accuracy[1:]
    result = KnnResult(
        accuracy=float(accuracy[0].mean()), accuracy_std=float(accuracy[0].std(ddof=1)),
        fold_accuracy=accuracy[0],
        confusion=confusion_matrix(classes, predicted, labels=np.arange(counts.size)),
        class_edges_um=np.asarray(edges_um, dtype=float), class_counts=counts,
        n_neighbors=n_neighbors, n_splits=folds, majority_rate=float(counts.max() / counts.sum()),
        unit=unit)
    drop = pd.DataFrame({"knn_drop": loss.mean(axis=1), "knn_drop_std": loss.std(axis=1, ddof=1)},
                        index=X.columns)
    return result, drop


def default_predictor(random_state: int = 0):
    """Predictor for permutation importance when none is given: gradient boosting."""
    from sklearn.ensemble import GradientBoostingRegressor

    return GradientBoostingRegressor(random_state=random_state)


def permutation_scores(X: pd.DataFrame, y_um, estimator=None, prefit: bool = False,
                       n_splits: int = N_SPLITS, n_repeats: int = 5,
                       random_state: int = 0) -> pd.DataFrame:
    """Permutation importance: increase of the held-out RMSE [um] when an input is shuffled.

    Parameters
    ----------
    estimator : object with ``predict`` (and ``fit`` unless ``prefit``), optional
        Default ``default_predictor``. Unfitted: cloned and fitted on each of ``n_splits``
        shuffled K folds, scored on the held-out fold. ``prefit=True``: scored on all of X
        as given (X is then data the predictor did not see, ideally).

    Returns
    -------
    DataFrame indexed by input: ``permutation_um`` and ``permutation_std_um``.
    """
    from sklearn.base import clone
    from sklearn.inspection import permutation_importance
    from sklearn.model_selection import KFold

    y = np.asarray(y_um, dtype=float)
    scoring = "neg_root_mean_squared_error"
    if prefit:
        estimator = estimator if hasattr(estimator, "fit") else _prefit(estimator)
        found = permutation_importance(estimator, X, y, scoring=scoring, n_repeats=n_repeats,
                                       random_state=random_state).importances
    else:
        estimator = default_predictor(random_state) if estimator is None else estimator
        folds = KFold(min(n_splits, len(X)), shuffle=True, random_state=random_state)
        found = np.hstack([
            permutation_importance(clone(estimator).fit(X.iloc[train], y[train]),
                                   X.iloc[test], y[test], scoring=scoring,
                                   n_repeats=n_repeats, random_state=random_state).importances
            for train, test in folds.split(X)])
    return pd.DataFrame({"permutation_um": found.mean(axis=1),
                         "permutation_std_um": found.std(axis=1, ddof=1)}, index=X.columns)


def _prefit(predictor):
    """A fitted predictor that has only ``predict``, seen through the scikit-learn API."""
    from sklearn.base import BaseEstimator, RegressorMixin

    class Prefit(RegressorMixin, BaseEstimator):
        def fit(self, X, y=None):
            raise TypeError("a given fitted predictor is never refitted")

        def predict(self, X):
            return np.asarray(predictor.predict(X), dtype=float)

        def __sklearn_is_fitted__(self):
            return True

    return Prefit()


def mutual_info_scores(X: pd.DataFrame, y_um, n_subsamples: int = 10, fraction: float = 0.8,
                       n_null: int = 10, random_state: int = 0) -> pd.DataFrame:
    """Mutual information between each input and backlash [nat], a non-linear check.

    Estimator: ``sklearn.feature_selection.mutual_info_regression`` (Kraskov k-neighbour,
    3 neighbours), seeded. Spread: std over ``n_subsamples`` random subsamples holding
    ``fraction`` of the points. Null level: mean + 3 std of the MI with backlash shuffled
    ``n_null`` times.

    Returns
    -------
    DataFrame indexed by input: ``mutual_info``, ``mutual_info_std``, ``mutual_info_null``.
    """
    from sklearn.feature_selection import mutual_info_regression

    values = X.to_numpy(dtype=float)
    y = np.asarray(y_um, dtype=float)
    rng = np.random.default_rng(random_state)

    def mi(rows, target):
        return mutual_info_regression(values[rows], target, random_state=random_state)

    every = np.arange(len(y))
    size = max(round(fraction * len(y)), 4)
    subsets = [rng.choice(len(y), size, replace=False) for _ in range(n_subsamples)]
    spread = np.array([mi(rows, y[rows]) for rows in subsets]).std(axis=0, ddof=1)
    null = np.array([mi(every, rng.permutation(y)) for _ in range(n_null)])
    return pd.DataFrame({"mutual_info": mi(every, y), "mutual_info_std": spread,
                         "mutual_info_null": null.mean(axis=0) + 3 * null.std(axis=0, ddof=1)},
                        index=X.columns)


# --- rank and reading -----------------------------------------------------------------------

def influence(table: pd.DataFrame) -> pd.Series:
    """True where at least one view separates the input from noise (module docstring)."""
    anova = table["anova_score"] > -np.log(ANOVA_ALPHA)
    perm = table["permutation_um"]
    permutation = ((perm > 2 * table["permutation_std_um"])
                   & (perm > PERMUTATION_FLOOR * max(perm.max(), 0.0)))
    mutual = table["mutual_info"] > table["mutual_info_null"]
    return (anova | permutation | mutual).rename("influence")


def final_rank(table: pd.DataFrame, rank_by: str = "consensus") -> pd.Series:
    """Rank 1 = strongest driver (module docstring for the rules)."""
    if rank_by not in RANK_BY:
        raise InputError(f"unknown rank rule {rank_by!r}; expected one of {', '.join(RANK_BY)}")
    if rank_by == "anova":
        keys = pd.DataFrame({"a": table["anova_score"].round(3).fillna(-np.inf),
                             "b": table["permutation_um"].fillna(-np.inf)})
    else:
        views = table[["anova_score", "permutation_um", "mutual_info"]].fillna(-np.inf)
        keys = pd.DataFrame({"i": influence(table).astype(int),
                             "a": -views.rank(ascending=False).mean(axis=1),
                             "b": table["anova_score"].fillna(-np.inf)})
    order = keys.sort_values(list(keys.columns), ascending=False, kind="stable").index
    return pd.Series(np.arange(1, len(order) + 1), index=order, name="rank").reindex(table.index)


def association_reading(name: str, row: pd.Series, unit: str = "um") -> str:
    """One sentence on what the marginal views see (association only, no causal claim)."""
    label = LABELS.get(name, name)
    if row["proxy_for_visit"]:
        return (f"{label} stands in for the visit: it was constant within each visit and "
                "differed between visits, so its association measures whatever else changed "
                "between visits.")
    p_text = format_p(row["anova_score"])
    if not row["influence"]:
        return (f"{label} shows no measurable association with backlash (ANOVA {p_text}, "
                f"permutation {row['permutation_um']:.2g} ± {row['permutation_std_um']:.2g} {unit}, "
                "MI at noise level).")
    hidden = (row["anova_score"] <= -np.log(ANOVA_ALPHA))
    tail = ("; the association is not monotone, so the ANOVA of class means misses what "
            "permutation or mutual information see") if hidden else ""
    return f"{label} is associated with backlash (ANOVA {p_text}){tail}."


def format_p(neg_log_p: float) -> str:
    """``p = 3.1e-45`` from -ln(p), also below the smallest float (p < 1e-308)."""
    if not np.isfinite(neg_log_p):
        return "p = 0" if neg_log_p > 0 else "p = n/a"
    log10_p = -neg_log_p / np.log(10)
    exponent = int(np.floor(log10_p))
    if exponent >= -3:
        return f"p = {10 ** log10_p:.3g}"
    return f"p = {10 ** (log10_p - exponent):.2g}e{exponent}"


def rank_features(X: pd.DataFrame, y_um, groups=None, bins=N_BINS,
                  n_neighbors: int = N_NEIGHBORS, n_splits: int = N_SPLITS, estimator=None,
                  prefit: bool = False, rank_by: str = "consensus", n_boot: int = 200,
                  n_repeats: int = 5, random_state: int = 0,
                  source: str = "features", unit: str = "um") -> Ranking:
    """Rank the inputs of a feature table by their association with backlash (marginal views).

    Parameters
    ----------
    X : DataFrame
        Inputs, one column per condition (feature-table names, ``features.table``).
    y_um : array-like
        Backlash per point [um].
    groups : array-like, optional
        Visit of each point; enables the proxy-for-visit check.
    bins : int or sequence of float
        Backlash classes for k-NN and ANOVA (``backlash_classes``).
    estimator, prefit
        Predictor for permutation importance (``permutation_scores``).
    rank_by : {'anova', 'consensus'}
        Final rank rule (module docstring).
    unit : str
        Unit of the backlash in labels and sentences: um, or arcsec for rotary axes.

    Returns
    -------
    Ranking
    """
    if rank_by not in RANK_BY:
        raise InputError(f"unknown rank rule {rank_by!r}; expected one of {', '.join(RANK_BY)}",
                         file=source)
    check_inputs(X, y_um, n_neighbors, source)
    X = X.astype(float).reset_index(drop=True)
    y = np.asarray(y_um, dtype=float)
    classes, edges = backlash_classes(y, bins, source, unit)
    knn, drop = knn_scores(X, classes, edges, n_neighbors, n_splits, random_state, source, unit)
    table = pd.concat([
        anova_scores(X, classes, n_boot, random_state),
        permutation_scores(X, y, estimator, prefit, n_splits, n_repeats, random_state),
        mutual_info_scores(X, y, random_state=random_state),
        drop,
    ], axis=1)
    share = (within_visit_share(X, groups) if groups is not None
             else pd.Series(np.nan, index=X.columns))
    table["within_visit_share"] = share
    table["proxy_for_visit"] = share.lt(PROXY_WITHIN_SHARE)
    table["influence"] = influence(table)
    table["rank"] = final_rank(table, rank_by)
    table.insert(0, "label", [LABELS.get(c, c) for c in table.index])
    table["reading"] = [association_reading(name, row, unit) for name, row in table.iterrows()]
    table = table.sort_values("rank")
    table.index.name = "feature"
    if prefit:
        model = f"given fitted predictor {type(estimator).__name__}, scored on these data"
    else:
        model = (f"{type(estimator or default_predictor(random_state)).__name__} fitted per "
                 f"fold ({min(n_splits, len(X))}-fold CV)")
    return Ranking(table, knn, rank_by, model, len(X))
