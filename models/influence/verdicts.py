"""Driver, proxy, none or undecided per input, given the others."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.schema import unit_of
from models.influence.design import Design, design_diagnostics, design_groups, nested_labels
from models.influence.paths import LABELS, TARGET_DERIVED, effect_paths
from models.influence.prose import physical_reading
from models.influence.sizes import effect_sizes
from models.influence.strata import (
    combine_strata,
    demean,
    fit_stratum,
    legendre_basis,
    strata,
    stratum_tests,
)

ALPHA = 0.01                 # family-wise level of the partial F-test per input
VERDICTS = ("driver", "proxy", "none", "undecided")


@dataclass
class Influence:
    """Verdict per input (``table``), the design diagnostics and the method's notes."""

    table: pd.DataFrame
    design: Design
    alpha: float
    n_boot: int
    notes: list[str] = field(default_factory=list)

    def drivers(self) -> list[str]:
        t = self.table
        return list(t.index[t["verdict"] == "driver"])

    def feature_json(self, name: str) -> dict:
        r = self.table.loc[name]
        low, high = r["effect_low_um"], r["effect_high_um"]
        return {"verdict": r["verdict"], "effect_um": _num(r["effect_um"]),
                "effect_interval_um": [_num(low), _num(high)],
                "effect_shape": r["effect_shape"], "proxy_for": r["proxy_for"],
                "physical_path": list(r["physical_path"]), "p_conditional": _num(r["p_value"]),
                "p_marginal": _num(r["p_marginal"]),
                "tested": r["tested"] if isinstance(r["tested"], str) else None,
                "level": r["level"], "dropcolumn_um": _num(r.get("dropcolumn_um")),
                "dropcolumn_std_um": _num(r.get("dropcolumn_std_um")),
                "physical_reading": r["physical_reading"]}


