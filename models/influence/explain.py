"""Association and influence together: what ``backlash rank`` reports."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.schema import unit_of
from models.influence.design import design_groups
from models.influence.dropcolumn import dropcolumn_importance
from models.influence.verdicts import ALPHA, Influence, conditional_influence


@dataclass
class Explanation:
    """The paper's association views (``ranking``) and the verdicts given the others
    (``influence``); ``table`` joins both, ordered drivers first (largest effect first), then
    proxies, undecided and none, each group in the association rank."""

    ranking: object              # features.ranking.Ranking
    influence: Influence
    table: pd.DataFrame
    notes: list[str] = field(default_factory=list)

    @property
    def knn(self):
        return self.ranking.knn

    @property
    def n_points(self) -> int:
        return self.ranking.n_points

    def drivers(self) -> list[str]:
        return self.influence.drivers()

    def to_dict(self) -> dict:
        """``features.ranking.Ranking.to_dict`` plus, per feature, ``verdict``, ``effect_um``
        with ``effect_interval_um``, ``proxy_for`` and the conditional tests; ``rank`` is the
        verdict order, ``association_rank`` the marginal views' rank; ``design`` holds the
        diagnostics."""
        base = self.ranking.to_dict()
        by_name = {f["name"]: f for f in base["features"]}
        features = []
        for position, name in enumerate(self.table.index, start=1):
            item = dict(by_name[name])
            item["association_rank"] = item["rank"]
            item["rank"] = position
            item.update(self.influence.feature_json(name))
            features.append(item)
        base.update(features=features, drivers=self.drivers(),
                    verdict_alpha=self.influence.alpha, n_boot=self.influence.n_boot,
                    design=self.influence.design.to_dict(), notes=[*base["notes"], *self.notes])
        return base


def explain(X: pd.DataFrame, y_um, meta: pd.DataFrame | None = None, *, bins=4,
            n_neighbors: int = 5, estimator=None, prefit: bool = False,
            rank_by: str = "consensus", n_boot: int = 200, n_repeats: int = 5,
            dropcolumn: bool = True, alpha: float = ALPHA, random_state: int = 0,
            source: str = "features") -> Explanation:
    """Association (``features.ranking.rank_features``) and conditional influence
    (``conditional_influence``, with ``dropcolumn_importance`` unless ``dropcolumn=False``) of
    every input of a feature table. ``meta`` holds the point keys (runs, visits, units)."""
    from features.ranking import rank_features

    groups = None
    if meta is not None and "visit" in meta and meta["visit"].nunique(dropna=True) > 1:
        groups = design_groups(meta, len(X))["visit"]
    ranking = rank_features(X, y_um, groups=groups, bins=bins, n_neighbors=n_neighbors,
                            estimator=estimator, prefit=prefit, rank_by=rank_by,
                            n_boot=n_boot, n_repeats=n_repeats, random_state=random_state,
                            source=source, unit=unit_of(meta["axis"]) if meta is not None
                            and "axis" in meta else "um")
    X = X.reset_index(drop=True)
    drop = (dropcolumn_importance(X, y_um, meta, random_state=random_state)
            if dropcolumn else None)
    result = conditional_influence(X, y_um, meta, association=ranking.table["influence"],
                                   alpha=alpha, n_boot=n_boot, random_state=random_state,
                                   dropcolumn=drop, source=source)
    verdict = result.table[[c for c in result.table.columns if c != "label"]]
    joined = ranking.table.join(verdict.drop(columns=["association"]))
    order = {"driver": 0, "proxy": 1, "undecided": 2, "none": 3}
    joined = joined.assign(_o=joined["verdict"].map(order),
                           _e=np.where(joined["verdict"] == "driver",
                                       -joined["effect_um"].fillna(0), 0.0))
    joined = joined.sort_values(["_o", "_e", "rank"], kind="stable").drop(columns=["_o", "_e"])
    notes = list(result.notes)
    if drop is not None:
        notes.append("drop-column importance: gradient boosting, cross-validation grouped by "
                     "visit (or run), increase of the held-out RMSE when the input is left out")
    return Explanation(ranking, result, joined, notes)

