"""An axis's backlash at a maintenance visit: the series that drift monitoring follows.

One definition (docs/backlash.md), one value per machine, axis and visit:

- ``backlash_um``: the mean over the visit's interior backlash points of the per-point lost
  motion ``features.targets.backlash_targets(readings, "auto")``, each axis by its own
  measuring system: pendulum minus linear (``paper``) with a direct system (linear scale), the
  ISO reversal value |B_i| (``iso``) with an indirect one (rotary encoder) or when the visit
  has one test method only. ``target_kind`` says which, ``n_points`` how many points.
- ``backlash_u_um``: its standard uncertainty from the points' repeatability,
  ``sqrt(sum u_i²) / n``.
- with an ISO/TR 230-9 budget, ``backlash_U_um``: its expanded uncertainty, the budget's parts
  of the points (``features.targets.point_uncertainty``) with ``backlash_u_um``, and
  ``backlash_u_visit_um``, the standard uncertainty of the parts that change between visits.

Other quantities keep names of their own (``visit_backlash``): the mean signed ISO reversal
value ``reversal_mean_um`` (a direct system's linear tests hide lost motion, so with linear
and pendulum tests it reads about half the lost motion) and the mean of the tests' B = max|B_i|
``reversal_max_um``.

Time is counted in months of 30.4375 days (``DAYS_PER_MONTH``) since the first visit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.schema import AXIS_KEYS

DAYS_PER_MONTH = 30.4375
# Tests of one visit may span a few days (several shifts); more means two visits share an id.
MAX_VISIT_SPAN_DAYS = 14.0
SERIES_KEYS = AXIS_KEYS  # one drift series per machine axis
VISIT_KEYS = (*SERIES_KEYS, "visit")
VISIT_COLUMNS = (*VISIT_KEYS, "date", "n_tests", "n_points", "target_kind", "backlash_um",
                 "backlash_u_um", "reversal_mean_um", "reversal_max_um")
# Added to the visits when a budget is given (``axis_backlash``).
BUDGET_COLUMNS = ("backlash_U_um", "backlash_u_visit_um")


def axis_backlash(readings: pd.DataFrame, stats: pd.DataFrame | None = None,
                  budget=None, points: pd.DataFrame | None = None) -> pd.DataFrame:
    """The axis's backlash at each visit, with its standard uncertainty.

    b = (1/n) Σ_i b_i,   u(b) = sqrt(Σ_i u_i²) / n

    over the n interior points i of the visit (all its points when it has no interior one),
    b_i and u_i the per-point backlash and uncertainty of
    ``features.targets.backlash_targets(readings, "auto")``.

    With a budget, each point's budget uncertainty has a part systematic for one setup,
    u_setup,i (the Abbe error; zero for a ``paper`` point, where it cancels), and a part new at
    every run, u_env,i (``features.targets.point_uncertainty``). Both repeat at every point of
    a test (correlated across the points, r ≤ 1), so the visit's parts are the largest of its
    points' ([GUM] 5.2.2) and do not average down; the repeatability u(b) does. The visit's
    expanded uncertainty and the standard uncertainty of what changes between visits:

    .. math::

        U = k \\sqrt{u_{setup}^2 + u_{env}^2 + u(b)^2}, \\qquad
        u_{visit} = \\sqrt{u_{env}^2 + u(b)^2}

    For a visit of ``iso`` points this is k √((U(B)/k)² + u(b)²) with U(B) the largest of its
    tests' ([ISO230-9] through the backlash paper's Table 4, ``features.uncertainty``); with one
    setup at every visit the Abbe part cancels in the difference of two visits, so a step is
    compared with k √(u_visit,a² + u_visit,b²) (``models.condition.drift``).

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``features.readings.read_readings``).
    stats : DataFrame, optional
        ``features.iso230.per_target(readings)`` when already computed.
    budget : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget (``features.uncertainty``): adds ``BUDGET_COLUMNS``. Linear
        axes only.
    points : DataFrame, optional
        ``features.targets.targets_of(stats, "auto", source, budget, parts=True)`` when
        already computed.

    Returns
    -------
    DataFrame
        One row per (machine_id, axis, visit): ``backlash_um`` [um], ``backlash_u_um`` [um],
        ``target_kind`` ('paper', 'iso'; 'mixed' if the visit's points differ), ``n_points``
        and, with a budget, ``backlash_U_um`` [um] (k of the budget) and
        ``backlash_u_visit_um`` [um]. ``attrs`` carry the points' ``target_kind`` and
        ``target_reason`` (with a budget also ``coverage_factor``).

    Raises
    ------
    InputError
        An unreadable or non-physical budget, a budget for a rotary axis.

    References
    ----------
    .. [ISO230-9] ISO/TR 230-9:2005, basic equations of the measurement uncertainty of machine
       tool tests.
    .. [GUM] JCGM 100:2008, 5.1.2 (uncorrelated inputs) and 5.2.2 (correlated inputs).
    """
    from features import iso230
    from features.targets import BUDGET_PARTS, targets_of

    if points is None:
        stats = iso230.per_target(readings) if stats is None else stats
        points = targets_of(stats, "auto", readings.attrs.get("source", "readings"), budget,
                            parts=True)
    keys = list(VISIT_KEYS)
    group = points.groupby(keys, sort=False, dropna=False, observed=True)
    points = points[points["interior"] | ~group["interior"].transform("any")]
    g = points.assign(u2=points["backlash_u_um"] ** 2).groupby(
        keys, sort=False, dropna=False, observed=True)
    n = g.size()
    kind = g["target_kind"].first().where(g["target_kind"].nunique() < 2, "mixed")
    table = pd.DataFrame({"backlash_um": g["backlash_um"].mean(),
                          "backlash_u_um": np.sqrt(g["u2"].sum()) / n,
                          "target_kind": kind, "n_points": n})
    attrs = {k: points.attrs[k] for k in ("target_kind", "target_reason")}
    if budget is not None:
        u_setup, u_env = (g[part].max() for part in BUDGET_PARTS)
        u_r = table["backlash_u_um"].fillna(0.0)
        k = points.attrs["coverage_factor"]
        table["backlash_U_um"] = k * np.sqrt(u_setup ** 2 + u_env ** 2 + u_r ** 2)
        table["backlash_u_visit_um"] = np.hypot(u_env, u_r)
        attrs["coverage_factor"] = k
    table = table.reset_index()
    table.attrs.update(attrs)
    return table


def visit_backlash(readings: pd.DataFrame, stats: pd.DataFrame | None = None,
                   budget=None, points: pd.DataFrame | None = None,
                   figures: pd.DataFrame | None = None) -> pd.DataFrame:
    """The visit series of every machine axis: its backlash (``axis_backlash``) per visit,
    dated, with the ISO reversal figures under their own names.

    Parameters
    ----------
    readings : DataFrame
        Validated readings with ``visit`` and ``started_at``.
    stats : DataFrame, optional
        ``features.iso230.per_target(readings)`` when already computed.
    budget : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget: the visits also get ``BUDGET_COLUMNS`` (``axis_backlash``).
    points, figures : DataFrame, optional
        The points of ``axis_backlash`` and ``features.iso230.axis_figures(readings, stats)``
        when already computed.

    Returns
    -------
    DataFrame
        One row per (machine_id, axis, visit) sorted by date, columns ``VISIT_COLUMNS``:
        ``date`` (earliest ``started_at``, UTC), ``n_tests``, ``n_points``, ``target_kind``,
        ``backlash_um`` [um] and ``backlash_u_um`` [um] (``axis_backlash``),
        ``reversal_mean_um`` (mean over the tests of their mean signed B_i) [um] and
        ``reversal_max_um`` (mean over the tests of B = max|B_i|) [um]. ``attrs`` carry
        ``target_kind`` and ``target_reason``. With a budget also ``BUDGET_COLUMNS`` [um] and
        ``attrs["coverage_factor"]``.

    Raises
    ------
    InputError
        Missing dates, a visit id spanning weeks, two visits at one instant, no axis with
        two visits, or a bad budget (``axis_backlash``).
    """
    from features import iso230

    source = readings.attrs.get("source", "readings")
    check_dates(readings, source)
    keys = list(VISIT_KEYS)
    if stats is None and (points is None or figures is None):
        stats = iso230.per_target(readings)
    figures = iso230.axis_figures(readings, stats) if figures is None else figures
    backlash = axis_backlash(readings, stats, budget, points)
    dates = readings.groupby(keys, sort=False, observed=True)["started_at"].min()
    reversal = figures.groupby(keys, sort=False).agg(
        n_tests=("test_id", "size"), reversal_mean_um=("B_mean", "mean"),
        reversal_max_um=("B", "mean"))
    table = (reversal.join(dates.rename("date")).reset_index()
             .merge(backlash, on=keys, how="left", validate="one_to_one"))
    table = table.sort_values([*SERIES_KEYS, "date"], kind="stable").reset_index(drop=True)
    check_visits(table, source)
    table = table[[*VISIT_COLUMNS, *(BUDGET_COLUMNS if budget is not None else ())]]
    table.attrs.update(backlash.attrs)
    return table


def check_dates(readings: pd.DataFrame, source: str = "readings") -> None:
    """Every test needs a ``started_at`` date, and one visit may not span weeks."""
    if "started_at" not in readings.columns:
        raise InputError("drift needs visit dates: no column 'started_at'", file=source,
                         column="started_at")
    missing = readings["started_at"].isna().to_numpy()
    if missing.any():
        i = int(np.argmax(missing))
        raise InputError("drift needs a date on every test: 'started_at' is empty "
                         f"(visit {readings['visit'].iloc[i]!r}, test "
                         f"{readings['test_id'].iloc[i]!r})", file=source, column="started_at")
    span = readings.groupby([*SERIES_KEYS, "visit"], observed=True)["started_at"].agg(
        ["min", "max"])
    days = (span["max"] - span["min"]).dt.total_seconds() / 86400.0
    if (days > MAX_VISIT_SPAN_DAYS).any():
        (machine, axis, visit), d = next(iter(days[days > MAX_VISIT_SPAN_DAYS].items()))
        raise InputError(f"visit {visit!r} of {machine} axis {axis} has tests {d:.0f} days "
                         f"apart (at most {MAX_VISIT_SPAN_DAYS:.0f}): one visit id used for "
                         "two visits? give each visit its own id", file=source, column="visit")


def check_visits(table: pd.DataFrame, source: str = "readings") -> None:
    """Two visit ids starting at the same instant are one visit entered twice."""
    dup = table.duplicated([*SERIES_KEYS, "date"], keep=False)
    if dup.any():
        rows = table[dup]
        machine, axis, date = rows.iloc[0][["machine_id", "axis", "date"]]
        same = rows[(rows["machine_id"] == machine) & (rows["axis"] == axis)
                    & (rows["date"] == date)]["visit"].tolist()
        raise InputError(f"visits {', '.join(map(repr, same))} of {machine} axis {axis} both "
                         f"start at {date.isoformat()}: the same visit entered twice?",
                         file=source, column="visit")
    counts = table.groupby(list(SERIES_KEYS)).size()
    if (counts < 2).all():
        machine, axis = counts.index[0]
        raise InputError(f"drift needs at least two visits per machine and axis; {machine} "
                         f"axis {axis} has {int(counts.iloc[0])}", file=source, column="visit")


def months_between(dates: pd.Series, origin) -> np.ndarray:
    """Elapsed time [month of 30.4375 d] from ``origin`` to each date."""
    return ((pd.to_datetime(dates) - origin).dt.total_seconds() / 86400.0
            / DAYS_PER_MONTH).to_numpy(float)


