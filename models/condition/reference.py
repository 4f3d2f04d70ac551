"""An axis's lost motion at reference conditions: its sensitivity to feed and temperature.

A visit's backlash (``features.visits.visit_backlash``) is the mean of its interior per-point
targets b_i (``features.targets.targets_of(stats, "auto")``), each measured at the feed f_i
[mm/min] of its test and the machine temperature T_i [°C] of its readings. Lost motion depends
on both (friction windup grows with feed, the nut's preload with temperature), so the series
states the lost motion at the tests' own conditions. Metrology states it at reference
conditions: 20 °C ([ISO1], [ISO230-2]) and, for the feed, the **reference feed** f_ref: the
median feed of the axis's tests (the feed the axis is usually measured at).

**Sensitivity.** Per machine axis, across its visits, the linear model

.. math:: b_i = \\alpha_{c(i)} + \\beta_f f_i + \\beta_T T_i + \\varepsilon_i

with a fixed effect α_c per cell c = (visit, target): the cell absorbs the visit's level
(wear, adjustments) and the lost motion's profile along the screw, so only the tests of one
visit at one target, run at other feeds and temperatures, inform β = (β_f [um per mm/min],
β_T [um/K]). β is the OLS estimate of the within-cell (demeaned) regression; its covariance is
the cluster-robust sandwich ([Liang1986], [Cameron2015]) with clusters = tests (the points of a
test share its run: they are not independent)

.. math::

    V(\\hat\\beta) = c \\, A^{-1} \\Big(\\sum_g X_g^\\top e_g e_g^\\top X_g\\Big) A^{-1},
    \\qquad A = X^\\top X, \\qquad c = \\frac{G}{G-1} \\frac{N-1}{N-K}

(G tests, N points, K = 2 + the cells: the CR1 small-sample factor). A condition the axis's
data cannot decide (one feed; a temperature span within cells below ``MIN_TEMP_SPAN_K``;
feed and temperature collinear, |r| > ``MAX_COLLINEARITY``; fewer than ``MIN_TESTS`` tests) is
taken from the fleet's pooled estimate (the same model over every axis of the same unit,
cells per axis: the same drive design is assumed to respond alike), and where that cannot
decide either it is not corrected.

**Correction.** The forecast line runs through the visits' values, each at its visit's mean
conditions (f̄_v, T̄_v: the means over the points its value averages). Over the visits the line
is fitted to, with mean conditions f̄, T̄, the line at reference conditions is the line plus

.. math::

    \\delta = \\beta_f (f_{ref} - \\bar f) + \\beta_T (20\\,°C - \\bar T), \\qquad
    u^2(\\delta) = d^\\top V(\\hat\\beta)\\, d, \\quad d = (f_{ref} - \\bar f,\\; 20\\,°C - \\bar T)

([GUM] 5.1.2 with the sensitivity coefficients d of the correction to β and the estimate's own
covariance, 5.2.2; the mean conditions are known exactly). u²(δ) adds to the lost-motion
interval's variance ([GUM] 6.3: a correction's uncertainty enters as a standard uncertainty).
A condition not corrected stays at the tests' own (the result says which).

References
----------
.. [ISO1] ISO 1:2022, reference temperature for geometrical product specification: 20 °C.
.. [ISO230-2] ISO 230-2:2014, 6.1: tests at or corrected to 20 °C.
.. [GUM] JCGM 100:2008, 5.1.2, 5.2.2, 6.3.
.. [Liang1986] Liang & Zeger (1986), Biometrika 73(1), 13-22.
.. [Cameron2015] Cameron & Miller (2015), "A practitioner's guide to cluster-robust
   inference", J. Human Resources 50(2), 317-372.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

REFERENCE_TEMP_C = 20.0
CONDITIONS = ("feed_mm_min", "machine_temp_c")
# The smallest within-cell temperature span [K] a temperature sensitivity is estimated from.
MIN_TEMP_SPAN_K = 0.2
# Feed and temperature more correlated than this (within cells) cannot be told apart.
MAX_COLLINEARITY = 0.95
# The fewest tests (clusters) a sensitivity is estimated from.
MIN_TESTS = 6


@dataclass(frozen=True)
class Sensitivity:
    """The lost motion's sensitivity to the conditions, with its covariance.

    ``beta``: {condition: β} [unit per mm/min, unit/K] of the conditions the data decide;
    ``cov``: their cluster-robust covariance (same order as ``beta``); ``tests``: G;
    ``points``: N; ``pooled``: from the fleet's axes of the unit rather than the axis's own.
    """

    beta: dict = field(default_factory=dict)
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    tests: int = 0
    points: int = 0
    pooled: bool = False


@dataclass(frozen=True)
class AxisReference:
    """What an axis's forecast needs to state its lost motion at reference conditions.

    ``reference``: {"temp_c": 20.0, "feed_mm_min": f_ref}; ``visits``: the mean conditions of
    each visit (index: visit; columns ``CONDITIONS``); ``feed``, ``temp``: the Sensitivity each
    condition's β comes from (None: not corrected).
    """

    reference: dict
    visits: pd.DataFrame
    feed: Sensitivity | None = None
    temp: Sensitivity | None = None

    def correction(self, visits) -> dict:
        """δ and u(δ) [unit] for a line through ``visits`` (visit ids), and the conditions
        (``corrected``) it corrects; the others stay at the tests' mean over these visits."""
        found = self.visits.reindex(list(visits))[list(CONDITIONS)]
        mean = found.mean()
        # a visit without laser tests (a trace day): its conditions are unknown, so is the
        # line's mean
        known = bool(found.notna().all(axis=None))
        ref = {"feed_mm_min": self.reference["feed_mm_min"], "machine_temp_c": REFERENCE_TEMP_C}
        delta, corrected, distance = 0.0, [], {}  # distance: {id(sensitivity): (sens, {n: d})}
        for name, sens in (("feed_mm_min", self.feed), ("machine_temp_c", self.temp)):
            d = ref[name] - float(mean[name])
            if not known or not np.isfinite(d):
                continue
            if d == 0.0:  # at reference already (one feed: the median is that feed)
                corrected.append(name)
                continue
            if sens is None:
                continue
            corrected.append(name)
            delta += sens.beta[name] * d
            distance.setdefault(id(sens), (sens, {}))[1][name] = d
        # d^T V d per fit, so that the covariance of two sensitivities from one fit counts;
        # the axis's own fit and the fleet's pooled one are taken as independent
        var = 0.0
        for sens, d in distance.values():
            dv = np.array([d.get(n, 0.0) for n in sens.beta])
            var += float(dv @ sens.cov @ dv)
        return {"correction_um": delta, "correction_u_um": float(np.sqrt(var)),
                "corrected": corrected, "reason": None if known else "visits",
                "tests_mean": {k: (None if not np.isfinite(v) else float(v))
                               for k, v in mean.items()}}


