"""The design: runs, visits and units, where each input varies, how inputs move together
and the measurement that would separate them."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from models.influence.paths import LABELS, TARGET_DERIVED

LEVELS = ("point", "run", "visit", "unit")
CONFOUNDED_R = 0.7           # |correlation| over the design above which two inputs are confounded


def design_groups(meta: pd.DataFrame | None, n: int) -> dict[str, np.ndarray]:
    """Integer labels of the run, visit and unit of each point, from the feature-table keys.

    A run is one linear/pendulum pair (machine, axis, visit, feed, dwell, repeat); a visit is
    machine, axis and visit; a unit is machine and axis. Missing keys count as equal.
    """
    if meta is None:
        zeros = np.zeros(n, dtype=int)
        return {"run": np.arange(n), "visit": zeros, "unit": zeros}
    meta = meta.reset_index(drop=True)

    def codes(keys):
        keys = [k for k in keys if k in meta]
        if not keys:
            return np.zeros(n, dtype=int)
        return meta.groupby(keys, dropna=False, sort=False).ngroup().to_numpy()

    unit = ("machine_id", "axis")
    return {"run": codes((*unit, "visit", "feed_mm_min", "dwell_s", "repeat")),
            "visit": codes((*unit, "visit")), "unit": codes(unit)}


def nested_labels(groups: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """Labels per level, each level nested in the next (a run never spans two visits)."""
    def within(inner, outer):
        return pd.factorize(np.asarray(inner, np.int64) * (int(outer.max()) + 1) + outer)[0]

    point = np.arange(n)
    unit = pd.factorize(groups["unit"])[0]
    visit = within(groups["visit"], unit)
    run = within(groups["run"], visit)
    return {"point": point, "run": run, "visit": visit, "unit": unit,
            "all": np.zeros(n, dtype=int)}


def variance_shares(X: pd.DataFrame, labels: dict[str, np.ndarray]) -> pd.DataFrame:
    """Share of each input's sum of squares at each level: within runs (``point``), between runs
    within visits (``run``), between visits within units (``visit``), between units (``unit``).
    Rows sum to 1."""
    values = X.to_numpy(float)
    means = {lev: group_mean(values, labels[lev]) for lev in ("point", "run", "visit", "unit",
                                                               "all")}
    chain = ("point", "run", "visit", "unit", "all")
    ss = {lev: ((means[a] - means[b]) ** 2).sum(axis=0)
          for lev, (a, b) in zip(LEVELS, itertools.pairwise(chain), strict=True)}
    table = pd.DataFrame(ss, index=X.columns)
    total = table.sum(axis=1)
    return table.div(total.where(total > 0), axis=0).fillna(0.0)


def group_mean(values: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Each row replaced by the mean of its group (same shape as ``values``)."""
    size = int(codes.max()) + 1
    counts = np.bincount(codes, minlength=size)
    sums = np.column_stack([np.bincount(codes, weights=values[:, j], minlength=size)
                            for j in range(values.shape[1])])
    return (sums / counts[:, None])[codes]


@dataclass
class Design:
    """Where each input varies, how inputs move together, and what would separate them."""

    shares: pd.DataFrame                 # input x level: share of its variance
    level: pd.Series                     # level holding most of its variance
    correlation: pd.DataFrame            # over the design (points)
    counts: dict                         # number of runs, visits, units
    confounded: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"counts": self.counts,
                "varies": {name: {"level": self.level[name],
                                  "shares": {k: float(v) for k, v in self.shares.loc[name].items()}}
                           for name in self.shares.index},
                "correlation": {a: {b: float(self.correlation.loc[a, b])
                                    for b in self.correlation.columns}
                                for a in self.correlation.index},
                "confounded": self.confounded}


LEVEL_WORDS = {"point": "within runs", "run": "between runs", "visit": "between visits",
               "unit": "between machines/axes"}


def design_diagnostics(X: pd.DataFrame, labels: dict[str, np.ndarray]) -> Design:
    """Variance shares per level, the correlation over the design and confounded pairs with
    the test that would separate them."""
    shares = variance_shares(X, labels)
    if labels["run"].max() + 1 == len(X):  # every point its own run: no run level
        shares = shares.assign(point=shares["point"] + shares["run"], run=0.0)
    level = shares.idxmax(axis=1)
    corr = X.corr().fillna(0.0)
    counts = {"points": len(X), "runs": int(labels["run"].max() + 1),
              "visits": int(labels["visit"].max() + 1), "units": int(labels["unit"].max() + 1)}
    confounded = []
    for a, b in itertools.combinations(X.columns, 2):
        r = float(corr.loc[a, b])
        if abs(r) >= CONFOUNDED_R:
            confounded.append({"inputs": [a, b], "r": r,
                               "separating_test": separating_test(a, b, level[a], level[b])})
    for name in X.columns:
        if level[name] in ("visit", "unit") and counts["visits"] > 1:
            confounded.append({"inputs": [name, "visit"], "r": None,
                               "separating_test": separating_test(name, "visit", level[name],
                                                                  "visit")})
    return Design(shares, level, corr, counts, confounded)


def separating_test(a: str, b: str, level_a: str, level_b: str) -> str:
    """The measurement that would tell ``a`` from ``b``."""
    la, lb = LABELS.get(a, a), LABELS.get(b, b).lower() if b != "visit" else "the visit"
    if b == "visit":
        return (f"{la} changed only between visits, so it cannot be told apart from anything "
                "else that changed between them (wear, adjustments, other conditions): vary "
                "it within a visit, or record what else changed")
    if a in TARGET_DERIVED or b in TARGET_DERIVED:
        return (f"{la} and {lb} move together over this axis; the deviations are measured, "
                "not set: compare axes or machines with different error profiles")
    if level_a in ("visit", "unit") and level_b in ("visit", "unit"):
        return (f"{la} and {lb} changed together between visits: more visits in which they "
                "move independently, or a change of one of them within a visit")
    where = {"point": "along the run", "run": "from run to run", "visit": "from visit to visit",
             "unit": "between machines"}
    return (f"{la} and {lb} moved together ({where[level_a]}): add runs in which {la.lower()} "
            f"changes while {lb} is held (e.g. the same {lb} at two levels of {la.lower()}), "
            "in randomised order")