def _num(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def conditional_influence(X: pd.DataFrame, y_um, meta: pd.DataFrame | None = None, *,
                          association: pd.Series | None = None, alpha: float = ALPHA,
                          n_boot: int = 200, random_state: int = 0,
                          dropcolumn: pd.DataFrame | None = None,
                          source: str = "features") -> Influence:
    """Driver, proxy or none per input, given the others (module docstring).

    Parameters
    ----------
    X : DataFrame
        Inputs (feature-table columns).
    y_um : array-like
        Backlash per point [um].
    meta : DataFrame, optional
        Point keys (``machine_id, axis, visit, feed_mm_min, dwell_s, repeat``) giving the runs,
        visits and units; without it every point is its own run.
    association : Series of bool, optional
        Per input: the marginal views (``features.ranking``) see an association. Such an input
        is at least a proxy even where the stratum tests find nothing of its own.
    alpha : float
        Family-wise level of each input's partial F-test.
    n_boot : int
        Bootstrap resamples of the effect interval.
    dropcolumn : DataFrame, optional
        ``dropcolumn_importance`` output, shown beside the verdicts.
    """
    y = np.asarray(y_um, dtype=float)
    if len(y) != len(X):
        raise InputError(f"{len(X)} input rows but {len(y)} backlash values", file=source)
    if not np.isfinite(y).all() or not np.isfinite(X.to_numpy(float)).all():
        raise InputError("NaN/inf in inputs or backlash: every point needs values", file=source)
    X = X.astype(float).reset_index(drop=True)
    labels = nested_labels(design_groups(meta, len(X)), len(X))
    design = design_diagnostics(X, labels)
    layers = strata(X, y, labels, design.shares)
    ranges = {c: (float(X[c].min()), float(X[c].max())) for c in X.columns}
    paths = effect_paths(X.columns)
    physics = [c for c in X.columns if paths[c].paths]
    rng = np.random.default_rng(random_state)

    rows, fits = stratum_tests(layers, list(X.columns), physics, ranges)
    records = [{"name": c, **combine_strata(rows[c])} for c in X.columns]
    table = pd.DataFrame(records).set_index("name")
    table["level"] = design.level
    table["physical_path"] = [tuple(n for n, _ in paths[c].paths) for c in table.index]

    effects = effect_sizes(table, layers, ranges, X, n_boot, rng)
    table = table.join(effects)
    assoc = (association.reindex(table.index).fillna(False).astype(bool)
             if association is not None else pd.Series(False, index=table.index))
    verdicts = [verdict(c, table.loc[c], assoc[c], alpha) for c in table.index]
    table["verdict"] = [v for v, _ in verdicts]
    table["proxy_for"] = [p for _, p in verdicts]
    table["proxy_for"] = pd.Series(proxy_targets(table, layers, X, fits, ranges),
                                   index=table.index, dtype=object)
    table["association"] = assoc
    if dropcolumn is not None:
        table = table.join(dropcolumn)
    unit = (unit_of(meta["axis"]) if meta is not None and "axis" in meta else "um")
    table["physical_reading"] = [physical_reading(c, table.loc[c], paths[c], design, unit)
                                 for c in table.index]
    table.insert(0, "label", [LABELS.get(c, c) for c in table.index])
    order = {"driver": 0, "proxy": 1, "undecided": 2, "none": 3}
    table = table.assign(_o=table["verdict"].map(order), _e=-table["effect_um"].fillna(0))
    table = table.sort_values(["_o", "_e"], kind="stable").drop(columns=["_o", "_e"])
    table.index.name = "feature"
    notes = [(f"partial F-tests in the effect model by stratum, family-wise level {alpha:g} per "
              f"input; effect intervals from {n_boot} bootstrap resamples of the stratum's cells")]
    return Influence(table, design, alpha, n_boot, notes)


def verdict(name, row, associated, alpha) -> tuple[str, str | None]:
    """Verdict and (``?`` = to be named) what a proxy stands in for. The marginal views'
    association counts on its own only for inputs that changed between visits, where the
    stratum test has few degrees of freedom; elsewhere it must survive the stratum's own
    marginal test (the views treat the points of one run as independent)."""
    significant = np.isfinite(row["p_value"]) and row["p_value"] < alpha
    marginal = np.isfinite(row["p_marginal"]) and row["p_marginal"] < alpha
    if name not in TARGET_DERIVED and row["level"] not in ("visit", "unit"):
        associated = False
    if name in TARGET_DERIVED:
        return ("proxy", "backlash_um") if (significant or marginal or associated) \
            else ("none", None)
    if row["physical_path"]:
        if significant:
            return "driver", None
        if not np.isfinite(row["p_value"]):
            return "undecided", None
        return ("proxy", "?") if (marginal or associated) else ("none", None)
    if significant:
        return "proxy", "?"
    return ("proxy", "?") if (marginal or associated) else ("none", None)


def proxy_targets(table, layers, X, fits, ranges) -> list:
    """Fill the ``?`` proxies: the driver whose fitted effect the input follows most closely at
    its stratum, or the visit/run it changed with."""
    drivers = list(table.index[table["verdict"] == "driver"])
    by_level = {s.level: s for s in layers}
    out = []
    for c, row in table.iterrows():
        if row["proxy_for"] != "?":
            out.append(row["proxy_for"] if isinstance(row["proxy_for"], str) else None)
            continue
        level = row["tested"] if isinstance(row["tested"], str) else row["level"]
        best, best_r = None, 0.0
        s = by_level.get(level)
        if s is not None:
            x = demean(s.X[[c]].to_numpy(), s.blocks)[:, 0]
            for d in drivers:
                if d == c or d not in s.inputs:
                    continue
                deg = fits.get(level, {}).get(d, 1)
                basis = demean(legendre_basis(s.X[d].to_numpy(), *ranges[d], deg), s.blocks)
                fit = fit_stratum(s, fits[level], ranges)
                f = basis @ fit.coef[d] if d in fit.coef else basis[:, 0]
                if np.std(x) > 0 and np.std(f) > 0:
                    r = abs(float(np.corrcoef(x, f)[0, 1]))
                    if r > best_r:
                        best, best_r = d, r
        if best is not None and best_r >= 0.3 and not (row["level"] in ("visit", "unit")
                                                       and best_r < 0.5):
            out.append(best)
        elif row["level"] in ("visit", "unit"):
            out.append("visit")
        elif row["level"] == "run":
            out.append("run")
        else:
            out.append(best)
    return out

