"""Which conditions drive backlash given the others (driver, proxy, none), beside the paper's
association views (weighted k-NN, ANOVA -ln(p), permutation importance, mutual information).

>>> import backlash as bl
>>> result = bl.rank("readings.csv", boot=50)   # doctest: +SKIP
>>> result.table[["verdict", "effect_um"]]      # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from numbers import Integral
from pathlib import Path

from features.readings.errors import InputError, Progress, report
from pipeline.results import Result, TrackingRecord
from pipeline.steps.constraints import Interval, StrOptions
from pipeline.steps.parameters import (
    FEATURES,
    FORMAT,
    MODEL,
    RANDOM_SEED,
    TARGET,
    Param,
    readings,
)
from pipeline.steps.source import readings_of, source_of

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--boot", "5", "--no-dropcolumn", "--out", "{side}/rank"],
    {"data": "{twin}", "boot": 5, "dropcolumn": False, "out": "{side}/rank"},
)

PARAMETERS = {
    "data": readings(),
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "output folder for the report", required=True,
                 output="folder"),
    "model": Param((*MODEL, None), metavar="DIR"),
    "bins": Param((Interval(Integral, 2, None, closed="left"), str, "array-like"),
                  parse=str),  # the text as given: parse_bins reads it
    "features": replace(FEATURES, help=None),  # described by rank's docstring
    "target": Param((*TARGET.accepts, None)),
    "k": Param((Interval(Integral, 1, None, closed="left"),)),
    "rank_by": Param((StrOptions(("consensus", "anova")),)),
    "boot": Param((Interval(Integral, 0, None, closed="left"),)),
    "dropcolumn": Param(("boolean",)),
    "seed": RANDOM_SEED,
}


@dataclass
class RankResult(Result):
    """Verdicts given the other inputs and the association views of one data set.

    Attributes
    ----------
    explanation : models.influence.Explanation
        Association (``.ranking``) and conditional influence (``.influence``).
    table : DataFrame
        One row per input, drivers first (largest effect [um] first), then proxies,
        undecided and none: verdict, effect [um] with its 95 % interval, the input it stands
        in for, and every association score.
    target_kind : str
        Backlash definition used (``paper`` or ``iso``).
    source : str
        Where the readings came from.
    readings : DataFrame
        The validated readings the ranking was computed from.
    parameters : dict
        The workflow's parameters as given (logged with the run).
    """

    explanation: object
    target_kind: str
    source: str
    readings: object = field(repr=False)
    parameters: dict = field(default_factory=dict)

    @property
    def table(self):
        return self.explanation.table

    @property
    def unit(self) -> str:
        """Unit of every backlash value: um, or arcsec for rotary axes."""
        from features.readings.schema import unit_of

        return unit_of(self.readings["axis"])

    @property
    def knn(self):
        """The cross-validated weighted k-NN (``features.ranking.KnnResult``)."""
        return self.explanation.knn

    def drivers(self) -> list[str]:
        """Inputs with a verdict ``driver``, largest effect first."""
        return self.explanation.drivers()

    def write(self, out) -> dict[str, Path]:
        """The report files of ``pipeline.reports.rank_report`` (HTML, figures, CSV, JSON)."""
        from pipeline.reports.rank_report import write_rank_report

        self.files = write_rank_report(self.explanation, out, source=self.source,
                                       target_kind=self.target_kind, unit=self.unit)
        return self.files

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan(self.explanation.to_dict())

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``rank``: parameters, every score as a metric, the files."""
        from pipeline.results import data_hash

        e, p = self.explanation, self.parameters
        model = p.get("model")
        params = {"data": self.source, "data_sha256": data_hash(self.readings),
                  "n_points": e.n_points, "features": ",".join(self.table.index),
                  "bins": p.get("bins"), "k": p.get("k"), "rank_by": e.ranking.rank_by,
                  "seed": p.get("seed"), "boot": p.get("boot"), "target_kind": self.target_kind,
                  "model": model if isinstance(model, (str, os.PathLike)) or model is None
                  else type(model).__name__,
                  "permutation_model": e.ranking.permutation_model[:500]}
        params["model"] = str(params["model"] or "")
        metrics = {"knn_accuracy": e.knn.accuracy, "knn_accuracy_std": e.knn.accuracy_std,
                   "n_drivers": float(len(e.drivers()))}
        columns = ("effect_um", "effect_low_um", "effect_high_um", "anova_score",
                   "anova_score_std", "permutation_um", "mutual_info", "knn_drop")
        for name, row in self.table.iterrows():
            metrics[f"driver_{name}"] = float(row["verdict"] == "driver")
            metrics.update({f"{c}_{name}": row[c] for c in columns})
            metrics[f"rank_{name}"] = float(row["rank"])
        return TrackingRecord("rank", f"rank {os.path.basename(self.source)}", params=params,
                              metrics=metrics, artifacts=list(self.files.values()),
                              artifact_path="rank")


