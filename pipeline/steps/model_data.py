"""A model job's data: readings -> checked feature table, noise floor, truth table.

``train``, ``compare`` (and its backtest) and ``tune`` read their data the same way, with the
same parameters (``pipeline.steps.parameters``: ``TARGET``, ``FEATURES``, ``TRUTH``...).
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from features.readings.errors import InputError
from pipeline.steps.parameters import each_once
from pipeline.steps.source import readings_of, source_of


@dataclass
class ModelData:
    """What a model job works on: the readings, their feature table, the noise floor of one
    measured backlash point [um], the twin's truth table (or None), the data's name and the
    readings' per-target ISO statistics (computed once, passed down to every step)."""

    readings: pd.DataFrame
    table: object  # features.table.FeatureTable
    noise_floor_um: float
    truth: pd.DataFrame | None
    source: str
    stats: pd.DataFrame | None = None  # features.iso230.per_target(readings), computed once

    @property
    def digest(self) -> str:
        from pipeline.results import data_hash

        return data_hash(self.readings)


def model_data(data, format: str = "auto", target: str = "auto", features=None,
               truth=None) -> ModelData:
    """Readings -> feature table (checked), noise floor and truth table (see ``train``)."""
    from features import iso230
    from features.table import check_features, feature_table
    from features.targets import MIXED
    from models.estimators.evaluation import read_truth, target_noise_floor

    readings = readings_of(data, format)
    source = source_of(data, readings)
    stats = iso230.per_target(readings)
    table = feature_table(readings, target=target, features=check_feature_names(features),
                          stats=stats)
    check_features(table.X, source, meta=table.meta, readings=readings)
    if truth is not None and not isinstance(truth, pd.DataFrame):
        truth = read_truth(truth)
    # a mixed table's points name their kinds: no second pass over the readings for them
    kinds = table.meta["target_kind"] if table.target_kind == MIXED else table.target_kind
    return ModelData(readings, table, target_noise_floor(readings, kinds), truth, source,
                     stats)


def check_feature_names(features) -> list[str] | None:
    """``features`` as a list of distinct column names, or None for the default inputs."""
    if features is None:
        return None
    names = list(features)
    if not names or not all(isinstance(n, str) and n.strip() for n in names):
        raise InputError("expected a non-empty list of feature-table column names",
                         parameter="features")
    return each_once(names, "features")