def point_conditions(readings: pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """The points a visit's backlash averages (its interior ones; all of a visit without
    any), each with the mean ``machine_temp_c`` [°C] of the readings at its keys (both tests of
    a ``paper`` pair, every test of an ``iso`` point) and its ``feed_mm_min`` [mm/min];
    ``test``: the test (pair) it belongs to, the cluster."""
    from features.targets import POINT_KEYS
    from features.visits import VISIT_KEYS

    keys = list(POINT_KEYS)
    group = points.groupby(list(VISIT_KEYS), sort=False, dropna=False, observed=True)
    used = points[points["interior"] | ~group["interior"].transform("any")]
    used = used[[*keys, "backlash_um"]].copy()
    if "machine_temp_c" in readings:
        temp = (readings.assign(**{k: readings[k].astype(used[k].dtype) for k in keys
                                   if k in readings and k in used})
                .groupby(keys, dropna=False, observed=True)["machine_temp_c"].mean())
        used = used.merge(temp.reset_index(), on=keys, how="left")
    else:
        used["machine_temp_c"] = np.nan
    pair = [k for k in keys if k != "target"]
    used["test"] = used.groupby(pair, dropna=False, observed=True, sort=False).ngroup()
    return used


def _within(frame: pd.DataFrame, cells: list[str], columns: list[str]) -> pd.DataFrame:
    return frame[columns] - frame.groupby(cells, observed=True, dropna=False)[columns].transform(
        "mean")


def sensitivity(points: pd.DataFrame, cells: list[str]) -> Sensitivity:
    """The cluster-robust fit of the module docstring over ``points`` (``point_conditions``
    rows) with a fixed effect per ``cells``; only the conditions the data decide are fitted
    (none: an empty Sensitivity)."""
    p = points.dropna(subset=["backlash_um", "feed_mm_min"])
    if p["test"].nunique() < MIN_TESTS:
        return Sensitivity()
    cols = ["backlash_um", "feed_mm_min", "machine_temp_c"]
    w = _within(p, cells, cols)
    names = []
    if np.ptp(w["feed_mm_min"].to_numpy(float)) > 0:
        names.append("feed_mm_min")
    temp = w["machine_temp_c"].to_numpy(float)
    if np.isfinite(temp).all() and np.ptp(temp) >= MIN_TEMP_SPAN_K:
        names.append("machine_temp_c")
    if len(names) == 2:
        r = np.corrcoef(w["feed_mm_min"], w["machine_temp_c"])[0, 1]
        if not np.isfinite(r) or abs(r) > MAX_COLLINEARITY:
            # collinear: neither can be told from the other, and the feed alone would carry
            # the temperature's effect
            return Sensitivity()
    if not names:
        return Sensitivity()
    x, y = w[names].to_numpy(float), w["backlash_um"].to_numpy(float)
    a_inv = np.linalg.inv(x.T @ x)
    beta = a_inv @ x.T @ y
    e = y - x @ beta
    scores = pd.DataFrame(x * e[:, None]).groupby(p["test"].to_numpy()).sum().to_numpy()
    g, n = len(scores), len(y)
    k = len(names) + p.groupby(cells, observed=True, dropna=False).ngroups
    c = g / (g - 1) * (n - 1) / max(n - k, 1)
    cov = c * a_inv @ (scores.T @ scores) @ a_inv
    return Sensitivity(dict(zip(names, beta.tolist())), cov, g, n)


def reference_corrections(readings: pd.DataFrame, points: pd.DataFrame
                          ) -> dict[tuple[str, str], AxisReference]:
    """Each machine axis's ``AxisReference``: its reference feed, its visits' mean
    conditions and the sensitivities (its own, else its unit's fleet-pooled; module
    docstring).

    Parameters
    ----------
    readings : DataFrame
        Validated readings with ``feed_mm_min`` [mm/min] and ``machine_temp_c`` [°C].
    points : DataFrame
        The per-point targets of the readings, ``features.targets.targets_of(per_target(
        readings), "auto")``, as the visits' values were computed from.

    Returns
    -------
    dict
        {(machine_id, axis): AxisReference}.
    """
    return references_of(point_conditions(readings, points))


def references_of(cond: pd.DataFrame) -> dict[tuple[str, str], AxisReference]:
    """``reference_corrections`` from the points' conditions (``point_conditions``)."""
    from features.readings.schema import deviation_unit

    cells = ["machine_id", "axis", "visit", "target"]
    cond = cond.assign(machine_id=cond["machine_id"].astype(str), axis=cond["axis"].astype(str),
                       visit=cond["visit"].astype(str))
    units = cond["axis"].map(deviation_unit)
    pooled = {u: dataclasses.replace(sensitivity(cond[units == u], cells), pooled=True)
              for u in units.unique()}
    out = {}
    for (machine, axis), mine in cond.groupby(["machine_id", "axis"], sort=True):
        own = sensitivity(mine, cells)
        fleet = pooled[deviation_unit(axis)]
        chosen = {}
        for name in CONDITIONS:
            if name in own.beta:
                chosen[name] = own
            elif name in fleet.beta:
                chosen[name] = fleet
        tests = mine.drop_duplicates("test")
        out[(machine, axis)] = AxisReference(
            {"temp_c": REFERENCE_TEMP_C,
             "feed_mm_min": float(np.median(tests["feed_mm_min"].dropna()))},
            mine.groupby("visit")[list(CONDITIONS)].mean(),
            chosen.get("feed_mm_min"), chosen.get("machine_temp_c"))
    return out