def rank(data, *, format: str = "auto", model=None, bins=4, features=None,
         target: str | None = None, k: int = 5, rank_by: str = "consensus", boot: int = 200,
         dropcolumn: bool = True, seed: int = 0,
         progress: Progress | None = None) -> RankResult:
    """Which inputs drive backlash given the others, and the paper's association views.

    Parameters
    ----------
    data : str, path or DataFrame
        Readings file, or a readings frame as ``read`` returns it.
    format : str, default 'auto'
        Input layout of a file (see ``features.readings.schema.FORMATS``).
    model : str, path or fitted predictor, optional
        A trained model directory: its predictor gives the permutation importance of the
        association views (default: a gradient boosting regressor fitted per cross-validation
        fold); it also sets the default features and target.
    bins : int, str or list of float, default 4
        Backlash classes: a count of quantile classes (at least 2), or class boundaries [um],
        comma-separated such as ``2,4,6``.
    features : list of str, optional
        Feature-table columns, comma-separated; default every input the data supply, or the
        model's inputs.
    target : {'auto', 'paper', 'iso'}, optional
        Backlash definition: pendulum minus linear (``paper``), the ISO reversal value
        (``iso``) or chosen from the measuring-system evidence (``auto``); default the
        model's, else ``auto``.
    k : int, default 5
        Neighbours of the weighted k-NN.
    rank_by : {'consensus', 'anova'}, default 'consensus'
        Order of the association views: the mean rank of ANOVA, permutation and mutual
        information (``consensus``), or the ANOVA score as in the paper (``anova``); the
        report lists drivers first either way.
    boot : int, default 200
        Bootstrap resamples of the effect intervals and the ANOVA spreads (0: none).
    dropcolumn : bool, default True
        Compute the drop-column importance of gradient boosting; skipping it is faster.
    seed : int, default 0
        Random seed.
    progress : callable, optional
        ``progress(done, total, what)``, called as the work advances.

    Returns
    -------
    RankResult
    """
    from features.table import feature_table
    from models.influence import explain
    from pipeline.steps.model_data import check_feature_names

    classes = parse_bins(bins)
    names = check_feature_names(features)
    report(progress, 0, 3, "reading")
    predictor = _predictor(model)
    if predictor is not None and names is None:
        names = list(predictor.feature_names_)
    readings = readings_of(data, format)
    source = source_of(data, readings)
    table = feature_table(readings, target=target or getattr(predictor, "target_kind", "auto"),
                          features=names)
    notes = _notes(predictor, table)
    report(progress, 1, 3, "association and influence")
    explanation = explain(table.X, table.y, table.meta, bins=classes, n_neighbors=k,
                          estimator=predictor, prefit=predictor is not None, rank_by=rank_by,
                          n_boot=boot, dropcolumn=dropcolumn, random_state=seed, source=source)
    explanation.notes.extend(notes)
    report(progress, 3, 3, "done")
    parameters = {"format": format, "model": model, "bins": bins, "features": features,
                  "target": target, "k": k, "rank_by": rank_by, "boot": boot,
                  "dropcolumn": dropcolumn, "seed": seed}
    return RankResult(explanation, table.target_kind, source, readings, parameters,
                      notes=list(explanation.notes))


def parse_bins(bins):
    """``4`` or ``"4"`` -> 4 quantile classes; ``"2,4.5"`` or ``[2, 4.5]`` -> boundaries [um]."""
    if isinstance(bins, Integral) and not isinstance(bins, bool):
        return int(bins)
    parts = ([p.strip() for p in bins.split(",") if p.strip()] if isinstance(bins, str)
             else list(bins))
    if len(parts) == 1 and isinstance(parts[0], str) and parts[0].lstrip("+").isdigit():
        count = int(parts[0])
        if count < 2:
            raise InputError(f"must be at least 2 classes; got {count}", parameter="bins")
        return count
    try:
        edges = [float(p) for p in parts]
    except (TypeError, ValueError):
        edges = []
    if not edges or not all(math.isfinite(e) for e in edges):
        raise InputError(f"expects a class count such as 4 or boundaries in um such as "
                         f"2,4,6; got {bins!r}", parameter="bins")
    return edges


def _predictor(model):
    if isinstance(model, (str, os.PathLike)):
        from models.serving.registry import load_model

        return load_model(model)
    return model


def _notes(predictor, table) -> list[str]:
    """What the report says about the choices made for the user."""
    if predictor is not None:
        missing = [f for f in predictor.feature_names_ if f not in table.X.columns]
        if missing:
            raise InputError(f"the model needs input {missing[0]!r}, which the features leave "
                             "out", parameter="features")
        scored = ("permutation importance of the given trained model, scored on these data; "
                  "if the model was trained on them, the scores are optimistic")
    else:
        scored = ("no model given: a gradient boosting regressor was fitted per "
                  "cross-validation fold for the permutation importance")
    notes = [scored]
    if table.reason:
        notes.append(f"backlash target {table.target_kind}: {table.reason}")
    if "visit" not in table.meta or table.meta["visit"].nunique(dropna=True) < 2:
        notes.append("a single visit: no input can be told apart from the visit, and "
                     "operating hours cannot be tested")
    return notes
