"""Conditional influence of each input on backlash, given the others: driver, proxy or none.

The marginal views of ``features.ranking`` (the paper's ANOVA -ln p and weighted k-NN, seed 004
Fig. 14 / Table 5) measure *association*. In a test plan inputs move together (run order,
visits, warm-up with feed), so an input with no physical path can score high and a real driver
can hide behind a larger one. This module decides per input, given the others:

``driver``
    the input has a physical path to lost motion (an effect record of kind ``lost_motion``
    lists it among its inputs, or operating hours through wear) **and** its partial F-test in
    the effect model is significant. It gets its effect [um] over the observed range with a
    bootstrap interval.
``proxy``
    the input is associated with backlash but has no path of its own (or its path is not
    significant given the others): it stands in for a named driver (``proxy_for``, e.g.
    humidity that follows feed in the run order), for the ``visit`` or ``run`` (it changed only
    between them), or for ``backlash_um`` itself (the deviations the target is computed from).
``none``
    no association, and no influence given the others.
``undecided``
    the design cannot test it (no residual degrees of freedom left, or it is aliased with
    another input); the separating test in the design diagnostics says what would.

An input without a physical path is never a driver, whatever its score.

Effect model (linear in parameters, split-plot strata)
------------------------------------------------------
Points are nested in runs (a linear/pendulum pair at one feed, dwell and repeat), runs in
visits, visits in units (machine and axis). An input is tested in every stratum that holds at
least ``MIN_SHARE`` of its variance, against the error of that stratum (classical split-plot
analysis): within runs (run fixed effects; position, warm-up), between runs within visits (run
means, visit fixed effects; feed, conditions of the run), between visits within units (visit
means, unit fixed effects; operating hours). Each input enters as Legendre polynomials of degree
1..``MAX_DEGREE`` over its observed range, the degree chosen by BIC. The partial F-test of input
j compares the stratum model with and without j:

.. math::

    F = \\frac{(RSS_{-j} - RSS) / d_j}{RSS / (n_{cells} - n_{blocks} - p)}

and the input's p-value is the smallest over its strata times their number (Bonferroni).
Drivers are tested within the *physics model* (the inputs with a path only); an input without
a path is tested by adding it to the physics model. The effect [um] is the peak-to-peak of the
fitted partial effect over the observed values; its interval is the 2.5-97.5 % percentile of a
bootstrap that resamples the stratum's cells (points, runs or visits) within their blocks, or,
where the stratum has too few cells for that, of draws from the coefficients' t distribution.

A second, non-parametric opinion (``dropcolumn_importance``): the increase of the
cross-validated RMSE [um] of a gradient boosting regressor when the input is dropped, with
folds grouped by visit (or run).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings.errors import InputError

ALPHA = 0.01                 # family-wise level of the partial F-test per input
MIN_SHARE = 0.10             # share of an input's variance a stratum needs to test it there
                             # (above what run-to-run scatter leaves in visit means by chance)
MAX_DEGREE = 4               # largest polynomial degree of one input's partial effect
FEW_CELLS = 12               # below this many cells (beyond blocks) the interval is parametric
MIN_RESIDUAL_DF = 3          # a higher degree needs this many and twice its parameters left
LEVELS = ("point", "run", "visit", "unit")
VERDICTS = ("driver", "proxy", "none", "undecided")
# Inputs the backlash target is computed from: they carry its measurement noise.
TARGET_DERIVED = ("deviation_down_um", "deviation_up_um")
CONFOUNDED_R = 0.7           # |correlation| over the design above which two inputs are confounded
WEAR = "operating_hours"
WEAR_READING = ("wear of screw and nut with running time since the last adjustment opens the "
                "clearance")
LABELS = {
    "target": "Position", "deviation_down_um": "Negative-direction deviation",
    "deviation_up_um": "Positive-direction deviation", "feed_mm_min": "Feed rate",
    "machine_temp_c": "Machine temperature", "ambient_temp_c": "Ambient temperature",
    "pressure_hpa": "Atmospheric pressure", "humidity_pct": "Air humidity",
    "dwell_s": "Dwell time", "operating_hours": "Operating hours",
}


# --- physical paths from the effect records -------------------------------------------------

@dataclass(frozen=True)
class Path:
    """How an input can act: effects on lost motion (``paths``) and on the measured position
    only (``position``), each with its physical reading."""

    paths: tuple[tuple[str, str], ...]      # (effect name, reading)
    position: tuple[tuple[str, str], ...]   # (effect name, reading)


def effect_paths(inputs) -> dict[str, Path]:
    """Per input: the lost-motion effects that read it (a physical path to backlash) and the
    position effects that read it (a path to the measured position only).

    Source: ``models.physics.effects.RECORDS`` (``kind``, ``inputs``, ``reading``). Operating
    hours act through wear of screw and nut (the twin's ``wear_um_per_1000h``) unless a record
    already lists them.
    """
    found = {name: ([], []) for name in inputs}
    for name, kind, needs, reading in _records():
        reading = reading.strip().rstrip(".")
        for used in needs:
            if used in found:
                found[used][0 if kind == "lost_motion" else 1].append((name, reading))
    if WEAR in found and not found[WEAR][0]:
        found[WEAR][0].append(("wear", WEAR_READING))
    return {k: Path(tuple(lost), tuple(pos)) for k, (lost, pos) in found.items()}


def _records():
    """(name, kind, inputs, reading) of every effect record."""
    from models.physics.effects import RECORDS

    return [(r.name, r.kind, tuple(r.inputs), r.reading) for r in RECORDS.values()]


# --- design: strata, variance shares, confounding -------------------------------------------

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


def _nested(groups: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
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
    means = {lev: _group_mean(values, labels[lev]) for lev in ("point", "run", "visit", "unit",
                                                               "all")}
    chain = ("point", "run", "visit", "unit", "all")
    ss = {lev: ((means[a] - means[b]) ** 2).sum(axis=0)
          for lev, (a, b) in zip(LEVELS, itertools.pairwise(chain), strict=True)}
    table = pd.DataFrame(ss, index=X.columns)
    total = table.sum(axis=1)
    return table.div(total.where(total > 0), axis=0).fillna(0.0)


def _group_mean(values: np.ndarray, codes: np.ndarray) -> np.ndarray:
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

    def to_json(self) -> dict:
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


# --- the effect model in strata -------------------------------------------------------------

def legendre_basis(x: np.ndarray, lo: float, hi: float, degree: int) -> np.ndarray:
    """Legendre polynomials P_1..P_degree of x mapped from [lo, hi] to [-1, 1]."""
    t = 2.0 * (np.asarray(x, float) - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros(len(x))
    return np.polynomial.legendre.legvander(t, degree)[:, 1:]


@dataclass
class Stratum:
    """Cell means of one level with their blocks (the next level up, as fixed effects)."""

    level: str
    y: np.ndarray                # cell means of backlash [um]
    X: pd.DataFrame              # cell means of the inputs
    blocks: np.ndarray           # block label of each cell
    inputs: tuple[str, ...]      # inputs holding >= MIN_SHARE of their variance here

    @property
    def n(self) -> int:
        return len(self.y)

    @property
    def n_blocks(self) -> int:
        return int(np.unique(self.blocks).size)


def strata(X: pd.DataFrame, y: np.ndarray, labels: dict, shares: pd.DataFrame) -> list[Stratum]:
    """One ``Stratum`` per level with more cells than blocks."""
    chain = ("point", "run", "visit", "unit", "all")
    out = []
    for level, up in itertools.pairwise(chain):
        cells = labels[level]
        n_cells = int(cells.max() + 1)
        first = np.unique(cells, return_index=True)[1]
        blocks = pd.factorize(labels[up][first])[0]
        if n_cells - np.unique(blocks).size < 1:
            continue
        frame = pd.DataFrame(X.to_numpy(float), columns=X.columns).groupby(cells).mean()
        ymean = pd.Series(y).groupby(cells).mean().to_numpy()
        name = "point" if n_cells == len(X) else level
        inputs = tuple(c for c in X.columns if shares.loc[c, name] >= MIN_SHARE)
        out.append(Stratum(name, ymean, frame.reset_index(drop=True), blocks, inputs))
    return out


def _demean(A: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    return A - _group_mean(A, blocks) if A.size else A


@dataclass
class StratumFit:
    rss: float
    df: int
    coef: dict                   # input -> coefficients of its basis
    degree: dict                 # input -> degree


def fit_stratum(s: Stratum, degrees: dict, ranges: dict, rows=None) -> StratumFit:
    """Least squares of the cell means on the inputs' bases with block fixed effects."""
    rows = np.arange(s.n) if rows is None else rows
    names = list(degrees)
    parts = [legendre_basis(s.X[c].to_numpy()[rows], *ranges[c], degrees[c]) for c in names]
    design = np.hstack(parts) if parts else np.empty((len(rows), 0))
    blocks = s.blocks[rows]
    yd = _demean(s.y[rows, None], blocks)[:, 0]
    Ad = _demean(design, blocks)
    n_blocks = int(np.unique(blocks).size)
    if Ad.shape[1]:
        # normal equations: the design is tall and narrow, its columns bounded on [-1, 1]
        beta, _, rank, _ = np.linalg.lstsq(Ad.T @ Ad, Ad.T @ yd, rcond=1e-10)
        resid = yd - Ad @ beta
    else:
        beta, rank, resid = np.empty(0), 0, yd
    coef, start = {}, 0
    for c in names:
        coef[c] = beta[start:start + degrees[c]]
        start += degrees[c]
    return StratumFit(float(resid @ resid), len(rows) - n_blocks - rank, coef, dict(degrees))


def _bic(fit: StratumFit, n: int) -> float:
    p = n - fit.df
    return n * np.log(max(fit.rss, 1e-300) / n) + p * np.log(n)


def max_degree(s: Stratum, name: str) -> int:
    return int(max(1, min(MAX_DEGREE, s.X[name].round(9).nunique() - 1)))


def choose_degrees(s: Stratum, names, ranges, fixed: dict | None = None) -> dict:
    """Degree per input by BIC, coordinate-wise (two passes), starting from straight lines."""
    degrees = {**(fixed or {}), **{c: 1 for c in names}}
    for _ in range(2):
        for c in names:
            best = None
            for d in range(1, max_degree(s, c) + 1):
                trial = {**degrees, c: d}
                fit = fit_stratum(s, trial, ranges)
                if fit.df < max(MIN_RESIDUAL_DF, 2 * (s.n - s.n_blocks - fit.df)):
                    break  # too few cells for this many parameters: BIC would overfit
                bic = _bic(fit, s.n)
                if best is None or bic < best[0] - 1e-9:
                    best = (bic, d)
            if best is not None:
                degrees[c] = best[1]
    return degrees


def partial_f(s: Stratum, degrees: dict, name: str, ranges: dict) -> tuple[float, float, int]:
    """Partial F-test of ``name`` in the stratum model: (F, p, residual df). p is NaN when the
    design leaves no residual degree of freedom or the input adds no column of its own."""
    from scipy import stats

    full = fit_stratum(s, degrees, ranges)
    reduced = fit_stratum(s, {k: v for k, v in degrees.items() if k != name}, ranges)
    d = reduced.df - full.df
    if full.df < 1 or d < 1:
        return np.nan, np.nan, full.df
    if full.rss <= 1e-24:
        return np.inf, 0.0, full.df
    F = ((reduced.rss - full.rss) / d) / (full.rss / full.df)
    return float(F), float(stats.f.sf(F, d, full.df)), full.df


def partial_effect(coef: np.ndarray, degree: int, values: np.ndarray, lo: float,
                   hi: float) -> np.ndarray:
    """f_j at ``values`` [um] (zero mean is not imposed: only differences matter)."""
    return legendre_basis(values, lo, hi, degree) @ coef


def _grid(x: np.ndarray) -> np.ndarray:
    u = np.unique(x)
    return u if u.size <= 200 else np.quantile(x, np.linspace(0, 1, 200))


def _shape(f: np.ndarray) -> str:
    if f.size < 2 or np.ptp(f) == 0:
        return "flat"
    i, j = int(np.argmax(f)), int(np.argmin(f))
    if 0 < i < f.size - 1 and f[i] - max(f[0], f[-1]) > 0.25 * np.ptp(f):
        return "peaks inside the range"
    if 0 < j < f.size - 1 and min(f[0], f[-1]) - f[j] > 0.25 * np.ptp(f):
        return "dips inside the range"
    return "increases" if f[-1] > f[0] else "decreases"


# --- the verdicts ---------------------------------------------------------------------------

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
    labels = _nested(design_groups(meta, len(X)), len(X))
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

    effects = _effects(table, layers, ranges, X, n_boot, rng)
    table = table.join(effects)
    assoc = (association.reindex(table.index).fillna(False).astype(bool)
             if association is not None else pd.Series(False, index=table.index))
    verdicts = [_verdict(c, table.loc[c], assoc[c], alpha) for c in table.index]
    table["verdict"] = [v for v, _ in verdicts]
    table["proxy_for"] = [p for _, p in verdicts]
    table["proxy_for"] = pd.Series(_proxy_targets(table, layers, X, fits, ranges),
                                   index=table.index, dtype=object)
    table["association"] = assoc
    if dropcolumn is not None:
        table = table.join(dropcolumn)
    table["physical_reading"] = [physical_reading(c, table.loc[c], paths[c], design)
                                 for c in table.index]
    table.insert(0, "label", [LABELS.get(c, c) for c in table.index])
    order = {"driver": 0, "proxy": 1, "undecided": 2, "none": 3}
    table = table.assign(_o=table["verdict"].map(order), _e=-table["effect_um"].fillna(0))
    table = table.sort_values(["_o", "_e"], kind="stable").drop(columns=["_o", "_e"])
    table.index.name = "feature"
    notes = [(f"partial F-tests in the effect model by stratum, family-wise level {alpha:g} per "
              f"input; effect intervals from {n_boot} bootstrap resamples of the stratum's cells")]
    return Influence(table, design, alpha, n_boot, notes)


def stratum_tests(layers, inputs, physics, ranges) -> tuple[dict, dict]:
    """Per input and stratum: (p given the others, level, residual df, degrees) and the
    marginal p (block fixed effects only). Inputs with a path are tested in the physics model,
    the others by adding them to it. Also returns the physics degrees per level."""
    rows = {c: {"p": [], "p_marg": []} for c in inputs}
    fits = {}
    for s in layers:
        phys = [c for c in physics if c in s.inputs]
        degrees = choose_degrees(s, phys, ranges)
        fits[s.level] = degrees
        for c in s.inputs:
            model = degrees if c in phys else choose_degrees(s, [c], ranges, fixed=degrees)
            _, p, df = partial_f(s, model, c, ranges)
            rows[c]["p"].append((p, s.level, df, model))
            alone = choose_degrees(s, [c], ranges)
            rows[c]["p_marg"].append(partial_f(s, alone, c, ranges)[1])
    return rows, fits


def combine_strata(row: dict) -> dict:
    """Smallest p over the strata that could test the input, times their number
    (Bonferroni), and the stratum that gave it."""
    tested = [t for t in row["p"] if np.isfinite(t[0])]
    best = min(tested, key=lambda t: t[0]) if tested else None
    marg = [p for p in row["p_marg"] if np.isfinite(p)]
    return {"p_value": min(1.0, best[0] * len(tested)) if best else np.nan,
            "p_marginal": min(1.0, min(marg) * len(marg)) if marg else np.nan,
            "tested": best[1] if best else None, "df": best[2] if best else 0,
            "degrees": best[3] if best else None}


def _effects(table, layers, ranges, X, n_boot, rng) -> pd.DataFrame:
    """Peak-to-peak effect [um] over the observed range at the stratum that tested the input,
    with a percentile interval from resampling that stratum's cells within their blocks (one
    refit per resample serves every input tested with the same model). With fewer than
    ``FEW_CELLS`` cells beyond the blocks a resample repeats the same few cells, so the
    coefficients are drawn from their multivariate t distribution instead (parametric
    bootstrap with the stratum's residual degrees of freedom)."""
    by_level = {s.level: s for s in layers}
    models = {}
    for c, row in table.iterrows():
        if isinstance(row["tested"], str):
            key = (row["tested"], tuple(sorted(row["degrees"].items())))
            models.setdefault(key, []).append(c)
    out = {c: (np.nan, np.nan, np.nan, "") for c in table.index}
    for (level, items), names in models.items():
        s, degrees = by_level[level], dict(items)
        grids = {c: _grid(X[c].to_numpy()) for c in names}

        def effects(cells=None, s=s, degrees=degrees, grids=grids, names=names):
            fit = fit_stratum(s, degrees, ranges, cells)
            return {c: partial_effect(fit.coef[c], degrees[c], grids[c], *ranges[c])
                    for c in names}

        point = effects()
        if s.n - s.n_blocks >= FEW_CELLS:
            boot = [{c: np.ptp(f) for c, f in effects(_resample_within(s.blocks, rng)).items()}
                    for _ in range(n_boot)]
        else:
            boot = [{c: np.ptp(partial_effect(coef[c], degrees[c], grids[c], *ranges[c]))
                     for c in names} for coef in _coef_draws(s, degrees, ranges, n_boot, rng)]
        for c in names:
            lo, hi = (np.percentile([b[c] for b in boot], [2.5, 97.5]) if boot
                      else (np.nan, np.nan))
            out[c] = (float(np.ptp(point[c])), float(lo), float(hi), _shape(point[c]))
    return pd.DataFrame.from_dict(out, orient="index",
                                  columns=["effect_um", "effect_low_um", "effect_high_um",
                                           "effect_shape"])


def _coef_draws(s: Stratum, degrees: dict, ranges: dict, n: int, rng) -> list[dict]:
    """``n`` coefficient sets beta + L z sqrt(df / chi2_df), L L^T = s^2 (A^T A)^-1."""
    fit = fit_stratum(s, degrees, ranges)
    names = list(degrees)
    design = np.hstack([legendre_basis(s.X[c].to_numpy(), *ranges[c], degrees[c])
                        for c in names])
    A = _demean(design, s.blocks)
    if fit.df < 1 or not n:
        return []
    cov = fit.rss / fit.df * np.linalg.pinv(A.T @ A)
    beta = np.concatenate([fit.coef[c] for c in names])
    z = rng.multivariate_normal(np.zeros(beta.size), cov, size=n, method="eigh")
    draws = beta + z * np.sqrt(fit.df / rng.chisquare(fit.df, size=(n, 1)))
    edges = np.cumsum([0] + [degrees[c] for c in names])
    return [{c: d[a:b] for c, a, b in zip(names, edges[:-1], edges[1:], strict=True)}
            for d in draws]


def _resample_within(blocks: np.ndarray, rng) -> np.ndarray:
    """Cells drawn with replacement within each block (the block sizes kept)."""
    order = np.argsort(blocks, kind="stable")
    sizes = np.bincount(blocks)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    draw = (starts[blocks[order]] + np.floor(rng.random(len(blocks)) * sizes[blocks[order]])
            .astype(int))
    return order[draw]


def _verdict(name, row, associated, alpha) -> tuple[str, str | None]:
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


def _proxy_targets(table, layers, X, fits, ranges) -> list:
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
            x = _demean(s.X[[c]].to_numpy(), s.blocks)[:, 0]
            for d in drivers:
                if d == c or d not in s.inputs:
                    continue
                deg = fits.get(level, {}).get(d, 1)
                basis = _demean(legendre_basis(s.X[d].to_numpy(), *ranges[d], deg), s.blocks)
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


# --- physical reading -----------------------------------------------------------------------

def physical_reading(name: str, row: pd.Series, path: Path, design: Design) -> str:
    """One or two sentences: the verdict and the physics behind it, from the effect records."""
    label = LABELS.get(name, name)
    verdict, proxy = row["verdict"], row["proxy_for"]
    via = "; ".join(f"{n}: {r}" for n, r in path.paths)
    position = "; ".join(f"{n}: {r}" for n, r in path.position)
    where = LEVEL_WORDS.get(row["level"], "")
    if verdict == "driver":
        interval = f"{row['effect_low_um']:.2f}-{row['effect_high_um']:.2f}"
        return (f"{label} drives backlash: {row['effect_um']:.2f} um over the observed range "
                f"(95 % interval {interval} um, {row['effect_shape']}), given the other inputs "
                f"({_p_text(row['p_value'])}, tested {LEVEL_WORDS[row['tested']]}). "
                f"Physical path: {via}.")
    if verdict == "undecided":
        return (f"{label} cannot be decided in this design: it varies only {where} and leaves "
                "no residual degrees of freedom there; " + _separation(name, design))
    if verdict == "proxy":
        if proxy == "backlash_um":
            return (f"{label} stands in for the backlash itself: the target is computed from "
                    "the same linear test, so the input carries the target's own measurement "
                    "(and the position-dependent errors of the axis), not a cause.")
        if proxy in ("visit", "run"):
            text = (f"{label} stands in for the {proxy}: it changed only {where}, so its "
                    f"association measures whatever else changed between {proxy}s, not an "
                    "effect of its own")
        elif proxy:
            text = (f"{label} follows {LABELS.get(proxy, proxy).lower()} in this test plan, "
                    f"and its association with backlash is that of "
                    f"{LABELS.get(proxy, proxy).lower()}")
        else:
            text = (f"{label} carries structure that the recorded effects do not explain; an "
                    "effect missing from the model may follow it (backlash discover)")
        if path.paths:
            text += f" (its own path, {via}, is not significant given the others)"
        elif position:
            text += f". It acts on the measured position only: {position}"
        else:
            text += ". No effect record gives it a path to lost motion"
        return text + "."
    if path.paths:
        return (f"{label} has no measurable influence given the other inputs "
                f"({_p_text(row['p_value'])}; effect at most {row['effect_high_um']:.2f} um "
                f"over the observed range). Possible path: {via}.")
    tail = f" It acts on the measured position only: {position}." if position else \
        " No effect record gives it a path to lost motion."
    return f"{label} has no measurable influence on backlash.{tail}"


def _p_text(p) -> str:
    if not np.isfinite(p):
        return "p n/a"
    return f"p = {p:.2g}" if p >= 1e-4 else "p < 1e-4"


def _separation(name: str, design: Design) -> str:
    tests = sorted((c for c in design.confounded if name in c["inputs"]),
                   key=lambda c: "visit" not in c["inputs"])
    return tests[0]["separating_test"] + "." if tests else \
        "vary it independently of the other inputs."


# --- non-parametric check: drop-column importance of gradient boosting -----------------------

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
    labels = _nested(design_groups(meta, len(X)), len(X))
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


# --- association and influence together: what ``backlash rank`` reports ----------------------

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

    def to_json(self) -> dict:
        """``features.ranking.Ranking.to_json`` plus, per feature, ``verdict``, ``effect_um``
        with ``effect_interval_um``, ``proxy_for`` and the conditional tests; ``rank`` is the
        verdict order, ``association_rank`` the marginal views' rank; ``design`` holds the
        diagnostics."""
        base = self.ranking.to_json()
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
                    design=self.influence.design.to_json(), notes=[*base["notes"], *self.notes])
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
                            source=source)
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
